"""Cost of MOOD (:mod:`mlsph_jax.mood`): one SSP-RK3 step with MOOD on vs off, and the MOOD
iteration count of whole runs.  Not a test.

For each built-in config (default: R2 and the 2D blast) and each mode

* ``first_order``: reconstruction degree 0, no limiter (the parachute scheme alone);
* ``unlimited``:   the config's reconstruction degree, no limiter (one RHS per stage);
* ``mood``:        the config's degree with MOOD (1 + iterations RHS evaluations per stage),

one SSP-RK3 step from the initial state is compiled ahead of time (compile time reported) and
timed as the median of ``--repeat`` calls (neighbour search included for moving particles, as
in a run).  The MOOD step from the *initial* state flags the discontinuities, so it is
representative of a shock run.  Then the whole MOOD run of the config is made (``mlsph run``
equivalent) and its summary gives the mean RHS evaluations per stage, the demoted fractions
and the wall time per step.  Prints a table and writes ``experiments/output/bench_mood.json``.

Usage::

    python experiments/bench_mood.py [--configs configs/riemann_r2_tammann.toml configs/blast_2d.toml]
                                     [--repeat 5] [--set case.dx=1e-3]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import platform
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

import mlsph_jax
from mlsph_jax import config
from mlsph_jax import neighbors as nb
from mlsph_jax.cases import build_problem
from mlsph_jax.integrate import cfl_dt, make_stage_geometry, ssp_rk3_step, static_geometry
from mlsph_jax.simulation import run_problem

ROOT = pathlib.Path(__file__).resolve().parents[1]


def step_function(pb, scheme):
    """jit-able p -> new state of one SSP-RK3 step (geometry per stage for moving particles)."""
    p0 = pb.particles
    h = scheme.beta * np.asarray(p0.vol) ** (1.0 / p0.dim)
    cell = scheme.support * float(h.max()) * (2.5 if p0.dim == 1 else 1.5) if scheme.moving else None
    nspec, nl = nb.allocate(np.asarray(p0.x), h, pb.domain, support=scheme.support, headroom=1.6, cell_size=cell)
    if scheme.moving:
        geom_fn = make_stage_geometry(scheme, pb.domain, nspec)
    else:
        g = static_geometry(p0, nl, scheme, pb.domain)
        geom_fn = lambda p: g  # noqa: E731

    def step(p, params):
        dt = cfl_dt(p, params, scheme, 0.3)
        out, overflow, stats = ssp_rk3_step(p, params, dt, scheme, geom_fn)
        return out.q, stats[1]

    return step


def time_step(pb, scheme, repeat: int):
    f = jax.jit(step_function(pb, scheme))
    t0 = time.perf_counter()
    c = f.lower(pb.particles, pb.params).compile()
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(c(pb.particles, pb.params))
    times, evals = [], 0
    for _ in range(repeat):
        t0 = time.perf_counter()
        q, n = jax.block_until_ready(c(pb.particles, pb.params))
        times.append(time.perf_counter() - t0)
        evals = int(n)
    return statistics.median(times), compile_s, evals


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--configs", nargs="+",
                    default=["configs/riemann_r2_tammann.toml", "configs/blast_2d.toml"])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--set", nargs="*", default=[], help="overrides applied to every config")
    ap.add_argument("--out", default=str(ROOT / "experiments" / "output" / "bench_mood.json"))
    args = ap.parse_args()
    rows = []
    print(f"{'config':<34} {'mode':<12} {'N':>7} {'ms/step':>9} {'p-upd/s':>10} {'RHS/step':>8} {'compile s':>9}")
    for path in args.configs:
        if not (ROOT / path).exists():
            print(f"{path}: not found, skipped")
            continue
        cfg = config.load(ROOT / path, ["output.progress=false", *args.set])
        pb = build_problem(cfg)
        base = pb.scheme
        modes = {"first_order": dataclasses.replace(base, reconstruction_degree=0, limiter="none"),
                 "unlimited": dataclasses.replace(base, limiter="none"),
                 "mood": dataclasses.replace(base, limiter="mood")}
        res = {}
        for mode, scheme in modes.items():
            pbm = dataclasses.replace(pb, scheme=scheme)
            dt, comp, evals = time_step(pbm, scheme, args.repeat)
            n = int(pb.particles.n)
            res[mode] = {"seconds_per_step": dt, "particle_updates_per_s": n / dt, "compile_s": comp,
                         "rhs_evaluations_per_step": evals}
            print(f"{path:<34} {mode:<12} {n:>7} {dt * 1e3:>9.2f} {n / dt:>10.3g} {evals:>8} {comp:>9.1f}")
        run = run_problem(pb, cfg, quiet=True).summary
        per_step = (run["wall_time_s"] - run["compile_time_s"]) / max(run["n_steps"], 1)
        mood = run.get("mood", {})
        print(f"{'':<34} MOOD overhead per step vs unlimited: "
              f"{res['mood']['seconds_per_step'] / res['unlimited']['seconds_per_step']:.2f}x, vs first order: "
              f"{res['mood']['seconds_per_step'] / res['first_order']['seconds_per_step']:.2f}x; whole run: "
              f"{run['n_steps']} steps, {per_step * 1e3:.2f} ms/step, RHS evaluations per stage "
              f"{mood.get('rhs_evaluations_per_stage', float('nan')):.2f} (MOOD iterations = that - 1), "
              f"demoted fraction mean {mood.get('flagged_fraction_mean', float('nan')):.3f} "
              f"max {mood.get('flagged_fraction_max', float('nan')):.3f}")
        rows.append({"config": path, "n_particles": int(pb.particles.n), "step": res,
                     "run": {"n_steps": run["n_steps"], "wall_time_s": run["wall_time_s"],
                             "compile_time_s": run["compile_time_s"], "seconds_per_step": per_step,
                             "mood": mood, "metrics": run["metrics"]}})
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"benchmark": "mood", "mlsph_jax": mlsph_jax.__version__, "jax": jax.__version__,
                               "machine": platform.platform(), "cpu_count": jax.local_device_count(),
                               "results": rows}, indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    jnp.zeros(1)  # initialise the backend before timing
    main()
