"""One device against two host devices, index-range sharding against the spatial decomposition.

Taylor-Green (``taylor_green_2d`` of :mod:`bench_taylor_green`: MLSPH-ALE, quadratic MLS
reconstruction, Eulerian frame, fixed step dt = 0.3 dx / (c0 + U0)) on n x n particles, in one
process started with ``XLA_FLAGS=--xla_force_host_platform_device_count=2`` (the script
re-executes itself with the flag):

* ``one``: ``run.devices = 1``;
* ``index``: ``run.devices = 2``, ``run.decomposition = "index"`` (index ranges, XLA's SPMD
  partitioner all-gathers the per-particle fields every stage);
* ``spatial``: ``run.devices = 2``, ``run.decomposition = "spatial"`` (:mod:`mlsph_jax.spatial`).

Each variant is compiled once; then ``--rounds`` rounds run the three in turn (one, index,
spatial, one, ...) so that the contention of the shared machine falls on all of them, and the
best round counts. Every timing carries the 1-minute load average (``os.getloadavg``) read just
before it, and the cores the process kept busy during the run call (user + system CPU time over
wall time, ``os.times``; set-up and snapshot included): one device that already keeps both cores
of a 2-core host busy leaves a second device nothing to gain. Also: the compile time of each
variant, the collective instructions of its compiled chunk (``all-gather``, ``all-reduce``,
``collective-permute``, ``all-to-all``,
``reduce-scatter`` in the optimised HLO text; the step and stage loops are compiled once, so
the count is per chunk, not per step; also for one chunk of the default ``taylor_green_2d``
config, adaptive step), the halo rows of the spatial layout, and the largest
difference of the final conserved quantities from the one-device run (relative to their scale).

    python experiments/bench_spatial_shards.py                      # N = 1e4 and 1e5
    python experiments/bench_spatial_shards.py --sizes 50 --steps 4 --rounds 2

Writes experiments/output/bench_spatial_shards.json (not committed).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "experiments" / "output"
VARIANTS = (("one", 1, "index"), ("index", 2, "index"), ("spatial", 2, "spatial"))
COLLECTIVES = ("all-gather", "all-reduce", "collective-permute", "all-to-all", "reduce-scatter")


def collectives(hlo: str) -> dict[str, int]:
    """Number of collective instructions of each kind in an HLO module's text (async pairs
    ``*-start``/``*-done`` counted once)."""
    return {c: len(re.findall(rf"\s{c}(?:-start)?\(", hlo)) for c in COLLECTIVES}


def load() -> float:
    return round(os.getloadavg()[0], 2)


def bench(n: int, steps: int, rounds: int, log) -> dict:
    import numpy as np
    from bench_scale import _problem_2d  # the same Taylor-Green set-up (this folder is on sys.path)

    from mlsph_jax.simulation import Simulation

    pb, cfg, dt = _problem_2d(n, "eulerian", steps)
    N = int(pb.particles.n)
    sims, rows = {}, {}
    for name, devices, dec in VARIANTS:
        sim = Simulation(pb, dt=dt, chunk=steps, max_steps=steps + 1, headroom=cfg["scheme"]["neighbor_headroom"],
                         devices=devices, decomposition=dec)
        la = load()
        res = sim.run(None, snapshots=1, progress=False, plots=False)
        s = res.summary
        sims[name] = sim
        rows[name] = {"variant": name, "devices": devices, "decomposition": dec, "particles": N,
                      "compile_s": s["compile_time_s"], "compile_load": la, "steps": s["n_steps"],
                      "collectives": collectives(sim._compiled.as_text()), "q": np.asarray(res.particles.q),
                      "timings": [], **({"layout": s["decomposition"]} if "decomposition" in s else {})}
        log(f"N={N} {name:8s} compile {s['compile_time_s']:6.2f} s (load {la})  collectives "
            f"{rows[name]['collectives']}")
    for r in range(rounds):
        for name, _, _ in VARIANTS:
            la = load()
            t0, c0 = time.perf_counter(), os.times()
            s = sims[name].run(None, snapshots=1, progress=False, plots=False).summary
            t1, c1 = time.perf_counter(), os.times()
            busy = (c1.user + c1.system - c0.user - c0.system) / max(t1 - t0, 1e-12)
            rate = N * s["n_steps"] / max(s["chunk_time_s"], 1e-12)
            rows[name]["timings"].append({"round": r, "load": la, "stepping_s": s["chunk_time_s"],
                                          "particle_steps_per_s": rate, "cores_busy": busy})
            log(f"N={N} round {r} {name:8s} {rate:10.3e} particle-steps/s, {busy:.2f} cores busy (load {la})")
    q1 = rows["one"]["q"]
    for row in rows.values():
        best = max(row["timings"], key=lambda t: t["particle_steps_per_s"])
        row["best"] = best
        row["max_q_difference"] = float(np.abs(row.pop("q") - q1).max() / np.abs(q1).max())
    best1 = rows["one"]["best"]["particle_steps_per_s"]
    for row in rows.values():
        row["speedup_over_one_device"] = row["best"]["particle_steps_per_s"] / best1
    return {"n": n, "particles": N, "steps": steps, "rounds": rounds, "variants": list(rows.values())}


def hlo_counts(log) -> dict:
    """Collective instructions of one compiled chunk of the default ``taylor_green_2d`` config
    (adaptive CFL step, 12 x 12; the count does not depend on N) in both decompositions."""
    from mlsph_jax import config
    from mlsph_jax.cases import build_problem
    from mlsph_jax.simulation import Simulation

    cfg = config.loads('[case]\nname = "taylor_green_2d"\nn = 12\n', ["time.t_end=0.01"])
    out = {}
    for name, dec in (("index", "index"), ("spatial", "spatial")):
        sim = Simulation(build_problem(cfg), chunk=4, devices=2, decomposition=dec)
        sim.run(None, snapshots=1, progress=False, plots=False)
        out[name] = collectives(sim._compiled.as_text())
        log(f"default taylor_green_2d chunk, {name:8s} decomposition: collectives {out[name]}")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[100, 316], help="n of the n x n lattice")
    ap.add_argument("--steps", type=int, default=5, help="steps per timed run (one chunk)")
    ap.add_argument("--rounds", type=int, default=3, help="interleaved timing rounds (best counts)")
    ap.add_argument("--out", default=str(OUT / "bench_spatial_shards.json"))
    a = ap.parse_args(argv)
    if "--xla_force_host_platform_device_count=2" not in os.environ.get("XLA_FLAGS", ""):
        env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2", "JAX_PLATFORMS": "cpu",
               "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
        return subprocess.run([sys.executable, __file__, *(argv if argv is not None else sys.argv[1:])],
                              env=env).returncode

    def log(msg):
        print(msg, flush=True)

    import jax

    log(f"jax {jax.__version__}, devices {jax.devices()}, cpus {os.cpu_count()}, load {os.getloadavg()}")
    out = {"jax": jax.__version__, "cpus": os.cpu_count(), "started": time.strftime("%Y-%m-%d %H:%M:%S"),
           "note": "shared 2-core machine: load averages above 2.5 mean contended timings", "runs": []}
    out["hlo_default_config"] = hlo_counts(log)
    for n in a.sizes:
        res = bench(n, a.steps, a.rounds, log)
        out["runs"].append(res)
        for v in res["variants"]:
            b = v["best"]
            log(f"SUMMARY N={res['particles']} {v['variant']:8s} best {b['particle_steps_per_s']:10.3e} "
                f"particle-steps/s (load {b['load']}), x{v['speedup_over_one_device']:.2f} of one device, compile "
                f"{v['compile_s']:.2f} s, collectives {v['collectives']}, max |q - q_1| / max|q_1| "
                f"{v['max_q_difference']:.1e}")
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(out, indent=1))
    log(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
