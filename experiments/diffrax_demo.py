"""The diffrax path on the small smooth cases of tests/test_differentiable.py (mlsph_jax.diffrax_path).

Prints, for the periodic viscous Tait shear case (Eulerian and Lagrangian) and start-up Couette
flow with mirror walls:

* the relative difference between diffrax + SSPRK3 and the built-in integrator (same fixed dt);
* adaptive Tsit5 / Dopri5 / SSPRK3(2) with PIDController(rtol=1e-8, atol=1e-10): steps taken and
  difference to the fixed-step solutions, with the Richardson estimate of SSP-RK3's error;
* d ke(t_end) / d(physics.mu, eos.c0) via RecursiveCheckpointAdjoint vs make_simulate;
* compile and run times (after compilation).

Run: /work/venv/bin/python experiments/diffrax_demo.py [--quick]
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import diffrax  # noqa: E402
import jax  # noqa: E402
import numpy as np  # noqa: E402

from mlsph_jax import diffrax_path as dp  # noqa: E402
from mlsph_jax.differentiable import kinetic_energy, make_simulate, with_param  # noqa: E402
from mlsph_jax.testing import couette_problem, periodic_shear_problem  # noqa: E402
from mlsph_jax.testing import state_difference as rel_diff  # noqa: E402


def timed(fn, *a):
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(*a))
    t1 = time.perf_counter()
    jax.block_until_ready(fn(*a))
    return out, t1 - t0, time.perf_counter() - t1


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--quick", action="store_true", help="shear (Eulerian) only")
    a = ap.parse_args()
    N = a.steps
    shear = periodic_shear_problem()
    cases = {"shear eulerian": shear}
    if not a.quick:
        cases["shear lagrangian"] = dataclasses.replace(shear, scheme=dataclasses.replace(shear.scheme,
                                                                                           frame="lagrangian"))
        cases["couette (walls)"] = couette_problem()
    for name, pb in cases.items():
        print(f"== {name}: {pb.particles.n} particles, t_end={pb.t_end}, {N} steps")
        sim = jax.jit(lambda prm, p, pb=pb: make_simulate(pb, n_steps=N, checkpoint="none")(prm, p).particles)
        ref, tc, tr = timed(sim, pb.params, pb.particles)
        print(f"  built-in            compile+run {tc:6.2f} s, run {tr * 1e3:7.1f} ms")
        fn = dp.make_solve(pb, n_steps=N)
        run = jax.jit(lambda prm, p, fn=fn, pb=pb: dp.final_particles(pb, fn(prm, p), prm))
        p, tc, tr = timed(run, pb.params, pb.particles)
        print(f"  diffrax SSPRK3      compile+run {tc:6.2f} s, run {tr * 1e3:7.1f} ms, "
              f"rel. difference {rel_diff(p, ref):.2e} (fluid), {rel_diff(p, ref, False):.2e} (all)")
        p2 = dp.final_particles(pb, dp.solve(pb, n_steps=2 * N))
        rich = 8 / 7 * rel_diff(p2, p)
        print(f"  Richardson estimate of the SSP-RK3({N}) error: {rich:.2e}")
        for solver in (diffrax.Tsit5(), diffrax.Dopri5(), dp.SSPRK3()):
            fa = dp.make_solve(pb, solver, n_steps=N, adaptive=True, rtol=1e-8, atol=1e-10)
            runa = jax.jit(lambda prm, q, fa=fa, pb=pb: (lambda s: (dp.final_particles(pb, s, prm),
                                                                    s.stats["num_accepted_steps"],
                                                                    s.stats["num_rejected_steps"]))(fa(prm, q)))
            (pa, acc, rej), tc, tr = timed(runa, pb.params, pb.particles)
            print(f"  adaptive {type(solver).__name__:7s} {int(acc):4d} accepted / {int(rej)} rejected steps, "
                  f"run {tr * 1e3:7.1f} ms; vs RK3({N}) {rel_diff(pa, p):.2e}, vs RK3({2 * N}) {rel_diff(pa, p2):.2e}")
        if pb.boundary is None:
            keys = ("physics.mu", "eos.c0")
        else:
            keys = ("physics.mu",)

        sim_nested = make_simulate(pb, n_steps=N, checkpoint="nested")

        def loss_ref(vals, pb=pb, keys=keys, sim=sim_nested):
            prm = pb.params
            for k, v in zip(keys, vals, strict=True):
                prm = with_param(prm, k, v)
            return kinetic_energy(sim(prm, pb.particles).particles, prm)

        def loss_dfx(vals, pb=pb, keys=keys, fn=fn):
            prm = pb.params
            for k, v in zip(keys, vals, strict=True):
                prm = with_param(prm, k, v)
            return kinetic_energy(dp.final_particles(pb, fn(prm, pb.particles), prm), prm)

        vals = tuple(pb.params[k] for k in keys)
        g_ref, tc1, tr1 = timed(jax.jit(jax.grad(loss_ref)), vals)
        g_dfx, tc2, tr2 = timed(jax.jit(jax.grad(loss_dfx)), vals)
        for k, r, d in zip(keys, g_ref, g_dfx, strict=True):
            print(f"  d ke/d {k:11s} built-in {float(r): .15e}  diffrax {float(d): .15e}  "
                  f"rel. diff {abs(float(d) - float(r)) / abs(float(r)):.1e}")
        print(f"  grad: built-in (nested checkpoints) compile+run {tc1:.2f} s run {tr1 * 1e3:.1f} ms; "
              f"diffrax (RecursiveCheckpointAdjoint) compile+run {tc2:.2f} s run {tr2 * 1e3:.1f} ms")
    return 0


if __name__ == "__main__":
    np.set_printoptions(precision=3)
    raise SystemExit(main())
