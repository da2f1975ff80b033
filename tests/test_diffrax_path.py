"""The diffrax path (mlsph_jax.diffrax_path): the semi-discrete system as a diffrax.ODETerm.

SSP-RK3 as a Butcher tableau reproduces the built-in Shu–Osher integrator to round-off (Eulerian
and Lagrangian, with mirror walls in the slow test), an adaptive solver runs the same case and
differs from it by SSP-RK3's truncation error, and the gradient through diffrax's checkpointed
adjoint equals the built-in differentiable path's.
"""

from __future__ import annotations

import dataclasses

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mlsph_jax import diffrax_path as dp  # noqa: E402
from mlsph_jax.differentiable import kinetic_energy, make_simulate, with_param  # noqa: E402
from mlsph_jax.errors import InputError  # noqa: E402
from mlsph_jax.testing import couette_problem, periodic_shear_problem, state_difference  # noqa: E402

N_STEPS = 20  # dt = t_end / 20 = 1e-3 (the CFL step of the case is ~3.3e-3)


rel_diff = state_difference


def _params(pb, mu, c0):
    return with_param(with_param(pb.params, "physics.mu", mu), "eos.c0", c0)


@pytest.fixture(scope="module")
def shear():
    """Built-in and diffrax (SSPRK3, RecursiveCheckpointAdjoint) runs of the periodic shear case:
    final state, ke(t_end) and its gradient w.r.t. (physics.mu, eos.c0), one compile each."""
    pb = periodic_shear_problem()
    sim = make_simulate(pb, n_steps=N_STEPS, checkpoint="none")
    sol_fn = dp.make_solve(pb, dp.SSPRK3(), n_steps=N_STEPS, adjoint=diffrax.RecursiveCheckpointAdjoint())
    assert sol_fn.dt == sim.dt

    def builtin(mu, c0):
        prm = _params(pb, mu, c0)
        p = sim(prm, pb.particles).particles
        return kinetic_energy(p, prm), p

    def via_diffrax(mu, c0):
        prm = _params(pb, mu, c0)
        p = dp.final_particles(pb, sol_fn(prm, pb.particles), prm)
        return kinetic_energy(p, prm), p

    out = {"pb": pb}
    mu, c0 = pb.params["physics.mu"], pb.params["eos.c0"]
    for name, f in (("builtin", builtin), ("diffrax", via_diffrax)):
        (ke, p), g = jax.jit(jax.value_and_grad(f, argnums=(0, 1), has_aux=True))(mu, c0)
        out[name] = {"ke": float(ke), "p": p, "grad": np.asarray(g)}
    return out


def test_ssprk3_tableau_is_the_shu_osher_scheme():
    """The tableau is consistent, 3rd order, and its embedded pair is Heun (SSP-RK2)."""
    t = dp.SSPRK3_TABLEAU
    c = np.concatenate([[0.0], t.c])
    A = np.zeros((3, 3))
    A[1, :1], A[2, :2] = t.a_lower
    b = t.b_sol
    assert np.allclose(A.sum(1), c)
    assert np.isclose(b.sum(), 1) and np.isclose(b @ c, 1 / 2)
    assert np.isclose(b @ c**2, 1 / 3) and np.isclose(b @ A @ c, 1 / 6)
    np.testing.assert_allclose(b - t.b_error, [0.5, 0.5, 0.0])
    assert dp.SSPRK3().order(None) == 3


def test_ssprk3_reproduces_the_builtin_integrator_eulerian(shear):
    """Periodic viscous Tait shear, Eulerian, MOOD off, 20 fixed steps: the final state agrees to
    round-off (measured 2.2e-15 relative).  In the ODE view the Eulerian positions have an exactly
    zero derivative and stay bit-identical; the built-in Shu–Osher combination 3/4 x + 1/4 x moves
    them by round-off (measured 1 ulp, harmless: the Eulerian geometry is computed once)."""
    p, ref = shear["diffrax"]["p"], shear["builtin"]["p"]
    assert rel_diff(p, ref) < 1e-13
    np.testing.assert_array_equal(np.asarray(p.x), np.asarray(shear["pb"].particles.x))
    assert shear["diffrax"]["ke"] == pytest.approx(shear["builtin"]["ke"], rel=1e-13)


@pytest.mark.slow   # CI time; the Eulerian equivalence stays in the default suite
def test_ssprk3_reproduces_the_builtin_integrator_lagrangian():
    """The same case with moving particles (frame = lagrangian, neighbour list rebuilt at every
    evaluation with the same fixed-capacity spec), through ``ode_term`` + ``diffrax.diffeqsolve``
    with a constant step: agreement to round-off (measured 3.8e-15)."""
    pb0 = periodic_shear_problem()
    pb = dataclasses.replace(pb0, scheme=dataclasses.replace(pb0.scheme, frame="lagrangian"))
    ref = jax.jit(make_simulate(pb, n_steps=N_STEPS, checkpoint="none"))(pb.params, pb.particles).particles
    term, y0, args = dp.ode_term(pb)

    @jax.jit
    def run(y0, args):
        sol = diffrax.diffeqsolve(term, dp.SSPRK3(), 0.0, pb.t_end, pb.t_end / N_STEPS, y0, args,
                                  max_steps=N_STEPS + 1)
        return dp.final_particles(pb, sol, args["params"]), sol.stats["num_steps"]

    p, n = run(y0, args)
    assert int(n) == N_STEPS
    assert float(jnp.max(jnp.abs(p.x - pb.particles.x))) > 1e-3  # the particles did move
    assert rel_diff(p, ref) < 1e-13


def test_adaptive_tsit5_differs_by_the_ssprk3_truncation_error(shear):
    """Tsit5 with PIDController(rtol=1e-8, atol=1e-10) runs the shear case to t_end (measured 11
    accepted steps, none rejected).  It is a different (5th-order) integrator, so it agrees with
    the 20-step SSP-RK3 solution only up to SSP-RK3's global error.  Richardson: with e(N) ~ C/N^3,
    y_RK3(N) - y_exact ~ 8/7 (y_RK3(N) - y_RK3(2N)); measured |Tsit5 - RK3(20)| = 6.2e-7 against
    8/7 x 5.5e-7 = 6.3e-7, and |Tsit5 - RK3(40)| = 1.1e-7 ~ 1/8 of it plus Tsit5's own ~4e-8
    (Tsit5 vs Dopri5 at the same tolerances)."""
    pb = shear["pb"]
    rk3_n = shear["diffrax"]["p"]
    rk3_2n = dp.final_particles(pb, dp.solve(pb, n_steps=2 * N_STEPS))
    sol = dp.solve(pb, diffrax.Tsit5(), n_steps=N_STEPS, adaptive=True, rtol=1e-8, atol=1e-10)
    assert sol.result == diffrax.RESULTS.successful
    assert float(sol.ts[-1]) == pb.t_end
    tsit5 = dp.final_particles(pb, sol)
    richardson = 8 / 7 * rel_diff(rk3_2n, rk3_n)   # estimated global error of RK3(20)
    d_n, d_2n = rel_diff(tsit5, rk3_n), rel_diff(tsit5, rk3_2n)
    assert 1e-8 < richardson < 1e-5
    assert 0.7 * richardson < d_n < 1.3 * richardson
    assert d_2n < 0.25 * d_n


def test_checkpointed_adjoint_gradient_matches_builtin(shear):
    """d ke(t_end) / d(physics.mu, eos.c0) by reverse mode through diffrax's
    RecursiveCheckpointAdjoint equals the built-in make_simulate gradient (measured: mu 1.9e-16,
    c0 1.8e-15 relative)."""
    g, ref = shear["diffrax"]["grad"], shear["builtin"]["grad"]
    assert np.all(np.abs(ref) > 0)
    np.testing.assert_allclose(g, ref, rtol=1e-10)


def test_mood_is_rejected():
    pb0 = periodic_shear_problem()
    pb = dataclasses.replace(pb0, scheme=dataclasses.replace(pb0.scheme, limiter="mood"))
    with pytest.raises(InputError, match="limiter='mood'"):
        dp.ode_term(pb)
    with pytest.raises(InputError, match="n_steps=0"):
        dp.make_solve(pb0, n_steps=0)


def test_geometry_per_step_is_rejected_in_a_moving_frame():
    """``scheme.geometry_update = "step"`` holds a geometry over an SSP-RK3 step, which a vector
    field does not have: a clear error, not a silently per-stage geometry."""
    pb0 = periodic_shear_problem()
    pb = dataclasses.replace(pb0, scheme=dataclasses.replace(pb0.scheme, frame="lagrangian", geometry_update="step"))
    with pytest.raises(InputError, match="geometry_update='step'"):
        dp.ode_term(pb)


@pytest.mark.slow
def test_mirror_walls_couette_matches_builtin_with_gradient():
    """Start-up Couette flow with mirror-wall ghosts (regenerated inside the vector field and when a
    state is read back): final state to round-off (measured 2.5e-15 fluid, 1.5e-15 with the ghosts) and
    d ke / d wall velocity (tangential components; the wall-normal ones sit on the |u.n| kink)."""
    pb = couette_problem()
    sim = make_simulate(pb, n_steps=N_STEPS, checkpoint="step")
    sol_fn = dp.make_solve(pb, n_steps=N_STEPS)

    def loss(f, uw):
        prm = with_param(pb.params, "boundary.wall_velocity", uw)
        p = f(prm)
        return kinetic_energy(p, prm), p

    uw = pb.params["boundary.wall_velocity"]
    (k1, p1), g1 = jax.jit(jax.value_and_grad(lambda u: loss(lambda prm: sim(prm, pb.particles).particles, u),
                                              has_aux=True))(uw)
    (k2, p2), g2 = jax.jit(jax.value_and_grad(
        lambda u: loss(lambda prm: dp.final_particles(pb, sol_fn(prm, pb.particles), prm), u), has_aux=True))(uw)
    assert rel_diff(p2, p1) < 1e-13
    assert rel_diff(p2, p1, fluid_only=False) < 1e-13  # the ghosts are regenerated identically too
    assert abs(float(g1[1, 0])) > 0
    np.testing.assert_allclose(np.asarray(g2[:, 0]), np.asarray(g1[:, 0]), rtol=1e-10)
