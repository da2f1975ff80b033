"""Cost of the reduced-degree bookkeeping (mlsph_jax.fallback) in a compiled chunk.

A/B in one process: the chunk as shipped (A: the geometry's per-particle degrees, their minimum
over the stages and the per-step fractions in the carry) against the same chunk with the
bookkeeping stubbed out (B: constant degrees, no fractions), alternating the order each
repetition, best of n.  Prints and writes JSON (experiments/output/bench_degree_report.json)
with particle-updates/s and compile times of both; record the load average beside it.

    python experiments/bench_degree_report.py [CONFIG] [--n N] [--steps S] [--reps R]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import jax
import jax.numpy as jnp

from mlsph_jax import config, fallback
from mlsph_jax.cases import build_problem
from mlsph_jax.config.builtin import config_path
from mlsph_jax.integrate import initial_carry
from mlsph_jax.simulation import Simulation


def compiled(pb, steps: int, stub: bool):
    """``(executable, arguments, compile seconds)`` of a chunk of ``steps`` steps."""
    real = (fallback.stack, fallback.step_fractions)
    if stub:
        fallback.stack = lambda area, fit, n: jnp.zeros((n, 2), jnp.int32)
        fallback.step_fractions = lambda degree, kind, scheme: jnp.zeros(len(fallback.STATS))
    try:
        sim = Simulation(pb, chunk=steps)
        carry = initial_carry(sim.problem.particles)
        args = (carry, sim.problem.params, sim._geom(carry.particles), jnp.asarray(1e9),
                jnp.asarray(10**9, jnp.int32))
        t = time.perf_counter()
        exe = sim._chunk.lower(*args).compile()
        return exe, args, time.perf_counter() - t
    finally:
        fallback.stack, fallback.step_fractions = real


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("config", nargs="?", default="taylor_green_2d_mlsph")
    ap.add_argument("--n", type=int, default=40, help="case.n")
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--reps", type=int, default=12)
    a = ap.parse_args(argv)
    pb = build_problem(config.load(config_path(a.config), [f"case.n={a.n}", "output.progress=false"]))
    arms = {"with_degrees": compiled(pb, a.steps, False), "stubbed": compiled(pb, a.steps, True)}
    best = dict.fromkeys(arms, float("inf"))
    order = list(arms)
    for r in range(a.reps):
        for key in order if r % 2 == 0 else order[::-1]:
            exe, args, _ = arms[key]
            t = time.perf_counter()
            jax.block_until_ready(exe(*args).particles.q)
            best[key] = min(best[key], time.perf_counter() - t)
    n = pb.particles.n
    res = {"config": a.config, "n_particles": n, "moving": pb.scheme.moving, "steps": a.steps, "reps": a.reps,
           **{f"{k}_particle_updates_per_s": n * a.steps / best[k] for k in arms},
           **{f"{k}_compile_s": arms[k][2] for k in arms},
           "time_ratio": best["with_degrees"] / best["stubbed"], "load_average": os.getloadavg()}
    print(json.dumps(res, indent=1))
    out = Path(__file__).parent / "output"
    out.mkdir(exist_ok=True)
    (out / "bench_degree_report.json").write_text(json.dumps(res, indent=1) + "\n")
    return res


if __name__ == "__main__":
    main()
