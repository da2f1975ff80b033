"""Record the run fingerprints (step count, final time, metrics, conservation, MOOD statistics)
of every built-in config, reduced (the default-suite regression) or at full size.

    python experiments/record_config_metrics.py                 # reduced runs -> stdout JSON
    python experiments/record_config_metrics.py --full --out F  # full configs
    python experiments/record_config_metrics.py --compare F     # rerun and compare with F (prints how
                                                                # much of its tolerance each config uses)
    python experiments/record_config_metrics.py --only A B --update F   # intentional change of A, B

The reduced fingerprints are stored in tests/data/config_fingerprints.json and checked by
tests/test_config_regression.py: a refactor must keep them to 1e-12 relative (the few configs that
amplify round-off beyond it: ``mlsph_jax.testing.ROUNDOFF_AMPLIFIED``, decision 97).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from mlsph_jax.testing import (
    REDUCED_OVERRIDES,
    builtin_configs,
    fingerprint_differences,
    fingerprint_margin,
    fingerprint_tolerance,
    run_fingerprint,
)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--full", action="store_true", help="the configs as shipped (minutes each) instead of reduced")
    ap.add_argument("--only", nargs="+", default=None, help="config stems to run")
    ap.add_argument("--out", help="write the fingerprints to this JSON file")
    ap.add_argument("--compare", help="compare with the fingerprints in this JSON file; exit 1 on a difference")
    ap.add_argument("--update", help="rerun the --only configs and replace their entries in this JSON file "
                                     "(an intentional numeric change; the other entries are kept)")
    args = ap.parse_args(argv)
    if args.update and not args.only:
        ap.error("--update needs --only: name the configs whose numbers changed on purpose")
    ref = json.load(open(args.compare)) if args.compare else None
    names = args.only or builtin_configs()
    out, failed = {}, 0
    for name in names:
        over = () if args.full else REDUCED_OVERRIDES[name]
        t0 = time.perf_counter()
        fp = run_fingerprint(name, over)
        fp["wall_s"] = round(time.perf_counter() - t0, 1)
        out[name] = fp
        line = f"{name:24s} {fp['n_steps']:6d} steps  {fp['wall_s']:7.1f} s"
        if ref is not None:
            tol = fingerprint_tolerance(name, full=args.full)  # decision 97
            diff = fingerprint_differences(fp, ref[name], **tol) if name in ref else ["not in the reference"]
            failed += bool(diff)
            if not diff:
                margin, where = fingerprint_margin(fp, ref[name], **tol)
                line += f"  same (largest difference {margin:.2g} of the tolerance{', ' + where if where else ''})"
            else:
                line += "  DIFFERENT: " + "; ".join(diff)
        print(line, file=sys.stderr, flush=True)
    if args.update:
        with open(args.update) as f:
            merged = json.load(f)
        merged.update(out)
        with open(args.update, "w") as f:
            f.write(json.dumps(merged, indent=1, sort_keys=True) + "\n")
    text = json.dumps(out, indent=1, sort_keys=True)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text + "\n")
    elif ref is None and not args.update:
        print(text)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
