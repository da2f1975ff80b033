"""How far a run's fingerprint moves when its initial state moves by one unit of round-off.

The refactor safety net (``tests/test_config_regression.py``) compares each built-in config's
metrics with a stored fingerprint to 1e-12 relative.  A change that only reorders a sum (a
fused loop, a different blocking) changes every step's result in the last bit, and a long run
can amplify that; this script measures the amplification, so that a fingerprint difference can
be told apart from a change of the numerics: it runs the config once as built and once with
every conserved quantity multiplied by ``1 + s_i 2^-52`` (``s_i`` = +-1 at random, seed 0: one
ulp per value), and prints the relative change of every metric and conservation entry.

    python experiments/roundoff_sensitivity.py taylor_green_2d_mlsph            # as shipped
    python experiments/roundoff_sensitivity.py riemann_r1_tait --set time.t_end=0.001

Writes experiments/output/roundoff_sensitivity_<config>.json (not committed).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "experiments" / "output"


def fingerprint(problem, cfg) -> dict:
    from mlsph_jax.simulation import run_problem
    from mlsph_jax.testing import _floats

    s = run_problem(problem, cfg, out_dir=None, quiet=True).summary
    return {"n_steps": int(s["n_steps"]), "metrics": _floats(s.get("metrics", {})),
            "conservation": _floats(s.get("conservation", {}))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("config", help="a built-in config stem or a TOML path")
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="config overrides")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)

    import numpy as np

    from mlsph_jax import config
    from mlsph_jax.cases import build_problem
    from mlsph_jax.testing import CONFIG_DIR

    path = Path(a.config) if Path(a.config).suffix else CONFIG_DIR / f"{a.config}.toml"
    cfg = config.load(path, [*a.set, "output.plots=false", "output.progress=false"])
    problem = build_problem(cfg)
    q = np.asarray(problem.particles.q)
    sign = np.random.default_rng(0).choice([-1.0, 1.0], size=q.shape)
    nudged = dataclasses.replace(problem, particles=problem.particles.replace(
        q=problem.particles.q * (1.0 + sign * 2.0 ** -52)))
    print(f"{path.stem}: initial q moved by {np.abs(np.asarray(nudged.particles.q) - q).max():.2e} "
          f"(max |q| {np.abs(q).max():.2e}); load {os.getloadavg()[0]:.2f}", flush=True)
    t0 = time.perf_counter()
    ref = fingerprint(problem, cfg)
    new = fingerprint(nudged, cfg)
    rows = {}
    for group in ("metrics", "conservation"):
        for k in sorted(set(ref[group]) & set(new[group])):
            x, y = new[group][k], ref[group][k]
            rel = abs(x - y) / max(abs(y), 1e-300)
            rows[f"{group}.{k}"] = {"reference": y, "nudged": x, "relative_change": rel}
            print(f"  {group}.{k:28s} {y!r:>24s}  relative change {rel:.2e}")
    print(f"steps {ref['n_steps']} / {new['n_steps']}; {time.perf_counter() - t0:.0f} s for both runs", flush=True)
    out = Path(a.out or OUT / f"roundoff_sensitivity_{path.stem}.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"config": str(path), "set": a.set, "steps": [ref["n_steps"], new["n_steps"]],
                               "entries": rows}, indent=1))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
