"""Order in time of SSP-RK3 with ``scheme.geometry_update = "stage"`` (default) and ``"step"``.

A dt-refinement on a short smooth run: the moving-particle Taylor-Green vortex of
``configs/taylor_green_2d_mlsph.toml`` (thesis §4.5.1) at n x n particles, run to ``--t-end``
with the fixed steps dt0, dt0/2, ... (``--halvings`` + 1 runs) for each setting.  The spatial
discretisation is the same in every run, so the difference of consecutive runs' final states
(fluid positions x and conserved densities U = V q, max norm) is the time error alone:
e_k = |y(dt_k) - y(dt_k / 2)| ~ C dt_k^p, and log2(e_k / e_{k+1}) estimates the order p
(3 for SSP-RK3; a geometry lagged over the step costs O(dt) per stage).

    python experiments/geometry_update_order.py [--n 20] [--t-end 0.2] [--dt0 0.01] [--halvings 4]
                                                [--frame ale_shift] [--updates stage step]
                                            [--set KEY=VALUE ...]

Writes experiments/output/geometry_update_order.json.  Not a test.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
from pathlib import Path

import numpy as np

from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.simulation import Simulation
from mlsph_jax.state import Kind

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "experiments" / "output" / "geometry_update_order.json"
CONFIG = ROOT / "configs" / "taylor_green_2d_mlsph.toml"


def final_state(n: int, frame: str, update: str, t_end: float, dt: float, sets=()) -> dict:
    steps = round(t_end / dt)
    cfg = config.load(CONFIG, [f"case.n={n}", f"scheme.frame={frame}", f"scheme.geometry_update={update}",
                               f"time.t_end={steps * dt!r}", f"time.dt={dt!r}", "output.plots=false",
                               "output.progress=false", *sets])
    pb = build_problem(cfg)
    sim = Simulation(pb, dt=dt, chunk=steps, max_steps=steps + 1, headroom=cfg["scheme"]["neighbor_headroom"],
                     moving_headroom=cfg["scheme"]["moving_neighbor_headroom"])
    res = sim.run(None, snapshots=1, progress=False, plots=False)
    p = res.particles
    fluid = np.asarray(p.kind) == Kind.FLUID
    return {"steps": res.summary["n_steps"], "x": np.asarray(p.x)[fluid], "U": np.asarray(p.U)[fluid],
            "l2_velocity_error": res.summary["metrics"]["l2_velocity_error"]}


def order(errors: list[float]) -> list[float | None]:
    """log2 of consecutive error ratios (the observed order for halved steps)."""
    return [math.log2(e0 / e1) if e1 > 0 else None for e0, e1 in itertools.pairwise(errors)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=20)
    ap.add_argument("--t-end", type=float, default=0.2)
    ap.add_argument("--dt0", type=float, default=0.01)
    ap.add_argument("--halvings", type=int, default=4)
    ap.add_argument("--frame", default="ale_shift")
    ap.add_argument("--updates", nargs="+", default=["stage", "step"], choices=["stage", "step"],
                    help="the scheme.geometry_update settings to refine (default: both)")
    ap.add_argument("--set", nargs="*", default=[], dest="sets", help="further config overrides KEY=VALUE")
    a = ap.parse_args(argv)
    dts = [a.dt0 / 2 ** k for k in range(a.halvings + 1)]
    rows = []
    for update in a.updates:
        runs = [final_state(a.n, a.frame, update, a.t_end, dt, a.sets) for dt in dts]
        ex = [float(np.max(np.abs(r1["x"] - r0["x"]))) for r0, r1 in itertools.pairwise(runs)]
        eu = [float(np.max(np.abs(r1["U"] - r0["U"]))) for r0, r1 in itertools.pairwise(runs)]
        row = {"geometry_update": update, "frame": a.frame, "n": a.n, "t_end": a.t_end, "dt": dts,
               "error_x": ex, "error_U": eu, "order_x": order(ex), "order_U": order(eu),
               "l2_velocity_error": [r["l2_velocity_error"] for r in runs], "load_average": os.getloadavg()}
        rows.append(row)
        print(f"{a.frame} {update}: n={a.n} t_end={a.t_end} dt={dts}", flush=True)
        for k, dt in enumerate(dts[:-1]):
            ox = row["order_x"][k - 1] if k else None
            ou = row["order_U"][k - 1] if k else None
            print(f"  dt {dt:.5g} -> {dt / 2:.5g}: |dx| {ex[k]:.3e}" + (f" (order {ox:.2f})" if ox else "")
                  + f"  |dU| {eu[k]:.3e}" + (f" (order {ou:.2f})" if ou else ""), flush=True)
        print(f"  load {os.getloadavg()[0]:.2f}", flush=True)
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps({"runs": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
