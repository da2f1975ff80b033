"""Moving particles (Lagrangian and particle-shifting ALE frames; issue 14, docs/moving_particles.md):
uniform states and volumes on moving disordered particles, one frame velocity for particles,
fluxes and volumes, the MLS degree fallback on stretched stencils, and the §4.5.1 Taylor-Green
vortex in the Lagrangian and shifted frames (coarse in the default run, the 50 x 50 targets slow).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial import ConvexHull, Voronoi

from mlsph_jax import config
from mlsph_jax import neighbors as nb
from mlsph_jax.approximation import mls
from mlsph_jax.cases import build_problem
from mlsph_jax.eos import get_eos, to_conservative
from mlsph_jax.frames import shifting_velocity
from mlsph_jax.kernels import get_kernel
from mlsph_jax.rhs import geometry, rhs
from mlsph_jax.run import setup_run
from mlsph_jax.simulation import Simulation, run_problem
from mlsph_jax.testing import jittered_lattice

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "taylor_green_2d_mlsph.toml"
L = 2.0 * np.pi


def voronoi_areas(x, length=L):
    """Voronoi cell areas of points in the periodic square [0, length)^2 (the geometric measure)."""
    n = len(x)
    offs = [(a, b) for a in (-1, 0, 1) for b in (-1, 0, 1)]
    pts = np.concatenate([np.mod(x, length) + length * np.asarray(o, float) for o in offs])
    vor = Voronoi(pts)
    c = offs.index((0, 0))
    return np.array([ConvexHull(vor.vertices[vor.regions[vor.point_region[c * n + i]]]).volume
                     for i in range(n)])


def _uniform_problem(n, sets, vel=(1.0, 0.5), jitter=0.25, t_end=0.3):
    """The §4.5.1 config's scheme on a jittered periodic n x n cloud with Voronoi volumes and a
    uniform state rho = 1, u = ``vel`` (so every error below is the scheme's, not the flow's)."""
    cfg = config.load(CONFIG, [f"case.n={n}", f"time.t_end={t_end}", "scheme.reconstruction_degree=1", *sets,
                               "output.progress=false", "output.plots=false"])
    pb = build_problem(cfg)
    x = np.mod(jittered_lattice(n, jitter, seed=1, upper=L, dim=2), L)
    vol = voronoi_areas(x)
    u = np.tile(np.asarray(vel, float), (len(x), 1))
    U = to_conservative(jnp.ones(len(x)), jnp.asarray(u), None, get_eos("tait"), pb.params)
    pb.particles = pb.particles.replace(x=jnp.asarray(x), vol=jnp.asarray(vol), q=U * jnp.asarray(vol)[:, None])
    return pb, x, vol, np.asarray(U)


@pytest.mark.parametrize("position_update", ["mls", "w_i"])
def test_uniform_flow_on_lagrangian_disordered_particles_keeps_state_and_voronoi_volumes(position_update):
    """A uniform flow on a disordered cloud in the Lagrangian frame is a rigid translation: the
    state stays uniform, each particle moves by u t, and each volume V_i (eq. 4.32) stays equal to
    the Voronoi area of the moved particles, to round-off."""
    pb, x0, vol0, U0 = _uniform_problem(12, ["scheme.frame=lagrangian", f"scheme.position_update={position_update}"])
    res = Simulation(pb).run(progress=False)
    p, t = res.particles, res.summary["t_final"]
    assert res.summary["n_steps"] >= 10
    np.testing.assert_allclose(np.asarray(p.U), U0, rtol=0, atol=1e-12)
    d = (np.asarray(p.x) - x0 - np.array([1.0, 0.5]) * t + 0.5 * L) % L - 0.5 * L
    assert np.abs(d).max() < 1e-12
    np.testing.assert_allclose(np.asarray(p.vol), voronoi_areas(np.asarray(p.x)), rtol=1e-12)
    np.testing.assert_allclose(np.asarray(p.vol), vol0, rtol=1e-13)


@pytest.mark.parametrize("projection", [True, False])
def test_uniform_state_on_shifted_disordered_particles_volumes_against_voronoi(projection):
    """Shifting frame (the §4.5.1 config: xu drift, C = 1, particles moved with their own w_i)
    on a strongly jittered cloud: the drift rearranges the particles (the Voronoi areas become
    more uniform: their spread drops from 12.5 % to ~5 %), the state stays uniform to round-off
    because fluxes and volumes use the particles' own velocity (eq. 4.36, 4.32), and the volumes
    follow the geometry only as well as eq. 4.32's discrete divergence of the particle-scale drift
    can: measured V_i / A_voronoi - 1 of 0.079 rms (0.18 max) at t = 0.3 on 12 x 12.  The total
    volume: kept to round-off by the config's conservation projection (decision 112); without it
    it drifts by the self-flux closure defect -w_i . sum_j A_ij, measured 2.8e-3.  The bounds
    below are those numbers with ~25 % margin; docs/moving_particles.md shows that replacing V by
    the Voronoi areas does not improve the Taylor-Green errors (and ruins the pressure if the
    mass is kept)."""
    pb, x0, vol0, U0 = _uniform_problem(12, [f"scheme.conservation_projection={str(projection).lower()}"])
    assert pb.scheme.frame == "ale_shift" and pb.scheme.position_update == "w_i"
    res = Simulation(pb).run(progress=False)
    p, t = res.particles, res.summary["t_final"]
    np.testing.assert_allclose(np.asarray(p.U), U0, rtol=0, atol=1e-12)
    x = np.asarray(p.x)
    d = (x - x0 - np.array([1.0, 0.5]) * t + 0.5 * L) % L - 0.5 * L
    assert np.sqrt(np.mean(d ** 2)) > 0.03 * L / 12, "the shifting drift did not act"
    va = voronoi_areas(x)
    assert np.std(va) / np.mean(va) < 0.8 * np.std(vol0) / np.mean(vol0)   # the layout became more regular
    rel = np.asarray(p.vol) / va - 1.0
    assert np.sqrt(np.mean(rel ** 2)) < VOLUME_RMS_BOUND
    assert np.abs(rel).max() < VOLUME_MAX_BOUND
    total = abs(np.sum(np.asarray(p.vol)) / L ** 2 - 1.0)
    if projection:
        assert total < 1e-13, total
    else:
        assert 1e-4 < total < TOTAL_VOLUME_BOUND, total


VOLUME_RMS_BOUND, VOLUME_MAX_BOUND, TOTAL_VOLUME_BOUND = 0.1, 0.23, 3.5e-3


def _rhs_on_cloud(sets, n=12):
    cfg = config.load(CONFIG, [f"case.n={n}", *sets])
    pb = build_problem(cfg)
    x = np.mod(jittered_lattice(n, 0.25, seed=2, upper=L, dim=2), L)
    vol = voronoi_areas(x)
    rng = np.random.default_rng(3)
    u = 0.5 * np.stack([np.sin(x[:, 1]), np.cos(x[:, 0])], 1) + 0.05 * rng.uniform(-1, 1, x.shape)
    U = to_conservative(jnp.asarray(1.0 + 0.01 * np.cos(x[:, 0])), jnp.asarray(u), None, get_eos("tait"), pb.params)
    p = pb.particles.replace(x=jnp.asarray(x), vol=jnp.asarray(vol), q=U * jnp.asarray(vol)[:, None])
    sch = pb.scheme
    _, nl = nb.allocate(x, sch.beta * np.sqrt(vol), pb.domain, support=sch.support)
    geom = geometry(p.x, p.vol, nl, sch, pb.domain)
    return p, pb, geom, u


@pytest.mark.parametrize("position_update", ["mls", "shepard"])
def test_interpolated_motion_is_the_velocity_of_fluxes_and_volumes(position_update):
    """With an interpolating position update (eq. 4.28) the particles move with the interpolant of
    u plus the un-interpolated shifting drift, and eq. 4.32 uses that same velocity:
    dV_i/dt = sum_j ((v_i + v_j)/2 - v_i) . A_ij with v = dx/dt (architecture decision 44).
    ``mls_literal`` (the thesis as printed) moves the particles the same way but keeps w_i = u_i +
    dw_i in eq. 4.32, so its volume rate differs.  (Without the config's conservation projection,
    which adds one uniform relative rate to every row: tests/test_conservation_projection.py.)"""
    sets = ["scheme.frame=ale_shift", f"scheme.position_update={position_update}",
            "scheme.conservation_projection=false"]
    p, pb, geom, u = _rhs_on_cloud(sets)
    dx, dv, _ = rhs(p, pb.params, geom, pb.scheme)
    dx, dv = np.asarray(dx), np.asarray(dv)
    drift = np.asarray(shifting_velocity(jnp.asarray(u), geom, p.kind, pb.scheme, p.vol))
    interp = np.einsum("nk,nkd->nd", np.asarray(geom.interp), u[np.asarray(geom.jsafe)])
    np.testing.assert_allclose(dx, interp + drift, rtol=0, atol=1e-13)
    A, j, pm = np.asarray(geom.A), np.asarray(geom.jsafe), np.asarray(geom.pair_mask)
    expect = np.einsum("nkd,nkd->n", np.where(pm[..., None], 0.5 * (dx[j] - dx[:, None]), 0.0), A)
    np.testing.assert_allclose(dv, expect, rtol=0, atol=1e-13 * np.abs(expect).max())
    if position_update == "mls":
        p2, pb2, geom2, _ = _rhs_on_cloud(["scheme.frame=ale_shift", "scheme.position_update=mls_literal",
                                           "scheme.conservation_projection=false"])
        dx2, dv_literal, _ = rhs(p2, pb2.params, geom2, pb2.scheme)
        wd = u + drift
        np.testing.assert_allclose(np.asarray(dx2), np.einsum("nk,nkd->nd", np.asarray(geom.interp), wd[j]),
                                   rtol=0, atol=1e-13)
        assert np.abs(np.asarray(dv_literal) - dv).max() > 1e-3 * np.abs(dv).max()


def test_scheme_defaults_move_particles_with_their_own_velocity():
    """Defaults of the moving frames (decision 44, decision 2): particles move with their own w_i
    and the MLS fallback threshold is 1e-2; a lattice keeps its full degree with it (below)."""
    from mlsph_jax.scheme import Scheme

    s = Scheme()
    assert s.position_update == "w_i" and s.rcond == 1e-2


def test_fallback_drops_the_cubic_level_on_a_three_column_stencil():
    """The stencil of a particle at a hyperbolic stagnation point after Lagrangian stretching
    (t ~ 1: three columns 2.7 dx apart inside the support, rows 0.37 dx apart, slightly curved)
    is nearly degenerate for a cubic in x (pivot ratio ~1e-3): the old threshold rcond = 1e-6
    keeps the cubic, rcond = 1e-2 drops it to quadratic; a square lattice stays cubic with both
    (its smallest pivot ratio is 0.33, tabulated in docs/moving_particles.md)."""
    kern = get_kernel("cubic_spline")
    h = 2.0
    cols = np.array([-2.7, 0.0, 2.7])
    rows = 0.37 * np.arange(-10, 11)
    X, Y = np.meshgrid(cols, rows, indexing="ij")
    X = X + 0.02 * Y ** 2 * np.sign(X)                       # the columns bend outwards
    dx = np.stack([X.ravel(), Y.ravel()], 1)
    dx = dx[np.hypot(dx[:, 0], dx[:, 1]) < 2.0 * h]
    g = np.stack(np.meshgrid(np.arange(-4, 5), np.arange(-4, 5), indexing="ij"), -1).reshape(-1, 2).astype(float)
    g = g[np.hypot(g[:, 0], g[:, 1]) < 2.0 * h]

    def degree(offsets, rcond):
        _, deg, _ = mls.stencil_fit(jnp.asarray(offsets), jnp.ones(len(offsets), bool), jnp.asarray(h),
                                    kernel=kern, degree=3, rcond=rcond)
        return int(deg)

    assert degree(dx, 1e-6) == 3 and degree(dx, 1e-2) == 2
    assert degree(g, 1e-6) == 3 and degree(g, 1e-2) == 3


def test_linear_area_vectors_keep_the_closure_on_a_stretched_layout():
    """The closure defect |sum_j A_ij| (zero on a lattice; it is what the self-flux term
    compensates) on the 16 x 16 lattice stretched like the Lagrangian Taylor-Green layout at
    t = 1 (exact trajectories): cubic-basis area vectors have a defect ~10x that of the
    linear-basis ones (docs/moving_particles.md, 'layouts')."""
    from scipy.integrate import solve_ivp

    n = 16
    cfg = config.load(CONFIG, [f"case.n={n}", "scheme.frame=eulerian"])
    pb = build_problem(cfg)
    x0 = np.asarray(pb.particles.x)
    f = lambda t, y: np.stack([np.sin(y[0::2]) * np.cos(y[1::2]), -np.cos(y[0::2]) * np.sin(y[1::2])], 1).ravel()
    x = np.mod(solve_ivp(f, (0.0, 1.0), x0.ravel(), rtol=1e-9, atol=1e-11).y[:, -1].reshape(-1, 2), L)
    vol = voronoi_areas(x)
    out = {}
    for deg in (1, 3):
        cfg = config.load(CONFIG, [f"case.n={n}", "scheme.frame=eulerian", f"scheme.degree={deg}",
                                   "scheme.reconstruction_degree=1"])
        sch = build_problem(cfg).scheme
        _, nl = nb.allocate(x, sch.beta * np.sqrt(vol), pb.domain, support=sch.support)
        A = np.asarray(geometry(jnp.asarray(x), jnp.asarray(vol), nl, sch, pb.domain).A)
        out[deg] = np.median(np.linalg.norm(A.sum(1), axis=1) / np.sqrt(vol))
    assert out[3] > 5.0 * out[1]


# -- the §4.5.1 Taylor-Green vortex ------------------------------------------------------------

def _tg(*sets):
    cfg = config.load(CONFIG, [*sets, "output.plots=false", "output.progress=false", "output.snapshots=1"])
    s = run_problem(build_problem(cfg), cfg, out_dir=None, quiet=True).summary
    assert s["status"] == "ok"
    return s["metrics"], s["conservation"]


def test_coarse_lagrangian_taylor_green():
    """The §4.5.1 config in the Lagrangian frame at 20 x 20 to t = 1 (before the stagnation-point
    columns tear apart, docs/moving_particles.md §4; 108 steps, ~12 s each run under load).
    Measured with the config's scheme: E_k error 0.114, pressure L2 0.050; with the scheme before
    the fix (quadratic areas and reconstruction, the thesis' literal motion, rcond 1e-6): 0.778 and
    0.365 (2026-12-05, `mlsph run configs/taylor_green_2d_mlsph.toml --set case.n=20 time.t_end=1.0
    scheme.frame=lagrangian [scheme.degree=2 scheme.reconstruction_degree=2
    scheme.position_update=mls_literal scheme.rcond=1e-6]`).  Bounds: the measured values + 30 %,
    and the old scheme must exceed them (the test rejects today's behaviour before the fix)."""
    m, c = _tg("case.n=20", "time.t_end=1.0", "scheme.frame=lagrangian")
    assert m["ke_rel_error"] < 0.114 * 1.3
    assert m["l2_pressure_error"] < 0.050 * 1.3
    assert abs(c["mass"]) < 1e-12
    old, _ = _tg("case.n=20", "time.t_end=1.0", "scheme.frame=lagrangian", "scheme.degree=2",
                 "scheme.reconstruction_degree=2", "scheme.position_update=mls_literal", "scheme.rcond=1e-6")
    assert old["ke_rel_error"] > 0.114 * 1.3 and old["l2_pressure_error"] > 0.050 * 1.3


# -- 50 x 50 targets (slow) ----------------------------------------------------------------------

@pytest.mark.slow
def test_taylor_green_50_shifting_frame_meets_the_targets():
    """Issue 14 target: 50 x 50, t = 2, shifting frame: E_k error <= 1 %, pressure L2 <= 2 %
    (measured 0.45 % / 1.07 %), mass kept to round-off by the config's conservation projection
    (decision 112; -1.6e-4 without it)."""
    m, c = _tg()
    assert m["ke_rel_error"] < 0.01 and m["l2_pressure_error"] < 0.02
    assert abs(c["mass"]) < 1e-12


@pytest.mark.slow
def test_taylor_green_50_lagrangian_frame_to_t1():
    """Lagrangian frame, 50 x 50, up to t = 1 (the columns at the hyperbolic stagnation points
    separate by more than the support after t ~ 1.2 with beta = 2; docs/moving_particles.md):
    E_k error <= 1 %, pressure L2 <= 2 %."""
    m, _ = _tg("scheme.frame=lagrangian", "time.t_end=1.0")
    assert m["ke_rel_error"] < 0.01 and m["l2_pressure_error"] < 0.02


def test_verlet_skin_lists_give_the_trajectory_of_per_stage_rebuilds():
    """The driver's chunk restricts a Verlet-skin candidate list to each stage's stencil instead of
    rebuilding the list (issue 15): the same stencils in the same slots, hence the trajectory of
    per-stage rebuilds (shifting frame, 12 x 12 Taylor-Green, 30 steps) bit for bit under XLA:CPU's
    default code generator, and to round-off in the test run's (decision 98; a stencil that differed
    would change the trajectory by far more).  A skin of
    0.02 support h (the driver's is 0.3) makes the candidates go stale every step or two, so
    the rebuild test is exercised: without rebuilds (the rebuild threshold patched away) the
    trajectory differs by far more than the round-off tolerance."""
    from mlsph_jax import verlet
    from mlsph_jax.integrate import StepControl, initial_carry, make_chunk
    from mlsph_jax.run import setup_run

    cfg = config.load(CONFIG, ["case.n=12", "output.plots=false", "output.progress=false"])
    pb = build_problem(cfg)
    setup = setup_run(pb, headroom=1.3, min_moving_headroom=True)
    runs = {}
    for skin in (0.0, 0.02):
        chunk = make_chunk(pb.scheme, pb.domain, StepControl(cfl=0.3), 30, nspec=setup.nspec, skin=skin)
        runs[skin] = chunk(initial_carry(pb.particles), pb.params, None, jnp.asarray(10.0))
    a, b = runs[0.0], runs[0.02]
    assert int(a.status) == 0 and int(a.step) == 30
    moved = float(jnp.sqrt(jnp.max(jnp.sum((a.particles.x - pb.particles.x) ** 2, axis=1))))
    skin = 0.02 * pb.scheme.support * pb.scheme.beta * float(jnp.sqrt(pb.particles.vol).max())
    assert moved > 5 * skin, (moved, skin)          # the candidates were rebuilt many times
    for f in ("x", "vol", "q"):
        ref = np.asarray(getattr(a.particles, f))
        np.testing.assert_allclose(np.asarray(getattr(b.particles, f)), ref, rtol=0, atol=1e-13 * np.abs(ref).max())
    np.testing.assert_array_equal(np.asarray(a.particles.ppd), np.asarray(b.particles.ppd))
    assert float(a.t) == pytest.approx(float(b.t), rel=1e-13) and int(b.status) == 0   # dt from the CFL
    # negative control: the same skin, candidates built once and never rebuilt (read at trace time)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(verlet, "_SKIN_SAFETY", 1e30)
        chunk = make_chunk(pb.scheme, pb.domain, StepControl(cfl=0.3), 30, nspec=setup.nspec, skin=0.02)
        c = chunk(initial_carry(pb.particles), pb.params, None, jnp.asarray(10.0))
    ref = np.asarray(a.particles.q)
    assert int(c.status) == 0        # measured: 6.5e-3 of max |q| apart, 6.5e10 times the tolerance above
    assert np.abs(np.asarray(c.particles.q) - ref).max() > 1e-6 * np.abs(ref).max()


@pytest.mark.slow   # 40-94 s (CI time); the default suite runs geometry_update = "step" in the
#                     temporal-order test below (first order with the geometry frozen over a step)
def test_geometry_per_step_reuses_the_start_geometry_in_all_three_stages():
    """``scheme.geometry_update = "step"`` (issue 15, opt-in): the SSP-RK3 step is the one whose
    three stages use the geometry (list, area vectors, fit) of the step's start positions, to
    round-off, while the states, frame velocities and positions still advance stage by stage; it
    differs from the default per-stage geometry (the setting acts), and the driver's chunk (with
    its Verlet-skin lists) takes the same step (shifting frame, 12 x 12 Taylor-Green)."""
    import dataclasses

    import jax

    from mlsph_jax.integrate import StepControl, initial_carry, make_chunk, make_stage_geometry, ssp_rk3_step
    from mlsph_jax.run import setup_run

    cfg = config.load(CONFIG, ["case.n=12", "output.plots=false", "output.progress=false"])
    pb = build_problem(cfg)
    per_stage = pb.scheme
    per_step = dataclasses.replace(per_stage, geometry_update="step")
    setup = setup_run(pb, headroom=1.3, min_moving_headroom=True)
    geom_fn = make_stage_geometry(per_stage, pb.domain, setup.nspec)
    p, dt = pb.particles, 2e-3

    @jax.jit
    def steps(p, params):
        lagged = ssp_rk3_step(p, params, dt, per_step, geom_fn)[0]
        g0 = geom_fn(p)
        frozen = ssp_rk3_step(p, params, dt, per_stage, lambda z: g0)[0]     # reference: start geometry
        fresh = ssp_rk3_step(p, params, dt, per_stage, geom_fn)[0]          # the default
        return lagged, frozen, fresh

    lagged, frozen, fresh = steps(p, pb.params)
    for f in ("x", "vol", "q"):
        a, b, c = (np.asarray(getattr(s, f)) for s in (lagged, frozen, fresh))
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-14 * np.abs(b).max())
        assert np.abs(a - c).max() > 1e-10 * np.abs(c).max(), f          # the setting changes the step
    # the driver's chunk (Verlet-skin candidates restricted at the step's start) takes the same step
    chunk = make_chunk(per_step, pb.domain, StepControl(dt_fixed=dt), 1, nspec=setup.nspec)
    out = chunk(initial_carry(p), pb.params, None, jnp.asarray(10.0))
    assert int(out.status) == 0 and int(out.step) == 1
    for f in ("x", "vol", "q"):
        ref = np.asarray(getattr(lagged, f))
        np.testing.assert_allclose(np.asarray(getattr(out.particles, f)), ref, rtol=0, atol=1e-14 * np.abs(ref).max())


def test_ssp_rk3_is_third_order_with_per_stage_geometry_and_first_order_with_it_frozen():
    """Time order of a moving step (decision 79): in the Lagrangian frame (a smooth right-hand
    side) the local error of one step in the conserved densities q, |S(dt) q - S(dt/2) S(dt/2) q|
    ~ dt^(p+1), shrinks 16x when
    dt halves with the default per-stage geometry (SSP-RK3, p = 3) but only 4x with
    ``scheme.geometry_update = "step"`` (p = 1: the geometry lags by O(dt) in every stage), which
    is why the cheaper setting is not the default (12 x 12 Taylor-Green vortex)."""
    import dataclasses

    import jax

    from mlsph_jax.integrate import make_stage_geometry, ssp_rk3_step
    from mlsph_jax.run import setup_run

    cfg = config.load(CONFIG, ["case.n=12", "scheme.frame=lagrangian", "output.plots=false", "output.progress=false"])
    pb = build_problem(cfg)
    setup = setup_run(pb, headroom=1.3, min_moving_headroom=True)
    geom_fn = make_stage_geometry(pb.scheme, pb.domain, setup.nspec)

    for update, lo, hi in (("stage", 3.6, 4.4), ("step", 1.7, 2.3)):
        scheme = dataclasses.replace(pb.scheme, geometry_update=update)

        step = jax.jit(lambda p, dt, scheme=scheme: ssp_rk3_step(p, pb.params, dt, scheme, geom_fn)[0])

        def local_error(dt, step=step):
            one = step(pb.particles, jnp.asarray(dt))
            two = step(step(pb.particles, jnp.asarray(dt / 2)), jnp.asarray(dt / 2))
            return float(jnp.max(jnp.abs(one.q - two.q)))

        e1, e2 = local_error(8e-3), local_error(4e-3)
        assert lo < np.log2(e1 / e2) < hi, (update, e1, e2)       # p + 1


def test_smooth_shift_law_keeps_ssp_rk3_third_order_in_time():
    """Time order of the ``ale_shift`` frame with ``scheme.shift_law = "xu_smooth"`` (decision 80):
    over a fixed interval (10 x 10 vortex of the §4.5.1 config, t = 0.16, 10 / 20 / 40 steps) the
    global time error of the conserved densities, |y(dt) - y(dt/2)|, shrinks ~2^3 per halved dt:
    the tapered drift is C^1 where a neighbour crosses the support edge.  The default ``xu`` drift
    jumps there and makes SSP-RK3 order ~1: with ``shift_law=xu`` the same measurement gives
    order 0.34 and fails this test (docs/moving_particles.md §7)."""
    import jax

    from mlsph_jax.integrate import make_stage_geometry, ssp_rk3_step
    from mlsph_jax.run import setup_run

    cfg = config.load(CONFIG, ["case.n=10", "scheme.shift_law=xu_smooth", "output.plots=false",
                               "output.progress=false"])
    pb = build_problem(cfg)
    assert pb.scheme.frame == "ale_shift"
    setup = setup_run(pb, headroom=1.3, min_moving_headroom=True)
    geom_fn = make_stage_geometry(pb.scheme, pb.domain, setup.nspec)
    step = jax.jit(lambda p, dt: ssp_rk3_step(p, pb.params, dt, pb.scheme, geom_fn)[:2])

    def final(steps):
        p, dt = pb.particles, jnp.asarray(0.16 / steps)
        for _ in range(steps):
            p, overflow = step(p, dt)
            assert int(overflow) == 0
        return np.asarray(p.q)

    q10, q20, q40 = final(10), final(20), final(40)
    e1, e2 = np.abs(q10 - q20).max(), np.abs(q20 - q40).max()
    assert np.log2(e1 / e2) > 2.5, (e1, e2)      # measured 3.35 (xu_smooth); 0.34 with xu


def test_a_moving_headroom_below_one_is_refused():
    from mlsph_jax.errors import InputError

    cfg = config.load(CONFIG, ["case.n=12", "time.t_end=0.02", "output.plots=false", "output.progress=false"])
    with pytest.raises(InputError, match="moving_neighbor_headroom=0.5"):
        Simulation(build_problem(cfg), moving_headroom=0.5)


def test_eulerian_lists_get_their_largest_count_and_the_same_right_hand_side():
    """Decision 91 (issue 15): fixed (Eulerian) particles never change their list, so the run
    layer sizes its capacity to the largest neighbour count, ignoring the headroom that moving
    particles need (K = 31 instead of 41 at N = 4e4; moving particles keep theirs, see the test
    below).  The right-hand side on that tight list
    equals the one on a list padded to the old headroom 1.3 (padding slots are masked; measured
    bitwise with the default code generator, to 1e-13 of its scale in the test run: decision 98),
    and one slot fewer overflows (the capacity is the smallest that holds the list)."""
    n = 16
    pb, x, vol, _ = _uniform_problem(n, ["scheme.frame=eulerian", "scheme.reconstruction_degree=2"])
    rng = np.random.default_rng(5)
    u = 0.5 * np.stack([np.sin(x[:, 1]), np.cos(x[:, 0])], 1) + 0.05 * rng.uniform(-1, 1, x.shape)
    U = to_conservative(jnp.asarray(1.0 + 0.01 * np.cos(x[:, 0])), jnp.asarray(u), None, get_eos("tait"), pb.params)
    p = pb.particles.replace(q=U * jnp.asarray(vol)[:, None])
    pb.particles = p
    sch = pb.scheme
    setup = setup_run(pb, headroom=1.3)
    count = int(np.max(np.asarray(setup.nl.count)))
    assert setup.nspec.capacity == count and not bool(setup.nl.overflow), (setup.nspec.capacity, count)
    h = sch.beta * np.sqrt(vol)
    padded = nb.update(x, h, dataclasses.replace(setup.nspec, capacity=int(np.ceil(1.3 * count))))
    assert padded.idx.shape[1] > count
    tight = nb.update(x, h, dataclasses.replace(setup.nspec, capacity=count - 1))
    assert bool(tight.overflow)
    f = jax.jit(lambda nl: rhs(p, pb.params, geometry(p.x, p.vol, nl, sch, pb.domain), sch))
    out = [f(nl) for nl in (setup.nl, padded)]
    for a, b in zip(out[0], out[1], strict=True):
        b = np.asarray(b)
        np.testing.assert_allclose(np.asarray(a), b, rtol=0, atol=1e-13 * max(np.abs(b).max(), 1e-300))


@pytest.mark.slow   # 23 s; CI time: the Verlet-skin test runs the minimal moving headroom in the default suite
def test_higher_moving_headroom_pads_more_slots_and_keeps_the_trajectory():
    """``scheme.moving_neighbor_headroom`` (issue 15): a headroom of 1.6 instead of the driver's
    automatic 1.3 (decision 84) gives moving particles a larger list capacity (more padding slots,
    which every pass over the stencil pays for) and the same trajectory to round-off (the padding
    slots are masked)."""
    cfg = config.load(CONFIG, ["case.n=12", "time.t_end=0.02", "output.plots=false", "output.progress=false"])
    res, caps = {}, {}
    for mh in (0.0, 1.6):
        sim = Simulation(build_problem(cfg), moving_headroom=mh)
        caps[mh] = sim.nspec.capacity
        res[mh] = sim.run(progress=False)
    assert caps[0.0] < caps[1.6], caps
    a, b = res[0.0], res[1.6]
    assert a.summary["n_steps"] == b.summary["n_steps"] >= 5
    for f in ("x", "vol", "q"):
        ref = np.asarray(getattr(a.particles, f))
        np.testing.assert_allclose(np.asarray(getattr(b.particles, f)), ref, rtol=0, atol=1e-13 * np.abs(ref).max())


def test_moving_frames_get_the_eulerian_capacity_and_regrow_instead_of_dropping():
    """Decision 84 (issue 15): in 2D the driver sizes a moving run's list with
    ``scheme.neighbor_headroom`` 1.3 (no extra moving headroom: every padding slot costs every
    pass over the stencil of every stage).  A moving run whose neighbour counts outgrow the
    capacity stops the chunk with the row-overflow bit, regrows from the counts it measured and
    ends where the run at the default capacity ends (no neighbour dropped)."""
    over = ["case.n=12", "time.t_end=0.02", "scheme.frame=lagrangian", "output.plots=false",
            "output.progress=false"]
    pb = build_problem(config.load(CONFIG, over))
    p0 = pb.particles
    eul = nb.plan(np.asarray(p0.x), pb.scheme.beta * np.sqrt(np.asarray(p0.vol)), pb.domain,
                  support=pb.scheme.support, headroom=1.3)
    sim = Simulation(pb)
    assert sim.nspec.capacity == eul.capacity, (sim.nspec.capacity, eul.capacity)
    ref = sim.run(progress=False)
    assert not sim.regrowth_log
    tight = Simulation(pb)
    count = int(np.max(np.asarray(tight.setup.nl.count)))
    tight.setup = dataclasses.replace(tight.setup, nspec=dataclasses.replace(tight.nspec, capacity=count - 1))
    tight._build()
    res = tight.run(progress=False)
    assert res.summary["status"] == "ok"
    log = tight.regrowth_log
    assert log and log[0]["causes"] == ["NEIGHBOR_OVERFLOW_ROW"] and log[0]["capacity"][1] >= count
    for f in ("x", "vol", "q"):
        r = np.asarray(getattr(ref.particles, f))
        np.testing.assert_allclose(np.asarray(getattr(res.particles, f)), r, rtol=0, atol=1e-13 * np.abs(r).max())
