"""Validation of the 1D Riemann problems (thesis R1, R2 and Sod) against exact solutions.

Runs each built-in config at its resolution (profiles figure, as thesis Fig. 3.3/3.4) and a
refinement study (L1 errors and observed orders), prints a table, writes JSON to
experiments/output/riemann_validation.json and figures to docs/figures/ (used by
docs/validation.md).

    python experiments/validate_riemann.py [--sizes 100 200 400] [--degree 0] [--frame lagrangian]
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np

from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.simulation import run_problem

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = {"R1 (Tait)": "configs/riemann_r1_tait.toml", "R2 (stiffened gas)": "configs/riemann_r2_tammann.toml",
           "Sod (ideal gas)": "configs/sod_ideal_gas.toml"}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="+", default=[100, 200, 400])
    ap.add_argument("--degree", type=int, default=0, help="reconstruction degree (0 = first order)")
    ap.add_argument("--frame", default="lagrangian")
    ap.add_argument("--figures", default=str(ROOT / "docs" / "figures"))
    args = ap.parse_args()
    out = {"sizes": args.sizes, "degree": args.degree, "frame": args.frame, "cases": {}}
    figs = Path(args.figures)
    figs.mkdir(parents=True, exist_ok=True)
    print(f"{'case':<20} {'n':>5} {'l1_rho':>9} {'l1_u':>9} {'l1_p':>9} {'steps':>6} {'wall s':>7} {'compile s':>9}")
    for name, path in CONFIGS.items():
        rows = []
        base = config.load(ROOT / path)
        for n in args.sizes:
            cfg = config.load(ROOT / path, [f"case.n={n}", f"scheme.reconstruction_degree={args.degree}",
                                            f"scheme.frame={args.frame}"])
            tmp = Path(tempfile.mkdtemp())
            r = run_problem(build_problem(cfg), cfg, out_dir=tmp, quiet=True)
            s = r.summary
            rows.append({"n": n, **s["metrics"], "n_steps": s["n_steps"], "wall_time_s": s["wall_time_s"],
                         "compile_time_s": s["compile_time_s"], "conservation": s["conservation"]})
            m = s["metrics"]
            print(f"{name:<20} {n:>5} {m['l1_rho']:>9.4g} {m['l1_u']:>9.4g} {m['l1_p']:>9.4g} "
                  f"{s['n_steps']:>6} {s['wall_time_s']:>7.1f} {s['compile_time_s']:>9.1f}")
            if n == base["case"]["n"]:
                stem = Path(path).stem
                shutil.copy(tmp / "profiles.png", figs / f"{stem}_deg{args.degree}.png")
            shutil.rmtree(tmp)
        orders = {}
        for k in ("l1_rho", "l1_u", "l1_p"):
            e = np.array([r[k] for r in rows])
            orders[k] = [float(o) for o in np.log2(e[:-1] / e[1:])]
        print(f"{'':<20} observed orders: " + ", ".join(f"{k} {np.round(v, 2).tolist()}" for k, v in orders.items()))
        out["cases"][name] = {"config": path, "runs": rows, "orders": orders}
    dest = ROOT / "experiments" / "output"
    dest.mkdir(parents=True, exist_ok=True)
    (dest / "riemann_validation.json").write_text(json.dumps(out, indent=2))
    print(f"wrote {dest / 'riemann_validation.json'} and figures in {figs}")


if __name__ == "__main__":
    main()
