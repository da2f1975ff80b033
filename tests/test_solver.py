"""Solver-core physics: free-stream preservation, conservation, the MLSPH-ALE/SPH-ALE
equivalence (thesis eq. 4.27), and loud failure handling."""

from __future__ import annotations

import json

import h5py
import jax.numpy as jnp
import numpy as np
import pytest

import mlsph_jax
from mlsph_jax import Domain, Kind, Params, make_particles
from mlsph_jax import neighbors as nb
from mlsph_jax.cli import DEFAULT_CONFIG
from mlsph_jax.eos import get_eos, to_conservative
from mlsph_jax.integrate import StepControl, initial_carry, make_chunk, static_geometry
from mlsph_jax.rhs import evaluate
from mlsph_jax.scheme import Scheme
from mlsph_jax.simulation import Problem, Simulation

GAS = Params({"eos.gamma": 1.4})


def cloud(n1=14, jitter=0.35, seed=0):
    rng = np.random.default_rng(seed)
    g = (np.stack(np.meshgrid(np.arange(n1), np.arange(n1), indexing="ij"), -1).reshape(-1, 2) + 0.5) / n1
    x = (g + rng.uniform(-jitter, jitter, g.shape) / n1) % 1.0
    return x, np.full(len(x), 1.0 / len(x))


DOMAIN = Domain((0.0, 0.0), (1.0, 1.0), (True, True))


def neighbours(x, vol, scheme):
    h = scheme.beta * np.sqrt(vol)
    _, nl = nb.allocate(x, h, DOMAIN, support=scheme.support)
    return nl


def smooth_state(x, seed=1):
    rng = np.random.default_rng(seed)
    rho = 1.0 + 0.2 * np.sin(2 * np.pi * x[:, 0]) * np.cos(2 * np.pi * x[:, 1]) + 0.02 * rng.uniform(size=len(x))
    vel = 0.3 * np.stack([np.sin(2 * np.pi * x[:, 1]), np.cos(2 * np.pi * x[:, 0])], 1)
    p = 1.0 + 0.1 * np.cos(2 * np.pi * x[:, 0])
    return to_conservative(jnp.asarray(rho), jnp.asarray(vel), jnp.asarray(p), get_eos("ideal_gas"), GAS)


SCHEMES = [
    Scheme(method="mlsph_ale", frame="eulerian", eos="ideal_gas"),
    Scheme(method="mlsph_ale", frame="lagrangian", eos="ideal_gas"),
    Scheme(method="sph_ale", beta=2.0, frame="eulerian", eos="ideal_gas"),
    Scheme(method="sph_ale", beta=2.0, frame="lagrangian", eos="ideal_gas"),
]


@pytest.mark.parametrize("scheme", SCHEMES, ids=lambda s: f"{s.method}-{s.frame}")
def test_uniform_state_stays_uniform(scheme):
    """Free-stream preservation on a randomly perturbed cloud (self-flux on, SPEC §5.5):
    every bracket G_ij - F_i vanishes for a uniform state, and w_ij - w_i vanishes for a
    uniform frame velocity, so dU/dt = 0 and dV/dt = 0 to round-off; particles translate."""
    x, vol = cloud()
    n = len(x)
    vel = np.tile([0.3, -0.2], (n, 1))
    U = to_conservative(jnp.full(n, 1.3), jnp.asarray(vel), jnp.full(n, 0.8), get_eos("ideal_gas"), GAS)
    p = make_particles(x, vol, U)
    dx, dvol, dq = evaluate(p, GAS, neighbours(x, vol, scheme), scheme, DOMAIN)
    assert np.abs(np.asarray(dq)).max() < 1e-12 * np.abs(np.asarray(p.q)).max()
    assert np.abs(np.asarray(dvol)).max() < 1e-13 * vol.max()
    if scheme.frame == "lagrangian":  # the interpolated velocity reproduces a constant
        np.testing.assert_allclose(np.asarray(dx), vel, rtol=0, atol=1e-13)
    else:
        assert np.all(np.asarray(dx) == 0)


@pytest.mark.parametrize("scheme", [SCHEMES[0], SCHEMES[2]], ids=lambda s: s.method)
def test_uniform_state_stays_uniform_over_steps(scheme):
    """Ten SSP-RK3 steps of a uniform flow keep density, velocity and pressure uniform."""
    x, vol = cloud(12)
    n = len(x)
    U = to_conservative(jnp.ones(n), jnp.tile(jnp.array([0.5, 0.25]), (n, 1)), jnp.ones(n), get_eos("ideal_gas"), GAS)
    pb = Problem("uniform", make_particles(x, vol, U), GAS, scheme, DOMAIN, t_end=0.02)
    res = Simulation(pb, chunk=10).run(progress=False)
    Uf = np.asarray(res.particles.U)
    assert res.summary["n_steps"] >= 5
    np.testing.assert_allclose(Uf, np.asarray(U), rtol=1e-12, atol=0)


@pytest.mark.parametrize("scheme", [
    Scheme(method="mlsph_ale", frame="eulerian", eos="ideal_gas", self_flux=False),
    Scheme(method="sph_ale", beta=2.0, frame="lagrangian", eos="ideal_gas", self_flux=False),
    Scheme(method="mlsph_ale", frame="lagrangian", eos="ideal_gas", self_flux=False),
], ids=["mlsph_ale-eulerian", "sph_ale-lagrangian", "mlsph_ale-lagrangian"])
def test_conservation_without_self_flux(scheme):
    """With the self-flux off the pair terms are antisymmetric (A_ji = -A_ij, G_ji = G_ij), so
    total mass, momentum and energy in a periodic box change only by round-off (SPEC §5.5)."""
    x, vol = cloud(10)
    p = make_particles(x, vol, smooth_state(x))
    h = scheme.beta * np.sqrt(vol)
    # capacity for the compression of 100 Lagrangian steps (an overflow would stop the chunk)
    nspec, nl = nb.allocate(x, h, DOMAIN, support=scheme.support, headroom=2.5,
                            cell_size=scheme.support * h.max() * 1.5)
    tot0 = np.asarray(p.q.sum(0))
    geom = None if scheme.moving else static_geometry(p, nl, scheme, DOMAIN)
    chunk = make_chunk(scheme, DOMAIN, StepControl(cfl=0.3), 100, nspec=nspec)
    carry = chunk(initial_carry(p), GAS, geom, jnp.asarray(10.0))
    assert int(carry.status) == 0 and int(carry.step) == 100, int(carry.status)
    tot1 = np.asarray(carry.particles.q.sum(0))
    scale = np.abs(np.asarray(p.q)).sum(0)
    assert np.all(np.abs(tot1 - tot0) <= 1e-13 * scale), (tot1 - tot0) / scale
    # and the flow did change (the test is not vacuous)
    assert np.abs(np.asarray(carry.particles.q - p.q)).max() > 1e-3


@pytest.mark.parametrize("frame", ["eulerian", "lagrangian"])
def test_mlsph_ale_with_kernel_shape_functions_is_sph_ale(frame):
    """Thesis eq. 4.27 / 5.84: MLSPH-ALE with N_j = W V_j (kernel approximation, pair-mean h)
    has A_ij = 2 V_i V_j grad_i W_ij and reproduces the SPH-ALE right-hand side to round-off
    (first-order states; the position update compared through the Shepard average)."""
    x, vol = cloud()
    p = make_particles(x, vol, smooth_state(x))
    common = dict(beta=2.0, frame=frame, eos="ideal_gas", reconstruction_degree=0, position_update="shepard")
    a = Scheme(method="mlsph_ale", approximation="kernel", **common)
    b = Scheme(method="sph_ale", **common)
    nl = neighbours(x, vol, a)
    ra = evaluate(p, GAS, nl, a, DOMAIN)
    rb = evaluate(p, GAS, nl, b, DOMAIN)
    for u, v in zip(ra, rb, strict=True):
        u, v = np.asarray(u), np.asarray(v)
        assert np.abs(u - v).max() <= 1e-12 * max(np.abs(v).max(), 1e-300)
    assert np.abs(np.asarray(rb[2])).max() > 1e-3  # non-trivial right-hand side


def test_mls_rhs_differs_from_kernel_rhs():
    """Sanity check that the equivalence above is not vacuous: MLS areas differ from kernel ones."""
    x, vol = cloud()
    p = make_particles(x, vol, smooth_state(x))
    a = Scheme(method="mlsph_ale", beta=2.0, eos="ideal_gas", reconstruction_degree=0)
    b = Scheme(method="sph_ale", beta=2.0, eos="ideal_gas", reconstruction_degree=0)
    nl = neighbours(x, vol, a)
    da = np.asarray(evaluate(p, GAS, nl, a, DOMAIN)[2])
    db = np.asarray(evaluate(p, GAS, nl, b, DOMAIN)[2])
    assert np.abs(da - db).max() > 1e-3 * np.abs(db).max()


# --- bad input and failures ---------------------------------------------------------------------

def test_initial_state_errors():
    x = np.linspace(0, 1, 10)[:, None]
    U = np.ones((10, 3))
    with pytest.raises(mlsph_jax.InputError, match="vol"):
        make_particles(x, np.r_[np.ones(9), 0.0], U)
    with pytest.raises(mlsph_jax.InputError, match="non-finite U at particle 3"):
        make_particles(x, np.ones(10), np.where(np.arange(10)[:, None] == 3, np.nan, U))
    with pytest.raises(mlsph_jax.InputError, match="density .* at particle 4"):
        make_particles(x, np.ones(10), np.where(np.arange(10)[:, None] == 4, -1.0, U))
    with pytest.raises(mlsph_jax.InputError, match="non-finite x"):
        make_particles(np.where(np.arange(10)[:, None] == 2, np.inf, x), np.ones(10), U)


def _tube(tmp_path, **over):
    from mlsph_jax import config
    from mlsph_jax.cases import build_problem

    sets = SMALL_SOD + [f"{k}={v}" for k, v in over.items()]
    cfg = config.loads(DEFAULT_CONFIG, sets)
    return cfg, build_problem(cfg)


# the CLI's default case (Sod), made small and Eulerian for these tests
SMALL_SOD = ["case.n=40", "scheme.frame=eulerian", "time.t_end=0.1"]


def test_negative_density_in_config_is_a_config_error():
    from mlsph_jax import ConfigError, config

    with pytest.raises(ConfigError, match=r"case.left.rho"):
        config.loads(DEFAULT_CONFIG, ["case.left.rho=-1.0"])


def test_blow_up_stops_loudly_with_last_good_snapshot(tmp_path):
    """A fixed time step far above the CFL limit blows up; the run stops with the step, time
    and particle, summary.json records the failure, and the final snapshot is the last good,
    finite state."""
    from mlsph_jax.simulation import run_problem

    cfg, pb = _tube(tmp_path, **{"time.dt": 0.02, "output.snapshots": 5})
    with pytest.raises(mlsph_jax.SimulationError) as ei:
        run_problem(pb, cfg, out_dir=tmp_path, quiet=True)
    e = ei.value
    assert e.step is not None and e.step >= 1 and e.time is not None and e.particle is not None
    assert "step" in str(e) and "particle" in str(e)
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["status"].startswith("failed")
    with h5py.File(tmp_path / "fields.h5") as f:
        last = sorted(f["snapshots"])[-1]
        g = f["snapshots"][last]
        assert abs(g.attrs["t"] - e.time) < 1e-12
        for k in ("rho", "p", "vel", "x"):
            assert np.all(np.isfinite(g[k][()]))
        assert np.all(g["rho"][()] > 0)


def test_time_step_underflow_stops_the_run(tmp_path):
    """dt below time.dt_min * t_end is a failure, not an endless loop of tiny steps."""
    from mlsph_jax.simulation import run_problem

    cfg, pb = _tube(tmp_path, **{"time.dt_min": 0.5})
    with pytest.raises(mlsph_jax.SimulationError, match="time step underflow") as ei:
        run_problem(pb, cfg, out_dir=tmp_path, quiet=True)
    assert ei.value.step == 1 and ei.value.time == 0.0


def test_missing_eos_constant_is_named():
    from mlsph_jax import ConfigError, config

    text = DEFAULT_CONFIG.replace('kind = "ideal_gas"\ngamma = 1.4', 'kind = "stiffened_gas"\ngamma = 4.4')
    with pytest.raises(ConfigError, match="eos.pc"):
        config.loads(text)


def test_frozen_particles_do_not_move_or_change(tmp_path):
    cfg, pb = _tube(tmp_path, **{"scheme.frame": "lagrangian"})
    res = Simulation(pb).run(progress=False)
    frozen = np.asarray(pb.particles.kind) == Kind.FROZEN
    np.testing.assert_array_equal(np.asarray(res.particles.x)[frozen], np.asarray(pb.particles.x)[frozen])
    np.testing.assert_array_equal(np.asarray(res.particles.q)[frozen], np.asarray(pb.particles.q)[frozen])


@pytest.mark.parametrize("normal", ["area", "pair"])
def test_rusanov_dissipation_is_never_anti_diffusive(normal):
    """The dissipation 1/2 S (U+ - U-) (n . A) must oppose the jump for every normal: with the
    `pair` normal an MLS area vector pointing away from n_ij (n . A < 0) used to flip its sign."""
    from mlsph_jax.eos import get_eos, to_conservative
    from mlsph_jax.flux import rusanov_dot_area
    from mlsph_jax.state import Params

    eos, P = get_eos("ideal_gas"), Params({"eos.gamma": 1.4})
    Um = to_conservative(jnp.asarray([1.0]), jnp.zeros((1, 2)), jnp.asarray([1.0]), eos, P)
    Up = to_conservative(jnp.asarray([2.0]), jnp.zeros((1, 2)), jnp.asarray([1.0]), eos, P)
    A = jnp.asarray([[-0.3, 0.1]])          # points against the pair direction
    n_pair = jnp.asarray([[1.0, 0.0]])
    G = rusanov_dot_area(Um, Up, None, A, n_pair, eos, P, normal=normal)
    # at rest with equal pressures the mass flux is pure dissipation: -1/2 S (rho+ - rho-) |n . A|
    assert float(G[0, 0]) < 0.0


def test_reverse_pair_index_is_64_bit_when_n_times_k_overflows_int32():
    """The flat index j K + rev of the reverse-pair gather (used by the convective, viscous and
    MLS-area terms alike, mlsph_jax.stencil) must not wrap once N K >= 2^31."""
    import jax

    from mlsph_jax.stencil import flat_reverse_index

    big = jax.ShapeDtypeStruct((2**27, 16), jnp.int32)
    small = jax.ShapeDtypeStruct((1000, 16), jnp.int32)
    assert jax.eval_shape(lambda j, r: flat_reverse_index(j, r, 16), big, big).dtype == jnp.int64
    assert jax.eval_shape(lambda j, r: flat_reverse_index(j, r, 16), small, small).dtype == jnp.int32
    j = jnp.asarray([[2**27 - 1]], jnp.int32)
    assert int(flat_reverse_index(j, jnp.asarray([[15]], jnp.int32), 16)[0, 0]) == 2**31 - 1
