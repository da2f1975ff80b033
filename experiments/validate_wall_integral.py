"""Boundary-integral walls (thesis eq. 4.24) against mirror ghosts on the channel start-up flows.

Runs the built-in ``couette`` and ``poiseuille`` configs with ``case.walls`` = ``mirror_ghosts``
and ``boundary_integral`` at the same resolution (``--ny`` particles across the gap, ``nx`` = 8
along the periodic plates, which does not change the 1-D solution), Eulerian MLSPH-ALE with the
configs' reconstruction (cubic since 2026-12-05; quadratic before),
and prints the L-infinity error against the exact series (``linf_u_error``, normalised by the
peak speed), the largest wall-normal speed, the mass change and the wall time; writes
``experiments/output/validate_wall_integral.json``.  The load average is printed with every
row.  Not a test.

Usage::

    python experiments/validate_wall_integral.py --ny 10 20 --t-couette 1 --t-poiseuille 6
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import time

from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.simulation import run_problem

WALLS = ("mirror_ghosts", "boundary_integral")


def run(path: str, walls: str, ny: int, t_end: float, cfl: float, frame: str) -> dict:
    cfg = config.load(path, ["output.progress=false", "output.plots=false", "case.nx=8", f"case.ny={ny}",
                             f"time.t_end={t_end}", f"time.cfl={cfl}", f"case.walls={walls}",
                             f"scheme.frame={frame}"])
    t0 = time.perf_counter()
    s = run_problem(build_problem(cfg), cfg, out_dir=None, quiet=True).summary
    return {"case": cfg["case"]["name"], "walls": walls, "ny": ny, "t_end": t_end, "frame": frame,
            "n_steps": s["n_steps"], "wall_s": time.perf_counter() - t0, "load_average": os.getloadavg()[0],
            **{k: s["metrics"][k] for k in ("linf_u_error", "l2_u_error", "max_abs_v")},
            "mass_change": s["conservation"]["mass"]}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--ny", type=int, nargs="+", default=[10, 20])
    ap.add_argument("--t-couette", type=float, default=1.0)
    ap.add_argument("--t-poiseuille", type=float, default=6.0)
    ap.add_argument("--cfl", type=float, default=0.6)
    ap.add_argument("--frame", default="eulerian")
    ap.add_argument("--cases", nargs="+", default=["couette", "poiseuille"])
    args = ap.parse_args(argv)
    rows = []
    for case in args.cases:
        t_end = args.t_couette if case == "couette" else args.t_poiseuille
        for ny in args.ny:
            for walls in WALLS:
                r = run(f"configs/{case}.toml", walls, ny, t_end, args.cfl, args.frame)
                rows.append(r)
                print(f"{case:10s} ny={ny:3d} t={t_end:g} {walls:17s} linf={r['linf_u_error']:.3e} "
                      f"l2={r['l2_u_error']:.3e} max|v|={r['max_abs_v']:.1e} mass={r['mass_change']:.1e} "
                      f"steps={r['n_steps']} {r['wall_s']:.1f} s load {r['load_average']:.1f}", flush=True)
    out = pathlib.Path(__file__).parent / "output"
    out.mkdir(exist_ok=True)
    (out / "validate_wall_integral.json").write_text(json.dumps({"args": vars(args), "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
