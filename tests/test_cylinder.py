"""Flow past a cylinder (issue 17; SPEC §12.2 V9): the body-fitted polar layout, the frozen far
field, the boundary-integral body and the ``cylinder`` case."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from mlsph_jax.cases.layouts import polar_layout, polar_ring_edges
from mlsph_jax.errors import InputError


@pytest.mark.parametrize("n_theta, r_far, n_extra", [(32, 10.0, 0), (48, 7.5, 4), (120, 40.0, 4)])
def test_polar_layout_volumes_are_the_annular_sectors(n_theta, r_far, n_extra):
    """The volumes of the fluid rings sum to the annulus area pi (r_far^2 - R^2) to round-off, each
    ring's to its own annulus, and every particle lies inside its own sector."""
    R = 0.5
    lay = polar_layout(R, n_theta, r_far, n_extra)
    n_rings = len(lay.edges) - 1 - n_extra
    assert lay.edges[0] == R and math.isclose(lay.edges[n_rings], r_far, rel_tol=1e-14)
    fluid = lay.ring < n_rings
    area = math.pi * (r_far ** 2 - R ** 2)
    assert abs(lay.vol[fluid].sum() - area) <= 1e-13 * area
    rings = np.bincount(lay.ring, weights=lay.vol)
    np.testing.assert_allclose(rings, math.pi * np.diff(lay.edges ** 2), rtol=1e-13)
    r = np.hypot(lay.x[:, 0], lay.x[:, 1])
    assert np.all((r > lay.edges[lay.ring]) & (r < lay.edges[lay.ring + 1]))
    # geometric growth with square cells: dr / (r dtheta) in (1 - dtheta, 1] for every ring
    ratio = np.diff(lay.edges) / (lay.edges[:-1] * 2 * math.pi / n_theta)
    assert np.allclose(ratio, ratio[0], rtol=1e-12) and 1 - 2 * math.pi / n_theta < ratio[0] <= 1 + 1e-12


def test_polar_layout_thesis_count():
    """The thesis' setup (V9): 120 points on the body and 10,800 particles (90 rings)."""
    lay = polar_layout(0.5, 120, 40.0, 4)
    assert len(lay.x) == 10_800 and len(lay.edges) - 1 == 90


@pytest.mark.parametrize("args, key", [((0.5, 4, 10.0), "n_theta=4"), ((0.5, 32, 0.4), "r_far=0.4"),
                                       ((-1.0, 32, 10.0), "radius=-1.0")])
def test_polar_layout_bad_input(args, key):
    with pytest.raises(InputError, match=key):
        polar_ring_edges(*args)


# --- the case: far field and body -------------------------------------------------------------

import jax.numpy as jnp  # noqa: E402

from mlsph_jax import config as config_mod  # noqa: E402
from mlsph_jax.cases import build_problem  # noqa: E402
from mlsph_jax.cases.cylinder import free_stream  # noqa: E402
from mlsph_jax.state import Kind  # noqa: E402
from mlsph_jax.testing import CONFIG_DIR, rhs_once, stream_particles  # noqa: E402

SMALL = ("case.n_theta=32", "case.r_far=3.0", "output.plots=false", "output.progress=false")


def _problem(*overrides):
    cfg = config_mod.load(CONFIG_DIR / "cylinder.toml", [*SMALL, *overrides])
    return cfg, build_problem(cfg)


def _with_velocity(pb, cfg, speed):
    return stream_particles(pb, cfg, speed)


def _rhs(pb, p, boundary):
    return rhs_once(pb, p, boundary)


def test_uniform_stream_without_body_stays_uniform_and_far_field_is_frozen():
    """The cylinder's layout with its frozen far field and no body: a uniform free stream has a
    zero right-hand side to round-off (it stays uniform), and frozen particles get no update."""
    cfg, pb = _problem()
    p = pb.particles
    _, _, dq = _rhs(pb, p, None)
    scale = float(jnp.max(jnp.abs(p.q)))
    assert float(jnp.max(jnp.abs(dq))) <= 1e-12 * scale
    frozen = np.asarray(p.kind) == int(Kind.FROZEN)
    assert frozen.sum() == 32 * 4 and np.all(np.asarray(dq)[frozen] == 0.0)


def test_wall_search_cells_follow_the_body_particles_on_graded_rings():
    """The cells of the wall-stencil searches are sized by the wall points' own supports
    (support * h_b), not by the largest support of the graded rings (h grows ~30-fold out to
    10 D here): the set-up then plans cell searches for the stencils and for the near-wall rows of
    the first-moment correction, and they find the distance pass's stencils and rows (indices,
    slots, counts and rows exactly, offsets to round-off) also after the particles moved.  A
    support grown beyond the cells is reported (BOUNDARY_OVERFLOW), never cut.  Moving frames
    redo these searches every stage (Eulerian runs once): 302 -> 29 ms per call at 120 on the
    body (experiments/bench_cylinder.py, docs/performance.md)."""
    import dataclasses

    import jax

    from mlsph_jax.kernels import get_kernel
    from mlsph_jax.status import Status

    cfg = config_mod.load(CONFIG_DIR / "cylinder.toml", ["case.n_theta=48", "case.r_far=10", "output.plots=false"])
    pb = build_problem(cfg)
    p, bw = pb.particles, pb.boundary
    h = bw.beta * np.asarray(p.vol) ** 0.5
    kern = get_kernel(bw.kernel)
    xb = bw.points({}).x
    assert h.max() > 20 * h.min()
    assert bw.grid is not None and bw.near_grid is not None
    assert kern.support * float(np.max(np.asarray(bw.stencils(p, xb).h))) <= bw.grid.cell_size
    assert bw.grid.cell_size < 0.1 * kern.support * h.max()
    brute_walls = dataclasses.replace(bw, grid=None, near_grid=None)
    rng = np.random.default_rng(11)
    x = p.x + 0.2 * jnp.asarray(h[:, None] / bw.beta * rng.uniform(-1, 1, p.x.shape))
    moved = p.replace(x=x)
    search = jax.jit(lambda w, q: (w.stencils(q, xb), *w.near_rows(q, xb)))
    cells, brute = search(bw, moved), search(brute_walls, moved)
    assert int(jnp.max(cells[0].count)) <= bw.capacity and not bool(cells[2])
    for a, b in zip(jax.tree_util.tree_leaves(brute), jax.tree_util.tree_leaves(cells), strict=True):
        a, b = np.asarray(a), np.asarray(b)
        if a.dtype.kind == "f":
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-13 * max(np.abs(b).max(), 1e-300))
        else:
            np.testing.assert_array_equal(a, b)
    assert int(bw.band_status(moved, pb.params)[0]) == 0
    grown = moved.replace(vol=moved.vol * 4.0)       # supports 2x: beyond the cells' 1.5x headroom
    assert int(jnp.min(bw.stencils(grown, xb).count)) == np.iinfo(np.int32).max
    assert Status(int(bw.band_status(grown, pb.params)[0])) & Status.BOUNDARY_OVERFLOW


def test_body_terms_vanish_for_a_uniform_state_at_rest():
    """With the body: fluid at rest with uniform pressure has zero boundary terms (F_b . n = p n =
    F_i . n at every wall point) and zero right-hand side to round-off; the same fluid moving
    through the no-slip body does not (the check can fail)."""
    cfg, pb = _problem()
    p = _with_velocity(pb, cfg, 0.0)
    _, _, dq = _rhs(pb, p, pb.boundary)
    scale = float(jnp.max(jnp.abs(p.q)))
    assert float(jnp.max(jnp.abs(dq))) <= 1e-12 * scale
    _, _, dq_moving = _rhs(pb, pb.particles, pb.boundary)
    assert float(jnp.max(jnp.abs(dq_moving))) > 1e-3 * scale


@pytest.mark.parametrize("correction", [True, False])
def test_viscous_rate_is_exact_for_a_quadratic_no_slip_field_in_the_wall_rows(monkeypatch, correction):
    """Viscous consistency on the curved body: u = eps (r^2 - R^2) e vanishes on the body (no
    slip), so the constrained wall fit and every particle's fit hold it exactly; the viscous part
    of the momentum rate (the rate at mu minus the rate at mu = 0: nothing else depends on mu) is
    then mu (lap u + grad(div u) / 3) = mu eps (4 + 2/3) e in every row of the first rings (the
    first-moment correction of decision 60 acting on the diffusive flux, exact for a linear flux).
    Without that correction the wall rows miss it by O(1) (the check can fail).  The interior of
    the graded layout keeps its 0.75 % linear defect (docs/validation.md), hence rings 0-3 only."""
    from mlsph_jax import wall_integral
    from mlsph_jax.eos import get_eos, to_conservative

    cfg, pb = _problem()
    if not correction:
        orig = wall_integral.moment_defect
        monkeypatch.setattr(wall_integral, "moment_defect", lambda *a, **k: jnp.zeros_like(orig(*a, **k)))
    p = pb.particles
    x = np.asarray(p.x)
    r = np.hypot(x[:, 0], x[:, 1])
    R, eps, e = cfg["case"]["radius"], 0.1, np.array([1.0, 0.3])
    vel = eps * (r ** 2 - R ** 2)[:, None] * e
    U = to_conservative(jnp.ones(len(x)), jnp.asarray(vel), jnp.full(len(x), 71.4), get_eos(pb.scheme.eos), pb.params)
    p = p.replace(q=p.vol[:, None] * U)
    _, _, dq = _rhs(pb, p, pb.boundary)
    inviscid = dataclasses.replace(pb, params=pb.params.updated({"physics.mu": 0.0 * pb.params["physics.mu"]}))
    _, _, dq0 = _rhs(inviscid, p, pb.boundary)
    mu = float(pb.params["physics.mu"])
    exact = mu * eps * (4.0 + 2.0 / 3.0) * e
    rate = np.asarray(dq - dq0)[:, 1:3] / np.asarray(p.vol)[:, None]
    err = np.linalg.norm(rate - exact, axis=1) / np.linalg.norm(exact)
    fluid = np.asarray(p.kind) == int(Kind.FLUID)
    rings = np.unique(np.round(r[fluid], 9))[:4]
    near = fluid & (r <= rings[-1] + 1e-9)
    # measured: 6.4e-11 with the correction (round-off of the mu / mu = 0 difference), 0.25 without
    if correction:
        assert err[near].max() <= 1e-8, err[near].max()
    else:
        assert err[near].max() > 1e-2, err[near].max()


def _no_slip_wall_velocities(n_theta, *overrides, field="no_slip"):
    """(vn_b of the scheme, vn_b of the linear wall state, vn_b of a uniform penetration V minus
    V . n_b, spacing h, the acoustic term p* - p of the scheme's wall pressure) on the body of the
    ``n_theta`` layout for a divergence-free field with exact vn_b = 0, at uniform density and
    pressure: ``"no_slip"``, the stream function psi = (r - R)^2 sin(theta): u_r = (r - R)^2
    cos(theta) / r, u_theta = -2 (r - R) sin(theta), zero on the body with d u_r / dr = 0 there;
    ``"potential"``, the potential flow past the circle: u_r = (1 - R^2 / r^2) cos(theta), u_theta =
    -(1 + R^2 / r^2) sin(theta), which slips along the body and bends its normal component."""
    from mlsph_jax.eos import get_eos, to_conservative, to_primitive

    cfg, pb = _problem(f"case.n_theta={n_theta}", *overrides)
    p, walls = pb.particles, pb.boundary
    x = np.asarray(p.x)
    R = cfg["case"]["radius"]
    r, th = np.hypot(x[:, 0], x[:, 1]), np.arctan2(x[:, 1], x[:, 0])
    if field == "no_slip":
        ur, ut = (r - R) ** 2 * np.cos(th) / r, -2.0 * (r - R) * np.sin(th)
    else:
        ur, ut = (1.0 - R ** 2 / r ** 2) * np.cos(th), -(1.0 + R ** 2 / r ** 2) * np.sin(th)
    vel = jnp.asarray(np.stack([ur * np.cos(th) - ut * np.sin(th), ur * np.sin(th) + ut * np.cos(th)], 1))
    bp, st, vals = walls.state_weights(p, pb.params, pb.scheme)
    vn = np.asarray(walls.normal_velocity(pb.scheme, bp, st, vals, vel))
    vj = np.einsum("bkd,bd->bk", np.asarray(vel)[np.asarray(st.idx)], np.asarray(bp.normal))
    linear = np.einsum("bk,bk->b", np.asarray(vals), vj)
    V = np.array([0.3, -0.2])
    pen = np.asarray(walls.normal_velocity(pb.scheme, bp, st, vals, jnp.broadcast_to(jnp.asarray(V), vel.shape)))
    # the scheme's wall pressure for the same state (uniform rho and p: p* - p is the acoustic term)
    eos = get_eos(pb.scheme.eos)
    U = to_conservative(jnp.ones(len(x)), vel, jnp.full(len(x), 71.4), eos, pb.params)
    p = p.replace(q=p.vol[:, None] * U)
    _, _, _, pstar, _, _ = walls.wall_state(p, pb.params, pb.scheme, to_primitive(U, eos, pb.params))
    return vn, linear, pen - np.asarray(bp.normal) @ V, float(np.median(np.asarray(st.h))), np.asarray(pstar) - 71.4


def test_no_slip_wall_normal_velocity_vanishes_for_a_no_slip_profile_and_keeps_a_penetration():
    """Decision 108: on a no-slip body the wall-normal velocity of the mirror Riemann problem
    (whose acoustic term rho c vn_b the wall pressure carries) comes from the fit without the term
    linear in the wall-normal coordinate.  For a divergence-free field that vanishes on the body
    (u_n = O(y^2)) it is far below the linear wall state's O(h^2) intercept and converges faster,
    and the scheme's wall pressure p* carries it (its acoustic term is that of the new vn_b, far
    below that of the linear state's); a uniform penetration V keeps its whole restoring force
    (vn_b = V . n_b to round-off).  An inviscid scheme (a wall without friction, where u_n has a
    slope that this fit would read as a penetration) does not take this fit (decision 109, next
    test).  Measured: max |vn_b| 8.9e-5 (linear 3.4e-3) at n_theta = 48, 1.4e-5 (1.3e-3) at 96:
    order 2.6 against 1.4."""
    vn48, lin48, pen48, h48, ac48 = _no_slip_wall_velocities(48)
    vn96, lin96, pen96, h96, _ = _no_slip_wall_velocities(96)
    for pen in (pen48, pen96):
        assert np.abs(pen).max() <= 1e-13
    assert np.abs(vn48).max() <= 0.05 * np.abs(lin48).max()
    assert np.abs(vn96).max() <= 0.02 * np.abs(lin96).max()
    order = math.log(np.abs(vn48).max() / np.abs(vn96).max()) / math.log(h48 / h96)
    assert order >= 2.3, order
    # p* - p = rho vn (vn + |vn| + c) with c = sqrt(1.4 * 71.4) at rho = 1: the new vn_b, not the linear one
    c = math.sqrt(1.4 * 71.4)
    np.testing.assert_allclose(ac48, vn48 * (vn48 + np.abs(vn48) + c), rtol=1e-9, atol=1e-12)
    assert np.abs(ac48).max() <= 0.05 * c * np.abs(lin48).max()
    vn_e, _, _, _, _ = _no_slip_wall_velocities(48, "case.inviscid=true")
    assert np.abs(vn_e).max() >= 10.0 * np.abs(vn48).max()       # its slope is not held at 0


def test_free_slip_wall_normal_velocity_follows_the_bent_potential_flow_and_keeps_a_penetration():
    """Decision 109: on a wall without friction (here the body of an inviscid scheme) vn_b of the
    mirror Riemann problem comes from the quadratic MLS at the wall point.  For the potential flow
    past the circle (exact vn_b = 0; its normal velocity ~ 1 - R^2 / r^2 is bent) the linear wall
    state's O(h^2) error is reduced and converges at third order, the scheme's wall pressure p*
    carries the new vn_b, and a uniform penetration V keeps its whole restoring force (vn_b =
    V . n_b to round-off).  Measured (the tests' far field at 3 D): max |vn_b| 3.4e-2 (linear 7.2e-2)
    at n_theta = 48, 4.1e-3 (1.9e-2) at 96: order 3.0 against 1.9."""
    vn48, lin48, pen48, h48, ac48 = _no_slip_wall_velocities(48, "case.inviscid=true", field="potential")
    vn96, lin96, pen96, h96, _ = _no_slip_wall_velocities(96, "case.inviscid=true", field="potential")
    for pen in (pen48, pen96):
        assert np.abs(pen).max() <= 1e-13
    assert np.abs(vn48).max() <= 0.6 * np.abs(lin48).max()
    assert np.abs(vn96).max() <= 0.3 * np.abs(lin96).max()
    order = math.log(np.abs(vn48).max() / np.abs(vn96).max()) / math.log(h48 / h96)
    order_linear = math.log(np.abs(lin48).max() / np.abs(lin96).max()) / math.log(h48 / h96)
    assert order >= 2.7 and order_linear <= 2.2, (order, order_linear)
    c = math.sqrt(1.4 * 71.4)
    np.testing.assert_allclose(ac48, vn48 * (vn48 + np.abs(vn48) + c), rtol=1e-9, atol=1e-12)
    # a viscous scheme's no-slip body keeps decision 108's fit (it vanishes for this slip flow's
    # curvature only where u_n = O(y^2), which this field is not)
    vn_v, _, _, _, _ = _no_slip_wall_velocities(48, field="potential")
    assert np.abs(vn_v - vn48).max() > 1e-3


def test_inviscid_body_is_a_wall_without_friction():
    """`case.inviscid`: mu = 0, no diffusive flux, and the body's force on the impulsively started
    stream is its pressure part alone; the same state with the default viscosity has a viscous
    part (the check can fail)."""
    for inviscid, viscous_force in ((True, False), (False, True)):
        cfg, pb = _problem(f"case.inviscid={str(inviscid).lower()}")
        assert pb.scheme.viscous is not inviscid and (float(pb.params["physics.mu"]) == 0.0) is inviscid
        total, pressure = pb.boundary.forces(pb.particles, pb.params, pb.scheme)
        diff = float(jnp.max(jnp.abs(total - pressure)))
        assert (diff > 1e-6 * float(jnp.max(jnp.abs(total)))) is viscous_force, (inviscid, diff)


def test_a_derivative_with_respect_to_a_term_the_scheme_lacks_is_refused():
    """d/d physics.mu of an inviscid run (or d/d physics.kappa without conduction) is exactly zero
    and a finite-difference check would agree: refused, naming the parameter and what is allowed."""
    from mlsph_jax.sensitivity import sensitivity

    _, pb = _problem("case.inviscid=true")
    with pytest.raises(InputError, match=r"--wrt 'physics.mu': the scheme has no viscous stress.*allowed here"):
        sensitivity(pb, ["physics.mu"], of="cd")
    with pytest.raises(InputError, match=r"--wrt 'physics.kappa': the scheme has no heat conduction"):
        sensitivity(pb, ["physics.kappa"], of="cd")


def test_force_on_body_at_rest_is_the_buoyancy():
    """Archimedes: fluid at rest in the isothermal atmosphere p = p_inf exp(-a y), a = rho_inf g /
    p_inf, under the body force (0, -g).  The force of the fluid on the body, sum_b p_b n_b dGamma_b,
    equals -int_body grad p dA = 2 pi R p_inf I_1(a R) upward (no viscous part at rest); the wall
    pressure is the linear MLS interpolant of p, so the error is O((a h)^2) relative, below (a R)^2."""
    from scipy.special import i1

    g = 1.0
    cfg, pb = _problem(f"physics.body_force=[0.0, {-g}]")
    p = _with_velocity(pb, cfg, 0.0)
    total, pressure = pb.boundary.forces(p, pb.params, pb.scheme)
    p_inf = float(free_stream(cfg, np.zeros((1, 2)), pb.params)[2][0])
    a, R = 1.0 * g / p_inf, cfg["case"]["radius"]
    exact = 2.0 * math.pi * R * p_inf * i1(a * R)
    f = np.asarray(total[0])
    # measured: 1.9e-7 relative at g = 1 and 1.9e-5 at g = 10 (quadratic in a); bound (a R)^2 = 4.9e-5
    assert abs(f[1] - exact) <= (a * R) ** 2 * exact, (f, exact)
    assert abs(f[0]) <= 1e-12 * exact and np.array_equal(np.asarray(total), np.asarray(pressure))


@pytest.mark.parametrize("overrides, words", [
    (("case.n_theta=48", "case.r_far=0.65"), ["case.r_far=0.65", "far-field rings", "allowed: case.r_far > 0.6678"]),
    (("case.radius=9.5", "case.r_far=10.0"), ["case.radius=9.5", "case.r_far=10", "too big for the layout"]),
    (("case.n_theta=24",), ["case.n_theta", "24", ">= 32"]),
    (("case.r_far=0.4",), ["case.r_far=0.4", "outer radius > case.radius=0.5"]),
    (("eos.kind=\"tait\"", "eos.rho0=1.0", "eos.c0=10.0"), ["eos.kind", "ideal_gas"]),
    (("physics.mu=0.5",), ["physics.mu=0.5", "case.re"]),
    (("case.wall_temperature=1.1",), ["case.wall_temperature=1.1", "without heat conduction", "case.prandtl > 0"]),
    (("case.prandtl=0.72", "physics.kappa=0.01"), ["physics.kappa=0.01", "case.prandtl=0.72", "0.04861111111"]),
    (("case.inviscid=true", "physics.mu=0.025"), ["physics.mu=0.025", "case.inviscid=true", "mu = 0"]),
    (("case.inviscid=true", "case.prandtl=0.72"), ["case.prandtl=0.72", "case.inviscid=true", "no heat conduction"]),
    (("case.inviscid=true", "physics.kappa=0.01", "case.wall_temperature=1.1"),
     ["physics.kappa=0.01", "case.wall_temperature=1.1", "case.inviscid=true"]),
])
def test_bad_cylinder_configs_name_the_key(overrides, words):
    """A body overlapping the far-field rings, a body too big for the layout, too few points
    around the body, a far field inside the body, the wrong fluid or viscosity: ConfigError naming
    the key, its value and what is allowed."""
    from mlsph_jax.errors import ConfigError

    with pytest.raises(ConfigError) as e:
        config_mod.load(CONFIG_DIR / "cylinder.toml", list(overrides))
    for w in words:
        assert w in str(e.value), (w, str(e.value))


# --- the isothermal body -----------------------------------------------------------------------

def _conduction_problem(n_theta: int, r_o: float = 3.0):
    """The ``cylinder`` problem with an isothermal body (Pr 0.72, T_w / T_inf = 1.2) and a far
    field at r_o."""
    return _problem(f"case.n_theta={n_theta}", f"case.r_far={r_o}", "case.prandtl=0.72", "case.wall_temperature=1.2")


def _conduction_state(cfg, pb, ratio: float, r_o: float = 3.0):
    """``(particles, params, e_w - e_inf)``: the exact steady conduction state of a gas at rest
    between the body at T_w = ``ratio`` T_inf and the circle r_o at T_inf: uniform pressure, e =
    e_inf + (e_w - e_inf) ln(r_o / r) / ln(r_o / R); the params hold that wall energy."""
    from mlsph_jax.cases.cylinder import free_stream_energy
    from mlsph_jax.eos import get_eos, to_conservative

    p, R = pb.particles, cfg["case"]["radius"]
    e_inf = free_stream_energy(cfg)
    x = np.asarray(p.x)
    e = e_inf + (ratio - 1.0) * e_inf * np.log(r_o / np.hypot(x[:, 0], x[:, 1])) / math.log(r_o / R)
    pr = free_stream(cfg, x, pb.params)[2]
    rho = pr / ((cfg["eos"]["gamma"] - 1.0) * e)
    U = to_conservative(jnp.asarray(rho), jnp.zeros_like(p.x), jnp.asarray(pr), get_eos(pb.scheme.eos), pb.params)
    P = pb.params.updated({"geometry.body.wall_e": jnp.asarray(ratio * e_inf)})
    return p.replace(q=p.vol[:, None] * U), P, (ratio - 1.0) * e_inf


def test_isothermal_body_passes_the_exact_conduction_heat_and_reports_its_nusselt_number():
    """Issue 17 item 2 (fixed temperature) from the config: `case.prandtl` sets kappa = gamma mu /
    Pr, `case.wall_temperature` makes the body isothermal.  On the exact steady conduction state
    between the body and r_o = 3 D = 6 R (gas at rest) the heat passed into the fluid is 2 pi kappa
    (e_w - e_inf) / ln(r_o / R) per unit span and Nu = 2 / ln(r_o / R) = 1.1162 on every point.
    Measured relative errors of the wall heat (the constrained fit of e at each wall point): 7.8e-3
    at 32 points on the body, 2.7e-3 at 48 (order 2.6), 6.6e-4 at 80, 2.5e-4 at 128; the same for
    a cooled body (T_w < T_inf: the heat flows into the body, Nu stays positive); the local Nu at
    the front equals the mean (the state is axisymmetric).  d Nu / d e_w (jvp) matches central FD."""
    import jax

    from mlsph_jax.cases.cylinder import free_stream_energy
    from mlsph_jax.eos import get_eos, to_primitive

    errors, problems = [], {}
    for n_theta in (32, 48):
        cfg, pb = problems[n_theta] = _conduction_problem(n_theta)
        kappa = float(pb.params["physics.kappa"])
        assert kappa == pytest.approx(1.4 * (1.0 / 40.0) / 0.72, rel=1e-14)
        # e_inf is the free stream's own energy, and the wall energy the configured multiple of it
        e0 = np.asarray(to_primitive(pb.particles.U, get_eos(pb.scheme.eos), pb.params).e)
        np.testing.assert_allclose(e0, free_stream_energy(cfg), rtol=1e-14)
        assert float(pb.params["geometry.body.wall_e"]) == pytest.approx(1.2 * e0[0], rel=1e-14)
        for ratio in (1.2, 0.8):
            p, P, de = _conduction_state(cfg, pb, ratio)
            q, length = pb.boundary.heat_rates(p, P, pb.scheme)
            assert float(length[0]) == pytest.approx(math.pi, rel=1e-14)
            exact = 2.0 * math.pi * kappa * de / math.log(6.0)
            errors.append(float(q[0]) / exact - 1.0)
            m = pb.metrics(p, 0.0, P)
            assert m["nusselt"] == pytest.approx(2.0 / math.log(6.0) * (1.0 + errors[-1]), rel=1e-12)
            assert m["nusselt_front"] == pytest.approx(m["nusselt"], rel=1e-10)
    hot32, cold32, hot48, cold48 = errors
    assert abs(hot32) < 0.01 and abs(hot48) < 0.0035 and hot32 / hot48 > 2.2, errors
    assert cold32 == pytest.approx(hot32, rel=1e-8) and cold48 == pytest.approx(hot48, rel=1e-8)
    # d Nu / d e_w on a fixed state (the wall value enters the constrained fit and the scale)
    cfg, pb = problems[32]
    p, P, _ = _conduction_state(cfg, pb, 1.2)
    key = "geometry.body.wall_e"

    def nu(ew):
        return pb.differentiable_metrics(p, 0.0, P.updated({key: ew}))["nusselt"]
    ew = P[key]
    _, ad = jax.jvp(nu, (ew,), (jnp.ones_like(ew),))
    h = 1e-6 * float(ew)
    fd = (float(nu(ew + h)) - float(nu(ew - h))) / (2.0 * h)
    assert abs(float(ad) - fd) <= 1e-6 * abs(fd) and abs(fd) * float(ew) > 1e-2, (float(ad), fd)
    # the scheme passes that heat into the fluid: on the initial (uniform) state the hot body's
    # Q > 0 (the constrained fit sees e_w - e_inf; an unconstrained one would see a uniform e and
    # give 0), and the fluid's total energy rate exceeds the adiabatic body's by exactly Q
    # (sum_i N_i(x_b) = 1); the adiabatic body with conduction passes nothing and has no Nusselt number
    pb_a = pb
    q_hot, _ = pb_a.boundary.heat_rates(pb_a.particles, pb_a.params, pb_a.scheme)
    _, pb_b = _problem("case.prandtl=0.72")
    q_adi, _ = pb_b.boundary.heat_rates(pb_b.particles, pb_b.params, pb_b.scheme)
    assert float(q_hot[0]) > 0.0 and float(q_adi[0]) == 0.0
    assert "nusselt" not in pb_b.metrics(pb_b.particles, 0.0, pb_b.params)
    energy = [float(jnp.sum(rhs_once(pb_, pb_.particles, pb_.boundary)[2][:, 3])) for pb_ in (pb_a, pb_b)]
    assert energy[0] - energy[1] == pytest.approx(float(q_hot[0]), rel=1e-9), (energy, float(q_hot[0]))


# --- Re = 40 runs ----------------------------------------------------------------------------

from mlsph_jax.reference.cylinder import RE40_TARGETS  # noqa: E402
from mlsph_jax.simulation import run_problem  # noqa: E402

#: Drag coefficient of the steady flow at Re = 20 (thesis ch. 4 references: 2.0-2.1): a coarse
#: Re = 40 run must stay below it (a viscosity twice too large, or the plain Rusanov flux's
#: low-Mach dissipation, C_D 2.96 at n_theta = 32, ends above it).
CD_RE20 = 2.0
COARSE = ("case.n_theta=32", "case.r_far=4.0", "case.mach=0.2", "time.t_end=4.0", "output.snapshots=2",
          "case.steady_tol=0", "time.local_time_stepping=false",   # (t = 4 of the physical start-up)
          "output.degree_fallback_warn=0.1")    # 8.3 % (the first ring) on a quadratic fit (the config: 2.8 %)


# default suite (issue 17 "Tests": a coarse cylinder Re = 40 run with C_D inside a band); 23 s under load
def test_coarse_re40_drag_in_band():
    """Coarse Re = 40 run (n_theta = 32, far field at 4 D, Mach 0.2 for half the steps, t = 4
    after the impulsive start, 512 particles, ~700 steps): C_D
    between 0.97 x 1.56 (the study in docs/validation.md: C_D falls towards the references from
    above with time, resolution and far-field radius) and the Re = 20 drag; the flow is symmetric
    (|C_L| small) and the pressure drag dominates as at Re = 40 (C_D,p / C_D ~ 0.65-0.7)."""
    cfg = config_mod.load(CONFIG_DIR / "cylinder.toml", [*COARSE, "output.plots=false", "output.progress=false"])
    m = run_problem(build_problem(cfg), cfg, out_dir=None, quiet=True).summary["metrics"]
    cd = m["cd"]
    assert 0.97 * RE40_TARGETS["cd"][0] < cd < CD_RE20, m
    assert abs(m["cl"]) < 0.01 * cd
    assert 0.6 < m["cd_pressure"] / cd < 0.75, m
    # the flow has separated on the rear half (measured 47.96 deg from the base at t = 4), at the
    # same angle on both surfaces (a symmetric flow)
    assert 0.0 < m["separation_angle"] < 90.0, m
    assert m["separation_angle_lower"] == pytest.approx(m["separation_angle"], abs=1e-9)


def test_skin_friction_sign_angle_and_separation_point():
    """body_cf's convention on a circle whose every wall point feels the same downstream traction
    (tau, 0): C_f = tau |sin theta| / q_inf on both surfaces (positive: friction pointing from the
    front towards the base), the angle measured from the base; separation_angles finds the linear
    zero crossing of C_f walking from its maximum towards the base, 0 without one."""
    from types import SimpleNamespace

    from mlsph_jax.cases.cylinder import body_cf, separation_angles

    n, R, tau, q = 40, 0.5, 0.3, 0.5
    th = 2 * math.pi * (np.arange(n) + 0.5) / n
    xb = R * np.stack([np.cos(th), np.sin(th)], 1)
    walls = SimpleNamespace(curves=[SimpleNamespace(name="body")])
    tn = -np.broadcast_to([tau, 0.0], (n, 2))                    # f_b = -tau_b n_b = (tau, 0)
    phi, upper, cf = body_cf(walls, xb, -xb / R, np.zeros(n, int), tn, (0.0, 0.0), (1.0, 0.0), q)
    np.testing.assert_allclose(cf, tau * np.abs(np.sin(th)) / q, atol=1e-14)
    np.testing.assert_allclose(phi, np.abs(np.angle(np.exp(1j * th))), atol=1e-14)
    np.testing.assert_array_equal(upper, np.sin(th) > 0)
    assert separation_angles(phi, upper, cf) == (0.0, 0.0)      # attached everywhere
    # a friction that reverses 50 deg from the base on the upper surface, 40 deg on the lower
    zero = np.where(upper, np.radians(50.0), np.radians(40.0))
    cf2 = np.sin(phi) * (phi - zero)
    up_deg, low_deg = separation_angles(phi, upper, cf2)
    assert abs(up_deg - 50.0) < 0.2 and abs(low_deg - 40.0) < 0.2     # linear between points 9 deg apart
    assert separation_angles(phi, upper, -np.abs(cf2)) == (0.0, 0.0)  # no attached friction at all
    # the stream turned by alpha (an elliptic body's incidence turns the stream): angles and
    # surfaces follow the stream direction, not the x axis
    a = 0.4
    e_d = np.array([math.cos(a), math.sin(a)])
    phi, upper, cf = body_cf(walls, xb, -xb / R, np.zeros(n, int), -np.broadcast_to(tau * e_d, (n, 2)),
                             (0.0, 0.0), e_d, q)
    np.testing.assert_allclose(cf, tau * np.abs(np.sin(th - a)) / q, atol=1e-14)
    np.testing.assert_allclose(phi, np.abs(np.angle(np.exp(1j * (th - a)))), atol=1e-14)
    np.testing.assert_array_equal(upper, np.sin(th - a) > 0)


ELLIPSE = ('case.body="ellipse"', "case.aspect=2.0", "case.alpha=5.0")


# CI time: decision 77's wall threshold is checked by test_one_sided_first_ring_fits_fall_back_by_the_wall_threshold
@pytest.mark.slow
def test_builtin_scheme_survives_the_impulsive_start_on_a_coarse_ellipse():
    """The config's cubic reconstruction on the strongly curved, coarse body of the shape studies
    (ellipse A = 2 at 5 deg, 32 points, far field at 3 D, Mach 0.2, global steps) with the scheme's
    default thresholds: the fits of the first ring are one-sided, and with rcond = 1e-2 alone some
    keep a barely conditioned cubic (pivot ratio between 0.01 and 0.1) that blew up in step 1 (and
    at step 7 at the thesis' n_theta = 120 around the circle).  The truncated-stencil threshold
    scheme.wall_rcond = 0.1 drops those fits to quadratic (docs/architecture.md decisions 75, 77):
    the start-up must stay finite (0.3 time units, ~34 steps; with scheme.wall_rcond = 0.01 the
    run stops with a non-finite state in step 1)."""
    cfg, pb = _problem(*ELLIPSE, "case.mach=0.2", "scheme.rcond=0.01",
                       "time.local_time_stepping=false", "time.t_end=0.3", "output.snapshots=1",
                       "output.degree_fallback_warn=0.15")    # 10 %: the first ring of this small layout
    s = run_problem(pb, cfg, out_dir=None, quiet=True).summary
    assert s["status"] == "ok", s["status"]
    assert s["n_steps"] > 20 and np.isfinite(s["metrics"]["cd"]), s["metrics"]


def test_one_sided_first_ring_fits_fall_back_by_the_wall_threshold():
    """Decision 77 on the coarse ellipse (the layout above) with rcond = 0.01 and the default
    wall_rcond = 0.1: exactly the first ring (the 32 fluid particles nearest the body; their
    stencils are cut by the boundary-integral wall) fits quadratically, every other particle
    cubically (rcond = 0.01 alone: 16 of the 32, the rest with pivot ratios 0.01-0.1).  Checked by
    what the fits reproduce: the gradient of a cubic field is exact at the other particles and
    not at the first ring, where the gradient of a quadratic field is exact."""
    from mlsph_jax import neighbors
    from mlsph_jax.rhs import geometry
    from mlsph_jax.wall_integral import fit_gradient

    _, pb = _problem(*ELLIPSE, "scheme.rcond=0.01")
    p = pb.particles
    _, nl = neighbors.allocate(p.x, pb.scheme.beta * p.vol ** 0.5, pb.domain)
    geom = geometry(p.x, p.vol, nl, pb.scheme, pb.domain)
    x = np.asarray(p.x)
    fluid = np.flatnonzero(np.asarray(p.kind) == Kind.FLUID)
    xb = np.asarray(pb.boundary.points(pb.params).x)
    dist = np.min(np.linalg.norm(x[fluid, None] - xb[None], axis=-1), axis=1)
    order = np.argsort(dist)
    assert dist[order[31]] < 0.6 * dist[order[32]]         # the first ring is the 32 nearest, by a gap
    first = np.zeros(len(x), bool)
    first[fluid[order[:32]]] = True
    deg = np.asarray(geom.degree)[:, 1]
    assert np.all(deg[first] == 2) and np.all(deg[fluid[order[32:]]] == 3), np.unique(deg[fluid], return_counts=True)

    def error(f, grad, rows):
        g = np.asarray(fit_gradient(geom, jnp.asarray(f(x)), 3, jnp.asarray(rows)))
        return np.max(np.abs(g - grad(x[rows])), axis=1) / np.max(np.abs(grad(x[rows])))

    cubic = (lambda y: y[:, 0] ** 3 - 2 * y[:, 0] * y[:, 1] ** 2 + y[:, 1] ** 3,
             lambda y: np.stack([3 * y[:, 0] ** 2 - 2 * y[:, 1] ** 2, -4 * y[:, 0] * y[:, 1] + 3 * y[:, 1] ** 2], 1))
    quad = (lambda y: y[:, 0] ** 2 - 3 * y[:, 0] * y[:, 1] + 2 * y[:, 1] ** 2,
            lambda y: np.stack([2 * y[:, 0] - 3 * y[:, 1], -3 * y[:, 0] + 4 * y[:, 1]], 1))
    far_ok = np.flatnonzero(np.isin(np.arange(len(x)), fluid) & ~first)
    assert np.max(error(*cubic, far_ok)) < 1e-8
    assert np.max(error(*quad, np.flatnonzero(first))) < 1e-8
    assert np.min(error(*cubic, np.flatnonzero(first))) > 1e-4


@pytest.mark.slow
def test_builtin_config_meets_the_re40_targets():
    """configs/cylinder.toml as shipped (n_theta = 80 since decision 110, far field at 40 D, local
    time steps to the steady state) against issue 17's Re = 40 targets: C_D within 3 % of 1.56, C_p
    front within 4 % of 1.18, base within 8 % of -0.51, L_w / D within 10 % of 2.3 (about 11 min on
    2 cores beside other runs).  Measured (docs/validation.md "The built-in resolution",
    2026-12-06): steady at t = 22, C_D 1.5284, C_p front 1.1405, C_p base -0.4959, L_w / D 2.111.
    At 48 on the body (the config before decision 110) L_w / D is 1.73 and misses: the wake is
    under-resolved there."""
    cfg = config_mod.load(CONFIG_DIR / "cylinder.toml", ["output.plots=false", "output.progress=false"])
    s = run_problem(build_problem(cfg), cfg, out_dir=None, quiet=True).summary
    assert s["steady_state"]["converged"], s["steady_state"]
    m = s["metrics"]
    assert "recirculation_length" in RE40_TARGETS
    for key, (value, tol) in RE40_TARGETS.items():
        assert abs(m[key] - value) <= tol * abs(value), (key, m[key], value, tol)


@pytest.mark.slow
def test_inviscid_stagnation_pressure_converges_to_the_isentropic_value():
    """Euler flow past the circle (`case.inviscid`, M = 0.1, far field at 10 D, local time steps to
    the steady stop): the front stagnation C_p tends to the isentropic 1 + M^2/4 + ... = 1.0025
    (Bernoulli along the stagnation streamline, whatever the blockage).  The excess is the wall
    closure's: the wall state extrapolates the curved wall-normal velocity with an error that the
    acoustic term rho c vn of the wall pressure multiplies by c = U / M (docs/validation.md "Euler
    flow past the circle"), O(h^2) with the linear state, O(h^3) with the quadratic fit of decision
    109.  Measured (2026-12-06, decision 109): +0.0685 at n_theta = 48 and +0.0172 at 96 (4.0x; runs
    of 48 s and 217 s; with the linear state +0.160 and +0.047); asserted: at least 3x smaller per
    doubling and within 0.03 at 96 (the linear state's +0.047 fails it)."""
    exact = 2.0 / (1.4 * 0.01) * ((1.0 + 0.2 * 0.01) ** 3.5 - 1.0)
    excess = []
    for n in (48, 96):
        cfg = config_mod.load(CONFIG_DIR / "cylinder.toml", ["case.inviscid=true", "case.r_far=10.0",
                                                               f"case.n_theta={n}", "output.plots=false",
                                                               "output.progress=false"])
        s = run_problem(build_problem(cfg), cfg, out_dir=None, quiet=True).summary
        assert s["steady_state"]["converged"], s["steady_state"]
        excess.append(s["metrics"]["cp_front"] - exact)
    assert excess[1] <= excess[0] / 3.0 and abs(excess[1]) <= 0.03, excess


@pytest.mark.slow
def test_heated_body_nusselt_number_at_re40():
    """The built-in config at 48 points on the body (Re = 40, Mach 0.1; the shipped 80 since decision
    110, the figures below are at 48) with Pr = 0.72 and the body
    1 % hotter, then 1 % colder than the free stream, and adiabatic (~3 min each idle;
    docs/validation.md "The heated cylinder").  Each run's heat is h (T_w - T_aw): the hot run's
    Nu (based on T_w - T_inf) is low and the cold run's high by the recovery temperature
    T_aw - T_inf ~ r (gamma - 1) M^2 / 2 T_inf (0.0017 T_inf for r = Pr^1/2), and the pair's mean
    is h D / k.  Measured (since decision 108, 2026-12-06): 2.856 / 3.938, pair 3.397, T_aw / T_inf
    1.00159 (Churchill-Bernstein 3.399, Hilpert 3.415; before decision 108 2.865 / 3.940, and 80
    points on the body gave the pair 3.306, -2.8 %).  Bounds: the pair within 6 % of
    Churchill-Bernstein (the resolution change and margin; the correlations scatter ~20 %), the
    recovery temperature between r = 0.6 and 1.5 of the theory's (gamma - 1) M^2 / 2, the
    adiabatic run's C_D kept to 0.1 % (measured +0.03 % / +0.01 %), the local Nu at the front
    above 1.4 x the mean in each run (measured 1.55 hot, where the recovery temperature lowers the
    front, and 1.95 cold)."""
    from mlsph_jax.reference.cylinder import nusselt_churchill_bernstein

    runs = {}
    for ratio in (1.01, 0.99, None):
        heat = [] if ratio is None else ["case.prandtl=0.72", f"case.wall_temperature={ratio}"]
        cfg = config_mod.load(CONFIG_DIR / "cylinder.toml", ["case.n_theta=48", *heat, "output.plots=false",
                                                              "output.progress=false"])
        s = run_problem(build_problem(cfg), cfg, out_dir=None, quiet=True).summary
        assert s["steady_state"]["converged"], s["steady_state"]
        runs[ratio] = s["metrics"]
    adiabatic = runs.pop(None)["cd"]
    nu_hot, nu_cold = runs[1.01]["nusselt"], runs[0.99]["nusselt"]
    nu = 0.5 * (nu_hot + nu_cold)
    recovery = 0.01 * (nu_cold - nu_hot) / (nu_cold + nu_hot)          # T_aw / T_inf - 1
    theory = 0.5 * (1.4 - 1.0) * 0.1 ** 2
    assert nu_hot < nu < nu_cold
    assert abs(nu / nusselt_churchill_bernstein(40.0, 0.72) - 1.0) <= 0.06, (nu_hot, nu_cold, nu)
    assert 0.6 * theory < recovery < 1.5 * theory, recovery
    for m in runs.values():
        assert m["cd"] == pytest.approx(adiabatic, rel=1e-3) and m["nusselt_front"] > 1.4 * m["nusselt"]
