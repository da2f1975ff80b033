"""Local time stepping for steady runs (``time.local_time_stepping``, docs/architecture.md
decision 62): every fluid particle advances by its own CFL step, ``t`` by the smallest."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mlsph_jax import config as config_mod
from mlsph_jax.cases import build_problem
from mlsph_jax.errors import InputError
from mlsph_jax.integrate import _euler, cfl_dt, local_steps, ssp_rk3_step
from mlsph_jax.rhs import rhs
from mlsph_jax.run import setup_run
from mlsph_jax.simulation import Simulation
from mlsph_jax.state import Kind
from mlsph_jax.testing import CONFIG_DIR

jax.config.update("jax_enable_x64", True)

#: a small viscous problem with graded particle sizes and frozen (non-fluid) particles
COARSE_CYLINDER = ("case.n_theta=32", "case.r_far=4.0", "case.mach=0.2", "output.plots=false",
                   "output.progress=false")


@pytest.fixture(scope="module")
def cylinder():
    cfg = config_mod.load(CONFIG_DIR / "cylinder.toml", [*COARSE_CYLINDER, "time.t_end=0.05"])
    return cfg, build_problem(cfg)


def test_local_steps_are_the_per_particle_cfl_limits(cylinder):
    """Their minimum is the global CFL step bit for bit (convective and viscous limits), each is
    the particle's own min(C dx_i / (|u_i| + c_i), C_v rho_i dx_i^2 / mu), and every non-fluid
    (frozen far-field) particle gets 0; on the graded polar layout they span more than 5x."""
    _, pb = cylinder
    p, prm, sch = pb.particles, pb.params, pb.scheme
    steps = np.asarray(local_steps(p, prm, sch, 0.6, 0.125))
    fluid = np.asarray(p.kind) == Kind.FLUID
    assert (~fluid).any() and np.all(steps[~fluid] == 0.0)
    assert steps[fluid].min() == pytest.approx(float(cfl_dt(p, prm, sch, 0.6, 0.125)), rel=1e-14)   # two programs
    U = np.asarray(p.q) / np.asarray(p.vol)[:, None]
    rho = U[:, 0]
    speed = np.hypot(U[:, 1] / rho, U[:, 2] / rho)
    gam = float(prm["eos.gamma"])
    c = np.sqrt(gam * (gam - 1.0) * (U[:, 3] - 0.5 * rho * speed ** 2) / rho)
    dx = np.sqrt(np.asarray(p.vol))
    expect = np.minimum(0.6 * dx / (speed + c), 0.125 * rho * dx ** 2 / float(prm["physics.mu"]))
    np.testing.assert_allclose(steps[fluid], expect[fluid], rtol=1e-12)
    assert steps[fluid].max() > 5 * steps[fluid].min()      # 6.7x here (far field at 4 D)


def test_a_step_with_equal_local_steps_is_the_global_step(cylinder):
    """One SSP-RK3 step with every particle's step equal to dt is the step with the scalar dt,
    bit for bit; with unequal steps the first stage's forward-Euler sub-step of each particle is
    U_i + dt_i L_i (checked on the rhs)."""
    _, pb = cylinder
    p, prm, sch = pb.particles, pb.params, pb.scheme
    setup = setup_run(pb)
    g = setup.geometry_fn(p)
    dt = float(cfl_dt(p, prm, sch, 0.6, 0.125))
    one = jax.jit(lambda d: ssp_rk3_step(p, prm, d, sch, g, pb.boundary)[0])
    a, b = one(jnp.asarray(dt)), one(jnp.full(p.n, dt))
    for f in ("x", "vol", "q"):                           # two programs: to round-off (decision 98)
        ref = np.asarray(getattr(a, f))
        np.testing.assert_allclose(np.asarray(getattr(b, f)), ref, rtol=0, atol=1e-13 * np.abs(ref).max())
    z = pb.boundary.apply(p, prm) if pb.boundary is not None and hasattr(pb.boundary, "apply") else p
    steps = local_steps(z, prm, sch, 0.6, 0.125)
    dz = jax.jit(lambda z: rhs(z, prm, g(z), sch, pb.boundary))(z)
    e = _euler(z, steps, dz)
    fluid = np.asarray(z.kind) == Kind.FLUID
    want = np.asarray(z.q) + np.asarray(steps)[:, None] * np.asarray(dz[2])
    np.testing.assert_allclose(np.asarray(e.q)[fluid], want[fluid], rtol=1e-15, atol=0)
    np.testing.assert_array_equal(np.asarray(e.q)[~fluid], np.asarray(z.q)[~fluid])


def test_stencil_minimum_and_ratio_cap(cylinder):
    """With the geometry each particle takes the smallest step of its stencil, and with a ratio
    no step exceeds ratio x the smallest; ratio 1 is the global step everywhere."""
    _, pb = cylinder
    p, prm, sch = pb.particles, pb.params, pb.scheme
    g = setup_run(pb).geometry_fn(p)(p)
    own = np.asarray(local_steps(p, prm, sch, 0.6, 0.125))
    fluid = np.asarray(p.kind) == Kind.FLUID
    s = np.asarray(local_steps(p, prm, sch, 0.6, 0.125, geom=g))
    idx, mask = np.asarray(g.idx), np.asarray(g.mask)
    nb = np.where(mask & fluid[np.where(mask, idx, 0)], own[np.where(mask, idx, 0)], np.inf).min(axis=1)
    np.testing.assert_array_equal(s[fluid], np.minimum(own, nb)[fluid])
    capped = np.asarray(local_steps(p, prm, sch, 0.6, 0.125, geom=g, ratio=2.0))
    assert capped[fluid].max() == 2.0 * own[fluid].min() and np.all(capped <= s)
    one = np.asarray(local_steps(p, prm, sch, 0.6, 0.125, ratio=1.0))
    assert np.all(one[fluid] == own[fluid].min()) and np.all(one[~fluid] == 0.0)


def test_bad_input_names_the_setting(cylinder):
    cfg, pb = cylinder
    with pytest.raises(InputError, match=r"time.local_time_stepping=true: time.dt=0.001"):
        Simulation(pb, dt=1e-3, local_time_stepping=True)
    with pytest.raises(InputError, match=r"time.local_step_ratio=0.5"):
        Simulation(pb, local_time_stepping=True, local_step_ratio=0.5)
    tg = config_mod.load(CONFIG_DIR / "taylor_green_2d.toml", ["case.n=8", "scheme.frame=lagrangian"])
    with pytest.raises(InputError, match=r"scheme.frame='lagrangian'"):
        Simulation(build_problem(tg), local_time_stepping=True)
    from mlsph_jax.errors import ConfigError

    with pytest.raises(ConfigError, match=r"time.local_time_stepping=true: time.dt=0.001"):
        config_mod.load(CONFIG_DIR / "cylinder.toml", ["time.dt=0.001"])
    with pytest.raises(ConfigError, match=r"time.local_time_stepping=true: scheme.frame='ale_shift'"):
        config_mod.load(CONFIG_DIR / "cylinder.toml", ["scheme.frame=ale_shift"])
    from mlsph_jax.cli import main

    assert main(["sensitivity", str(CONFIG_DIR / "cylinder.toml"), "--wrt", "physics.mu", "--of", "cd",
                 "--set", *COARSE_CYLINDER, "time.local_time_stepping=true"]) == 2


@pytest.mark.slow
def test_local_steps_reach_the_global_steady_state_in_fewer_steps():
    """The cylinder at n_theta = 32 with the config's far field (40 D), Mach 0.2, run to
    case.steady_tol = 1e-3 with the global step and with local steps (ratio 4): the same steady
    coefficients within 1 % (each run stops at a residual of 1e-3 per unit time; measured
    differences 0.2 %) in at most 60 % of the steps (measured 1,369 against 3,192; ~6 min)."""
    from mlsph_jax.simulation import run_problem

    base = ["case.n_theta=32", "case.mach=0.2", "time.t_end=80", "output.snapshots=80", "case.steady_tol=1e-3",
            "output.plots=false", "output.progress=false"]
    runs = []
    for extra in (["time.local_time_stepping=false"], ["time.local_time_stepping=true", "time.local_step_ratio=4"]):
        cfg = config_mod.load(CONFIG_DIR / "cylinder.toml", [*base, *extra])
        runs.append(run_problem(build_problem(cfg), cfg, quiet=True).summary)
    glob, loc = runs
    assert glob["steady_state"]["converged"] and loc["steady_state"]["converged"]
    assert loc["n_steps"] <= 0.6 * glob["n_steps"], (loc["n_steps"], glob["n_steps"])
    for k in ("cd", "cd_pressure", "cp_front", "cp_base", "recirculation_length"):
        assert loc["metrics"][k] == pytest.approx(glob["metrics"][k], rel=1e-2), k
