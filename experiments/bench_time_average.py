"""Cost of a time-averaged objective (``--of cd_mean``; decision 73): a differentiated run of the
coarse ellipse (docs/validation.md "Shape sensitivity") with and without the in-run average of
C_D over the second half of the run, interleaved (A, B, A, B, ...; best of ``--repeat``), forward
and value + gradient w.r.t. the angle of attack.  Prints particle-steps/s and compile times and
writes JSON to experiments/output/bench_time_average.json.

    python experiments/bench_time_average.py [--steps 100] [--repeat 3] [--no-grad] [--set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import jax
import jax.numpy as jnp

from mlsph_jax import config as config_mod
from mlsph_jax.cases import build_problem
from mlsph_jax.differentiable import make_simulate, with_param
from mlsph_jax.sensitivity import time_average
from mlsph_jax.testing import CONFIG_DIR

ALPHA = "geometry.body.alpha"
SETUP = ("case.n_theta=32", "case.r_far=3.0", "case.mach=0.2", "scheme.reconstruction_degree=2",
         "time.local_time_stepping=false", "case.body=\"ellipse\"", "case.aspect=2.0", "case.alpha=5.0",
         "output.plots=false", "output.progress=false")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-grad", action="store_true", help="forward runs only")
    ap.add_argument("--set", nargs="*", default=[])
    args = ap.parse_args()
    pb = build_problem(config_mod.load(CONFIG_DIR / "cylinder.toml", [*SETUP, *args.set]))
    n, dt = args.steps, 6e-3
    base = make_simulate(pb, n_steps=n, t_end=n * dt, cfl=0.6, checkpoint="step", record_every=n)
    dm = pb.differentiable_metrics
    avg = make_simulate(pb, **base.options, average=lambda p, t, P: {"cd": dm(p, t, P)["cd"]},
                        window=(0.5 * n * dt, n * dt))

    def objective(sim, averaged):
        def f(a, P0):
            P = with_param(P0, ALPHA, a)
            out = sim(P, pb.particles_at(P))
            val = time_average(out.averages["cd"], "mean") if averaged else dm(out.particles, n * dt, P)["cd"]
            return val, out.status
        return f

    variants = {"cd (final)": objective(base, False), "cd_mean (window [t/2, t])": objective(avg, True)}
    kinds = {"forward": lambda f: jax.jit(f)}
    if not args.no_grad:
        kinds["value+gradient"] = lambda f: jax.jit(jax.value_and_grad(f, has_aux=True))
    a0 = jnp.asarray(float(pb.params[ALPHA]))
    fns, compile_s = {}, {}
    for kind, wrap in kinds.items():
        for name, f in variants.items():
            fn = wrap(f)
            t0 = time.perf_counter()
            jax.block_until_ready(fn(a0, pb.params))
            compile_s[(kind, name)] = time.perf_counter() - t0
            fns[(kind, name)] = fn
    best = {k: float("inf") for k in fns}
    for _ in range(args.repeat):           # interleaved: contention hits both variants alike
        for k, fn in fns.items():
            t0 = time.perf_counter()
            jax.block_until_ready(fn(a0, pb.params))
            best[k] = min(best[k], time.perf_counter() - t0)
    load = os.getloadavg()
    rows = []
    for (kind, name), t in best.items():
        rate = pb.particles.n * n / t
        rows.append({"kind": kind, "objective": name, "best_s": t, "compile_and_first_s": compile_s[(kind, name)],
                     "particle_steps_per_s": rate})
        print(f"{kind:15s} {name:26s} {t:8.3f} s (best of {args.repeat})  {rate:9.3g} particle-steps/s  "
              f"compile+first {compile_s[(kind, name)]:6.1f} s")
    for kind in kinds:
        r = best[(kind, "cd_mean (window [t/2, t])")] / best[(kind, "cd (final)")]
        print(f"{kind}: averaged / final = {r:.3f}")
    print(f"{pb.particles.n} particles, {n} steps; load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}"
          f"{' (contended)' if load[0] > 2.5 else ''}")
    out = Path(__file__).resolve().parent / "output" / "bench_time_average.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps({"n_particles": pb.particles.n, "steps": n, "repeat": args.repeat, "load": load,
                               "rows": rows}, indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
