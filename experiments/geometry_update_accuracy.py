"""Accuracy and cost of ``scheme.geometry_update = "step"`` (one geometry per SSP-RK3 step,
reused by its three stages) against the default ``"stage"`` (rebuilt every stage).

The moving-particle Taylor-Green vortex of ``configs/taylor_green_2d_mlsph.toml`` (thesis §4.5.1:
``ale_shift``, linear-basis areas, cubic reconstruction, Tait c0 = 10) run to ``--t-end`` (the
thesis' t = 2 by default) with the adaptive CFL step at n x n for n in ``--sizes``, both settings,
same process.  Reported per run: the error metrics against the exact vortex (relative E_k error,
L2 velocity and pressure errors), the conservation drifts and the stepping time
(``summary["chunk_time_s"]``, contended on a shared machine: the interleaved cost ratio is
``experiments/bench_taylor_green.py``'s business).  The difference between the two settings is
the time error of the lagged geometry; compare it with the spatial error (the "stage" error).

    python experiments/geometry_update_accuracy.py [--sizes 25 50] [--t-end 2.0] [--frame ale_shift]
                                                   [--config PATH --size-key case.ny] [--set KEY=VALUE ...]

``--config`` runs another case (e.g. ``configs/couette.toml`` with ``--set case.walls=boundary_integral``
and ``--size-key case.ny``); every metric of its summary is reported.

Writes experiments/output/geometry_update_accuracy.json.  Not a test.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.simulation import Simulation

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "experiments" / "output" / "geometry_update_accuracy.json"

CONFIG = ROOT / "configs" / "taylor_green_2d_mlsph.toml"
METRICS = ("ke_rel_error", "l2_velocity_error", "l2_pressure_error")


def run(n: int, frame: str, update: str, t_end: float, path=CONFIG, size_key="case.n", sets=()) -> dict:
    cfg = config.load(path, [f"{size_key}={n}", f"scheme.frame={frame}", f"scheme.geometry_update={update}",
                             f"time.t_end={t_end!r}", "output.plots=false", "output.progress=false", *sets])
    pb = build_problem(cfg)
    sim = Simulation(pb, chunk=cfg["time"]["chunk"], headroom=cfg["scheme"]["neighbor_headroom"],
                     moving_headroom=cfg["scheme"]["moving_neighbor_headroom"])
    res = sim.run(None, snapshots=1, progress=False, plots=False)
    s = res.summary
    m = s["metrics"]
    return {"n": n, "frame": frame, "geometry_update": update, "t_end": t_end, "steps": s["n_steps"],
            "status": s["status"], "chunk_time_s": s["chunk_time_s"],
            "metrics": m, **{k: m[k] for k in METRICS if k in m},
            "conservation": s["conservation"], "load_average": os.getloadavg()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[25, 50])
    ap.add_argument("--t-end", type=float, default=2.0)
    ap.add_argument("--frame", default="ale_shift")
    ap.add_argument("--config", type=Path, default=CONFIG)
    ap.add_argument("--size-key", default="case.n", help="the config key --sizes sets")
    ap.add_argument("--set", nargs="*", default=[], dest="sets", help="further config overrides KEY=VALUE")
    a = ap.parse_args(argv)
    rows = []
    for n in a.sizes:
        pair = {u: run(n, a.frame, u, a.t_end, a.config, a.size_key, a.sets) for u in ("stage", "step")}
        rows += list(pair.values())
        st, sp = pair["stage"], pair["step"]
        keys = [k for k, v in st["metrics"].items() if isinstance(v, float)]
        print(f"{a.size_key}={n} {a.frame} t={a.t_end}: steps {st['steps']} / {sp['steps']}; stage / step: "
              + "; ".join(f"{k} {st['metrics'][k]:.4e} / {sp['metrics'][k]:.4e}" for k in keys)
              + f"; stepping "
              f"{st['chunk_time_s']:.1f} s / {sp['chunk_time_s']:.1f} s (load {os.getloadavg()[0]:.2f})",
              flush=True)
        print(f"    conservation stage {st['conservation']}\n    conservation step  {sp['conservation']}", flush=True)
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps({"config": str(a.config), "sets": a.sets, "runs": rows}, indent=1, default=float) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
