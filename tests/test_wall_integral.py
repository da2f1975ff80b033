"""Walls by the boundary integral of thesis eq. 4.24 (mlsph_jax.wall_integral; SPEC §5.8):
exact balance of uniform states on the walls' own velocity, no mass through walls, free-slip
walls, Archimedes' buoyancy from the wall quadrature, the constrained wall-gradient fit, the
in-run checks, and Couette flow against the exact series and the mirror-ghost walls."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mlsph_jax import neighbors as nb
from mlsph_jax.boundaries import BOUNDARIES, Wall
from mlsph_jax.eos import get_eos, to_conservative, to_primitive
from mlsph_jax.errors import InputError
from mlsph_jax.geometry import Circle, Ellipse, Polygon
from mlsph_jax.integrate import step_status
from mlsph_jax.kernels import get_kernel
from mlsph_jax.rhs import geometry, rhs
from mlsph_jax.scheme import Scheme
from mlsph_jax.state import Domain, Kind, Params, make_particles
from mlsph_jax.status import Status
from mlsph_jax.wall_integral import constrained_gradient, search_grid, wall_stencils

TAIT = Params({"eos.rho0": 1.0, "eos.c0": 10.0, "eos.gamma": 7.0, "eos.p0": 5.0, "physics.mu": 0.1})
GAS = Params({"eos.gamma": 1.4, "physics.mu": 0.01})


def _lattice(nx, ny, dx, x0=0.0, y0=0.0):
    X, Y = np.meshgrid(x0 + (np.arange(nx) + 0.5) * dx, y0 + (np.arange(ny) + 0.5) * dx, indexing="ij")
    return np.stack([X.ravel(), Y.ravel()], axis=1)


def _channel(scheme, params, vel=(0.0, 0.0), nx=8, ny=10, slip=False, rho=None, seed=None):
    """Fluid between plates at y = 0 and y = 1 (periodic in x) with boundary-integral walls."""
    dx = 1.0 / ny
    x = _lattice(nx, ny, dx)
    n = len(x)
    eos = get_eos(scheme.eos)
    v = np.broadcast_to(np.asarray(vel, float), (n, 2)).copy()
    r = np.ones(n) if rho is None else rho
    if seed is not None:   # a non-uniform state
        rng = np.random.default_rng(seed)
        v += 0.3 * rng.standard_normal((n, 2))
        r = 1.0 + 0.05 * rng.standard_normal(n)
    p_arg = None if scheme.eos == "tait" else jnp.asarray(r)          # ideal gas: p = rho (e = 2.5)
    U = to_conservative(jnp.asarray(r), jnp.asarray(v), p_arg, eos, params)
    pf = make_particles(x, np.full(n, dx * dx), U)
    domain = Domain((0.0, -dx), (nx * dx, 1.0 + dx), (True, False))
    band = scheme.support * scheme.beta * dx
    walls = [Wall(1, 0.0, 1, slip=slip), Wall(1, 1.0, -1, slip=slip)]
    p, bw = BOUNDARIES.get("boundary_integral").setup(pf, walls, band, params, scheme.eos, scheme=scheme,
                                                       domain=domain)
    return p, bw, domain


def _body_box(curve, scheme, params, vel=(0.0, 0.0), dx=0.1, pressure=None):
    """A body in a periodic box of fluid (lattice with the body cut out)."""
    from mlsph_jax.geometry import curve_params
    from mlsph_jax.geometry.checks import inside_polygon, outline

    m = int(round(3.0 / dx))
    x = _lattice(m, m, dx, -1.5, -1.5)
    x = x[~inside_polygon(x, outline(curve, Params(curve_params([curve]))))]
    n = len(x)
    eos = get_eos(scheme.eos)
    pr = jnp.ones(n) if pressure is None else jnp.asarray(pressure(x))
    U = to_conservative(jnp.ones(n), jnp.broadcast_to(jnp.asarray(vel, float), (n, 2)), pr, eos, params)
    pf = make_particles(x, np.full(n, dx * dx), U)
    domain = Domain((-1.5, -1.5), (1.5, 1.5), (True, True))
    p, bw = BOUNDARIES.get("boundary_integral").setup(pf, [], 2 * dx, params, scheme.eos, scheme=scheme,
                                                       domain=domain, curves=(curve,))
    return p, bw, domain


def _rhs(p, bw, domain, scheme, params):
    h = scheme.beta * p.vol ** (1.0 / p.dim)
    _, nl = nb.allocate(p.x, h, domain)

    @jax.jit
    def f(p, params):
        geom = geometry(p.x, p.vol, nl, scheme, domain)
        return rhs(p, params, geom, scheme, bw)

    return f(p, params)


def _scale(p, params, scheme):
    """Momentum flux through one particle face, (p + rho |u|^2) dx: the size of the terms that
    cancel, against which 'round-off' is measured."""
    pr = _prim(p, scheme, params)
    return float(jnp.max(pr.p + pr.rho * jnp.sum(pr.vel ** 2, axis=-1))) * float(p.vol[0]) ** 0.5


# --- uniform states -------------------------------------------------------------------------------

@pytest.mark.parametrize("viscous", [False, True])
def test_uniform_state_at_rest_stays_exactly_uniform(viscous):
    """Every bracket [F_b - F_i] and [F_j - F_i] vanishes: the rate is zero to round-off."""
    sch = Scheme(eos="tait", viscous=viscous)
    p, bw, dom = _channel(sch, TAIT)
    _, _, dq = _rhs(p, bw, dom, sch, TAIT)
    assert float(jnp.max(jnp.abs(dq))) < 1e-13 * _scale(p, TAIT, sch)


def test_boundary_term_closes_the_wall_rows_without_the_self_term():
    """Without the self term (conservative form) the wall rows of a uniform state feel the
    one-sided interior sum F . sum_j A_ij; the boundary term F_b . sum_b N_i(x_b) n_b dGamma_b
    cancels most of it (the rest is the one-point-quadrature defect of SPEC §5.5, measured:
    max |rate| 0.395 with the walls, 0.933 without at ny = 10; 0.198 / 0.466 at ny = 20)."""
    sch = Scheme(eos="tait", self_flux=False)
    p, bw, dom = _channel(sch, TAIT)
    _, _, dq = _rhs(p, bw, dom, sch, TAIT)
    _, _, dq0 = _rhs(p, None, dom, sch, TAIT)
    with_walls, without = float(jnp.max(jnp.abs(dq))), float(jnp.max(jnp.abs(dq0)))
    assert with_walls < 0.5 * without and without > 0.1 * _scale(p, TAIT, sch)


def _prim(p, sch, params):
    from mlsph_jax.eos import to_primitive
    return to_primitive(p.U, get_eos(sch.eos), params)


def test_uniform_stream_with_a_body_moving_along_stays_uniform():
    """Lagrangian particles and an ellipse all moving at U: every boundary term vanishes."""
    sch = Scheme(eos="ideal_gas", frame="lagrangian")
    U = (0.3, -0.1)
    ell = Ellipse("e", centre=(0.0, 0.0), semi_axes=(0.5, 0.25), angle=0.3, n_points=40, velocity=U)
    p, bw, dom = _body_box(ell, sch, GAS, vel=U)
    dx, dvol, dq = _rhs(p, bw, dom, sch, GAS)
    assert float(jnp.max(jnp.abs(dq))) < 1e-13 and float(jnp.max(jnp.abs(dvol))) < 1e-14
    assert np.allclose(np.asarray(dx), U, atol=1e-15)


def test_free_slip_wall_keeps_a_tangential_uniform_flow():
    sch = Scheme(eos="tait")
    p, bw, dom = _channel(sch, TAIT, vel=(1.0, 0.0), slip=True)
    _, _, dq = _rhs(p, bw, dom, sch, TAIT)
    assert float(jnp.max(jnp.abs(dq))) < 1e-13 * _scale(p, TAIT, sch)
    # a no-slip viscous wall does not: it drags the first rows
    sch_v = Scheme(eos="tait", viscous=True)
    p2, bw2, _ = _channel(sch_v, TAIT, vel=(1.0, 0.0))
    _, _, dq2 = _rhs(p2, bw2, dom, sch_v, TAIT)
    wall_rows = np.asarray(p2.x[:, 1]) < 0.1
    assert np.all(np.asarray(dq2[wall_rows, 1]) < -1e-3)


def test_isothermal_walls_keep_the_exact_steady_conduction_profile():
    """Isothermal boundary-integral walls (issue 17 item 2, "fixed temperature"): an ideal gas at
    rest between plates held at e = 2 (y = 0) and e = 3 (y = 1), uniform pressure, e linear in y
    (rho = p / ((gamma - 1) e)) is an exact steady state of heat conduction: the energy
    rate of every particle, the wall rows included, is zero to round-off (the constrained wall fit
    of e is exact for a linear profile and the wall rows are linearly consistent, decision 60; rho e
    is uniform, so the Rusanov dissipation adds nothing to it), and the heat the upper wall gives
    equals the heat the lower one takes, kappa (e1 - e0) per unit length.  (The mass rate is not
    zero: rho ~ 1/e is not polynomial, so its reconstructed states jump and the Rusanov flux
    diffuses them, ~2e-5 here, the same with adiabatic walls.)  With the walls adiabatic that heat
    piles up in the rows next to the cold wall instead.  Bad input: an unknown curve, a
    non-positive energy, a scheme without heat conduction."""
    ny, nx, e0, e1, kappa = 10, 8, 2.0, 3.0, 0.05
    params = GAS.updated({"physics.kappa": jnp.asarray(kappa)})
    sch = Scheme(eos="ideal_gas", viscous=True, heat_conduction=True)
    dx = 1.0 / ny
    x = _lattice(nx, ny, dx)
    e = e0 + (e1 - e0) * x[:, 1]
    p_const = 1.0
    rho = p_const / (0.4 * e)
    eos = get_eos("ideal_gas")
    U = to_conservative(jnp.asarray(rho), jnp.zeros((len(x), 2)), jnp.full(len(x), p_const), eos, params)
    pf = make_particles(x, np.full(len(x), dx * dx), U)
    domain = Domain((0.0, -dx), (nx * dx, 1.0 + dx), (True, False))
    walls = [Wall(1, 0.0, 1), Wall(1, 1.0, -1)]
    band = sch.support * sch.beta * dx

    def setup(energy, scheme=sch):
        return BOUNDARIES.get("boundary_integral").setup(pf, walls, band, params, "ideal_gas", scheme=scheme,
                                                          domain=domain, wall_energy=energy)

    p, bw = setup({"wall0": e0, "wall1": e1})
    _, _, dq = _rhs(p, bw, domain, sch, params)
    flux = kappa * (e1 - e0) / dx          # the conducted heat flux density; flux * dx per particle face
    assert float(jnp.max(jnp.abs(dq[:, 3]))) < 1e-11 * flux * dx
    assert float(jnp.max(jnp.abs(dq[:, 1:3]))) < 1e-13
    prim = to_primitive(p.q / p.vol[:, None], eos, params)
    bp, st, _, _, _, qb = bw.wall_state(p, params, sch, prim)
    per_wall = np.asarray(jax.ops.segment_sum(qb * bp.dgamma, bp.curve, 2))
    np.testing.assert_allclose(per_wall, [-kappa * (e1 - e0) * nx * dx, kappa * (e1 - e0) * nx * dx], rtol=1e-12)
    pa, bwa = setup(None)
    _, _, dqa = _rhs(pa, bwa, domain, sch, params)
    # adiabatic: the heat conducted through the interior, kappa (e1 - e0) per unit length, piles up in
    # the rows next to the cold wall and leaves those next to the hot one (the first-moment rows
    # spread it over three rows)
    low, high = np.asarray(x[:, 1]) < 0.3, np.asarray(x[:, 1]) > 0.7
    heat = kappa * (e1 - e0) * nx * dx
    assert float(jnp.sum(dqa[low, 3])) == pytest.approx(heat, rel=1e-12)
    assert float(jnp.sum(dqa[high, 3])) == pytest.approx(-heat, rel=1e-12)
    np.testing.assert_allclose(np.asarray(dqa[:, :3]), np.asarray(dq[:, :3]), rtol=0, atol=1e-15)
    for energy, words in [({"wall7": 2.0}, ["wall_energy curve 'wall7' (= 2.0)", "'wall0'"]),
                          (2.0, ["wall_energy=2.0", "mapping"]), ({"wall0": True}, ["wall_energy['wall0']=True"]),
                          ({"wall0": -1.0}, ["wall_energy['wall0']=-1.0", "> 0"]),
                          ({"wall0": float("nan")}, ["wall_energy['wall0']=nan"])]:
        with pytest.raises(InputError) as ei:
            setup(energy)
        assert all(w in str(ei.value) for w in words), str(ei.value)
    with pytest.raises(InputError, match=r"scheme\.heat_conduction=False.*allowed: scheme\.heat_conduction = true"):
        setup({"wall0": e0}, Scheme(eos="ideal_gas", viscous=True))


def test_exact_steady_poiseuille_has_no_residual_in_the_wall_rows():
    """Linear consistency of the wall rows (decision 54): the exact steady Poiseuille state
    u = f/(2 nu) y (1 - y) has a linear viscous flux, so every particle's rate, the three rows next
    to each wall included, is zero to round-off.  Before the wall rows were made consistent the
    rows 1-3 kept |du/dt| = 0.31, 0.08, 0.38 at every resolution (0.014, 0.34, 0.35 with the
    symmetric boundary term of eq. 4.22 alone)."""
    sch = Scheme(eos="tait", viscous=True)
    ny, nx, f = 10, 8, 0.8
    params = TAIT.updated({"physics.body_force": jnp.asarray([f, 0.0])})
    y = _lattice(nx, ny, 1.0 / ny)[:, 1]
    nu = float(TAIT["physics.mu"]) / float(TAIT["eos.rho0"])
    vel = np.stack([f / (2 * nu) * y * (1 - y), np.zeros_like(y)], axis=1)
    p, bw, dom = _channel(sch, params, vel=vel, nx=nx, ny=ny)
    _, _, dq = _rhs(p, bw, dom, sch, params)
    dudt = np.asarray(dq[:, 1] / p.vol)
    assert np.abs(dudt).max() < 1e-11 * f


# --- conservation ---------------------------------------------------------------------------------

def test_no_mass_through_walls_and_momentum_balances_the_wall_force():
    """Without the self term the pair terms are antisymmetric and the wall flux has no mass part:
    the total mass rate is zero to round-off for any state; the total momentum rate is minus the
    force of the fluid on the walls (Newton's third law)."""
    sch = Scheme(eos="ideal_gas", self_flux=False, viscous=True)
    p, bw, dom = _channel(sch, GAS, seed=1)
    _, _, dq = _rhs(p, bw, dom, sch, GAS)
    total = np.asarray(jnp.sum(dq, axis=0))
    flux_scale = float(jnp.sum(jnp.abs(dq[:, 0])))
    assert abs(total[0]) < 1e-13 * flux_scale
    force, _ = jax.jit(lambda p: bw.forces(p, GAS, sch))(p)
    assert np.allclose(total[1:3], -np.asarray(jnp.sum(force, axis=0)), rtol=0, atol=1e-12 * flux_scale)


# --- forces ---------------------------------------------------------------------------------------

# the circle (with its radius derivative) and the polygon are slow (CI time); the rotated ellipse
# keeps Archimedes in the default suite, and test_shape_sensitivity the shape derivatives
@pytest.mark.parametrize("curve", [
    pytest.param(Circle("c", centre=(0.05, 0.1), radius=0.5, n_points=64), marks=pytest.mark.slow),
    Ellipse("c", centre=(0.0, -0.1), semi_axes=(0.6, 0.3), angle=0.5, n_points=64),
    pytest.param(Polygon("c", vertices=((-0.5, -0.4), (0.6, -0.3), (0.1, 0.5)), spacing=0.05),
                 marks=pytest.mark.slow),
])
def test_buoyancy_is_archimedes_and_uniform_pressure_gives_no_force(curve):
    sch = Scheme(eos="ideal_gas")
    rho_g, p0 = 0.7, 10.0
    p, bw, _ = _body_box(curve, sch, GAS, pressure=lambda x: p0 - rho_g * x[:, 1])
    force, fp = jax.jit(lambda p: bw.forces(p, GAS, sch))(p)
    area = {"Circle": math.pi * 0.25, "Ellipse": math.pi * 0.18}.get(type(curve).__name__)
    if area is None:
        v = np.asarray(curve.vertices)
        area = 0.5 * abs(np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1]))
    assert abs(float(force[0, 1]) / (rho_g * area) - 1.0) < 1e-10 and abs(float(force[0, 0])) < 1e-12
    co = bw.coefficients(p, GAS, sch, rho_inf=2.0, u_inf=(0.0, -3.0), length=0.5, curve="c")
    assert abs(float(co["cd"]) + rho_g * area / (0.5 * 2.0 * 9.0 * 0.5)) < 1e-10     # lift up = drag against -y
    assert abs(float(co["cl"])) < 1e-11 and float(co["cd"]) == float(co["cd_pressure"])
    if isinstance(curve, Circle):   # d(buoyancy)/d(radius) = 2 pi r rho g through the quadrature and the MLS
        key = "geometry.c.radius"
        P = GAS.updated(bw.default_params())
        g = jax.jit(jax.grad(lambda P: bw.forces(p, P, sch)[0][0, 1]))(P)[key]
        assert abs(float(g) / (2 * math.pi * 0.5 * rho_g) - 1.0) < 1e-9
    pu, bwu, _ = _body_box(curve, sch, GAS, pressure=lambda x: np.full(len(x), p0))
    fu, _ = jax.jit(lambda p: bwu.forces(p, GAS, sch))(pu)
    assert float(jnp.max(jnp.abs(fu))) < 1e-13 * p0


# --- the wall fit ---------------------------------------------------------------------------------

def test_constrained_wall_gradient_is_exact_for_quadratic_profiles():
    dx = 0.1
    x = jnp.asarray(_lattice(10, 6, dx))
    vol = jnp.full(len(x), dx * dx)
    xb = jnp.asarray([[0.3, 0.0], [0.55, 0.0]])
    st = wall_stencils(x, vol, jnp.zeros(len(x), jnp.int32), xb, beta=1.5, support=2.0, capacity=40)
    a, b, uw = 2.0, -3.0, 0.4
    u = jnp.stack([uw + a * x[:, 1] + b * x[:, 1] ** 2, jnp.zeros(len(x))], axis=1)
    G = constrained_gradient(st, u, jnp.asarray([[uw, 0.0]] * 2), get_kernel("cubic_spline"), 2)
    assert np.allclose(np.asarray(G), [[[0.0, a], [0.0, 0.0]]] * 2, atol=1e-12)
    # a wrong wall velocity changes the gradient: the constraint is imposed, not fitted
    G2 = constrained_gradient(st, u, jnp.asarray([[uw + 0.1, 0.0]] * 2), get_kernel("cubic_spline"), 2)
    assert float(jnp.abs(G2[0, 0, 1] - a)) > 0.5


# without a body is slow (CI time): the body case checks the same search and more
@pytest.mark.parametrize("body", [True, pytest.param(False, marks=pytest.mark.slow)])
def test_cell_list_stencils_are_the_brute_force_stencils(body):
    """The cell-list wall-stencil search sees the same particles in the same order as the
    O(N_b N) pass: on the lattice (equal distances: ties must break alike) and jittered (no
    symmetry to hide a missed candidate); the periodic channel wraps its stencils across the
    box.  Indices, slots and counts exactly, the offsets to round-off (bit for bit with the
    default code generator).  A support beyond the cells is reported."""
    sch = Scheme(eos="ideal_gas")
    if body:
        p, bw, domain = _body_box(Circle("cyl", radius=0.5, n_points=40), sch, GAS)
    else:
        p, bw, domain = _channel(sch, GAS)
    rng = np.random.default_rng(3)
    xb = bw.points({}).x
    kern = get_kernel(bw.kernel)
    args = dict(beta=bw.beta, support=kern.support, capacity=bw.capacity, box=bw._box())
    # the grid the set-up plans (it keeps the distance pass for these small layouts, where the
    # cells would hold more than half the fluid: the comparison builds the grid itself)
    grid = search_grid(p.x, bw.beta * np.asarray(p.vol) ** 0.5, domain, kern.support)
    brute_f = jax.jit(lambda x: wall_stencils(x, p.vol, p.kind, xb, **args))
    cells_f = jax.jit(lambda x: wall_stencils(x, p.vol, p.kind, xb, grid=grid, **args))
    for jitter in (0.0, 0.2):
        x = p.x + jitter * float(p.vol[0]) ** 0.5 * jnp.asarray(rng.uniform(-1, 1, p.x.shape))
        brute, cells = brute_f(x), cells_f(x)
        assert int(jnp.max(brute.count)) <= bw.capacity
        for a, b in zip(jax.tree_util.tree_leaves(brute), jax.tree_util.tree_leaves(cells), strict=True):
            a, b = np.asarray(a), np.asarray(b)
            assert a.dtype == b.dtype
            if a.dtype.kind == "f":     # offsets: two programs, to round-off (decision 98)
                np.testing.assert_allclose(a, b, rtol=0, atol=1e-13 * max(np.abs(b).max(), 1e-300))
            else:                       # which points, in which slots: exactly
                np.testing.assert_array_equal(a, b)
    # volumes grown so that the support outreaches the cells: the search says it is incomplete
    big = wall_stencils(x, p.vol * 4.0, p.kind, xb, grid=grid, **args)
    assert int(jnp.min(big.count)) > bw.capacity


def _fixed_walls_case():
    sch = Scheme(eos="ideal_gas", viscous=True)
    p, bw, dom = _body_box(Circle("c", radius=0.5, n_points=40), sch, GAS, vel=(0.4, 0.1))
    rng = np.random.default_rng(5)
    p = p.replace(q=p.q * (1.0 + 0.05 * jnp.asarray(rng.standard_normal(p.q.shape))))
    P = GAS.updated(bw.default_params())
    _, nl = nb.allocate(p.x, sch.beta * p.vol ** 0.5, dom)
    geom = jax.jit(lambda p: geometry(p.x, p.vol, nl, sch, dom))(p)

    def loss(P, fixed):
        walls = bw.fix(p, P) if fixed else bw
        dq = rhs(p, P, geom, sch, walls)[2]
        return jnp.sum(dq[:, 1] ** 2), dq

    return p, bw, P, loss


@pytest.mark.slow   # ~20 s, CI time; the reduced cylinder fingerprints run the searches-once path
def test_searches_done_once_for_fixed_particles_give_the_same_rate():
    """BoundaryIntegralWalls.fix (what an Eulerian run does once per chunk): the rate of a
    non-uniform viscous state is the per-stage searches' bit for bit, and the in-run check
    still sees a wall point crowded beyond its stencil capacity (every Eulerian run with these
    walls, e.g. the cylinder fingerprint, checks the clean status)."""
    p, bw, P, loss = _fixed_walls_case()
    per_stage, once = (jax.jit(lambda P, f=f: loss(P, f)[1])(P) for f in (False, True))
    assert float(jnp.max(jnp.abs(per_stage))) > 0.1 and np.array_equal(np.asarray(per_stage), np.asarray(once))
    status = jax.jit(lambda p: bw.fix(p, P).band_status(p)[0])
    crowd = p.replace(x=jnp.concatenate([p.x, jnp.tile(jnp.asarray([[0.6, 0.0]]), (60, 1))]),
                      vol=jnp.concatenate([p.vol, jnp.full(60, 0.01)]), q=jnp.concatenate([p.q, p.q[:60]]),
                      kind=jnp.concatenate([p.kind, jnp.zeros(60, p.kind.dtype)]),
                      ppd=jnp.concatenate([p.ppd, p.ppd[:60]]))
    assert Status(int(status(crowd))) & Status.BOUNDARY_OVERFLOW


@pytest.mark.slow   # 36 s (two gradient compilations through the wall terms)
def test_searches_done_once_for_fixed_particles_give_the_same_gradient():
    """The gradient with respect to the body's radius is the per-stage searches' (the offsets
    x_j - x_b of the fixed stencils stay functions of the parameters)."""
    _, _, P, loss = _fixed_walls_case()
    key = "geometry.c.radius"
    g0, g1 = (jax.jit(jax.grad(lambda P, f=f: loss(P, f)[0]))(P)[key] for f in (False, True))
    assert float(g0) != 0.0 and float(g1) == pytest.approx(float(g0), rel=1e-12)


# --- in-run checks and bad input --------------------------------------------------------------------

def test_particle_crossing_a_wall_or_crowding_it_stops_the_run():
    sch = Scheme(eos="ideal_gas")
    circ = Circle("cyl", radius=0.5, n_points=40)
    p, bw, _ = _body_box(circ, sch, GAS)
    bits, bad = bw.band_status(p)
    assert int(bits) == 0 and int(bad) == -1
    moved = p.replace(x=p.x.at[7].set(jnp.asarray([0.1, 0.2])))
    bits, bad = bw.band_status(moved)
    assert Status(int(bits)) == Status.WALL_CROSSED and int(bad) == 7
    # the step status of every run path sees it
    stats = (p.ppd, jnp.asarray(0), jnp.asarray(0), jnp.asarray(-1))
    bits, bad = step_status(p, moved, GAS, sch, 1e-3, jnp.asarray(0, jnp.int32), stats, boundary=bw)
    assert Status(int(bits)) == Status.WALL_CROSSED and int(bad) == 7
    crowd = p.replace(x=jnp.concatenate([p.x, jnp.tile(jnp.asarray([[0.6, 0.0]]), (60, 1))]),
                      vol=jnp.concatenate([p.vol, jnp.full(60, 0.01)]), q=jnp.concatenate([p.q, p.q[:60]]),
                      kind=jnp.concatenate([p.kind, jnp.zeros(60, p.kind.dtype)]),
                      ppd=jnp.concatenate([p.ppd, p.ppd[:60]]))
    bits, _ = bw.band_status(crowd)
    assert Status(int(bits)) & Status.BOUNDARY_OVERFLOW
    pc, bwc, _ = _channel(Scheme(eos="tait", viscous=True), TAIT)
    below = pc.replace(x=pc.x.at[3].set(jnp.asarray([0.35, -0.01])))
    assert Status(int(bwc.band_status(below)[0])) == Status.WALL_CROSSED


def test_bad_set_up_is_refused():
    with pytest.raises(InputError, match="scheme.method='sph_ale'"):
        _channel(Scheme(eos="tait", method="sph_ale"), TAIT)
    with pytest.raises(InputError, match=r"fluid particle \d+ .* inside the body geometry.cyl"):
        sch = Scheme(eos="ideal_gas")
        x = _lattice(10, 10, 0.1)
        pf = make_particles(x, np.full(len(x), 0.01), jnp.tile(jnp.asarray([[1.0, 0.0, 0.0, 2.5]]), (len(x), 1)))
        BOUNDARIES.get("boundary_integral").setup(pf, [], 0.2, GAS, "ideal_gas", scheme=sch,
                                                  domain=Domain((0.0, 0.0), (1.0, 1.0), (True, True)),
                                                  curves=(Circle("cyl", centre=(0.5, 0.5), radius=0.2, n_points=20),))
    assert Kind.FLUID == 0


# --- channel flows against the exact series and the mirror ghosts ----------------------------------

QUIET = ("output.progress=false", "output.plots=false")


def _channel_run(path, walls, *overrides):
    from mlsph_jax import config
    from mlsph_jax.cases import build_problem
    from mlsph_jax.simulation import run_problem

    cfg = config.load(path, [*QUIET, "case.nx=8", "time.cfl=0.6", f"case.walls={walls}", *overrides])
    return run_problem(build_problem(cfg), cfg, out_dir=None, quiet=True).summary


def test_couette_with_boundary_integral_walls_matches_the_exact_series():
    """Start-up Couette (Re 10, ny = 10, t = 1; ~12 s) on boundary-integral walls against the exact
    series, with the config's cubic reconstruction: measured L-inf error 1.67e-3 (mirror ghosts
    2.15e-3, compared in the slow test below; with the quadratic reconstruction 8.2e-3, and 0.0166
    before the wall rows were made linearly consistent, decision 60), no wall-normal velocity,
    mass conserved to round-off while the plates exchange momentum with the fluid."""
    sbi = _channel_run("configs/couette.toml", "boundary_integral", "case.ny=10", "time.t_end=1.0")
    bi = sbi["metrics"]
    assert bi["linf_u_error"] < 2.5e-3 and bi["max_abs_v"] < 1e-12
    # the plates exchange momentum with the fluid: reported as such, not as a drift of the scheme
    assert sbi["conservation_info"]["label"] == "change (boundary fluxes)" and abs(sbi["conservation"]["mass"]) < 1e-12


@pytest.mark.slow   # CI time: the boundary-integral run alone is the default test above
def test_couette_matches_the_exact_series_at_least_as_well_as_mirror_ghosts():
    """The same start-up Couette: the issue's target, L-inf error <= 2x the mirror ghosts'
    (measured 1.67e-3 against 2.15e-3 with the cubic reconstruction; 0.0082 against 0.0526 with
    the quadratic one)."""
    bi = _channel_run("configs/couette.toml", "boundary_integral", "case.ny=10", "time.t_end=1.0")["metrics"]
    mg = _channel_run("configs/couette.toml", "mirror_ghosts", "case.ny=10", "time.t_end=1.0")["metrics"]
    assert bi["linf_u_error"] <= 2.0 * mg["linf_u_error"]


def test_poiseuille_start_up_beats_the_mirror_ghosts():
    """Start-up Poiseuille (Re 10, ny = 10, t = 1) against the exact series: the issue's target
    (<= 2x the mirror ghosts' L-inf error), and the gain of the linearly consistent wall rows
    (decision 60): measured with the config's cubic reconstruction 6.37e-3 with the boundary
    integral against 0.0116 with mirror ghosts (ratio 0.55); with the quadratic one 0.0307 against
    0.0535, and 0.0459 with the wall rows as they were (which fails the second bound; at t = 6,
    ny = 10-40 the quadratic ratio is 0.006-0.024, docs/validation.md)."""
    bi = _channel_run("configs/poiseuille.toml", "boundary_integral", "case.ny=10", "time.t_end=1.0")["metrics"]
    mg = _channel_run("configs/poiseuille.toml", "mirror_ghosts", "case.ny=10", "time.t_end=1.0")["metrics"]
    assert bi["linf_u_error"] <= 2.0 * mg["linf_u_error"]
    assert bi["linf_u_error"] <= 0.7 * mg["linf_u_error"] and bi["max_abs_v"] < 1e-12
    assert bi["linf_u_error"] < 8e-3      # the cubic scheme's accuracy (the quadratic 0.0307 fails it)


#: Why the shifted frame's mass is not conserved to round-off on boundary-integral walls.
SHIFT_MASS = (
    "known defect (docs/architecture.md decisions 54, 78): once the particles are disordered, the drift along "
    "the walls varies across the wall rows, and the first-moment correction of those rows (not a pair "
    "difference) acts on the gradient of rho (u - w): measured mass change 9.7e-6 at t = 1 with the cubic "
    "reconstruction (4.7e-6 quadratic; 6.0e-4 while the drift still pointed into the walls, before decision 78, "
    "3.7e-3 before decision 60); 95-100 % of the rate is that correction, the rest the self-flux term's closure "
    "defect, as without walls (docs/moving_particles.md section 9); scheme.conservation_projection = true "
    "removes it (decision 112)")


def test_shifting_drift_has_no_component_into_the_walls():
    """Decision 78: the rows in a wall's stencil keep only the drift along the wall.  On the
    channel lattice the xu drift of those rows points straight at the walls (one-sided
    neighbourhoods); with it the self term of the boundary integral carried mass through the walls
    (instantaneous rate 1.4e-3 of a total |rate| 1.08 for this state); without it the mass rate is
    round-off, as for fixed particles."""
    from mlsph_jax.frames import shifting_velocity

    sch = Scheme(eos="ideal_gas", frame="ale_shift")
    p, bw, dom = _channel(sch, GAS, seed=1)
    h = sch.beta * p.vol ** (1.0 / p.dim)
    _, nl = nb.allocate(p.x, h, dom)

    @jax.jit
    def drifts(p):
        geom = geometry(p.x, p.vol, nl, sch, dom)
        dw = shifting_velocity(jnp.ones_like(p.x), geom, p.kind, sch, p.vol)
        return dw, bw.drift_at_walls(p, GAS, dw), rhs(p, GAS, geom, sch, bw)[2]

    dw, kept, dq = drifts(p)
    dw, kept = np.asarray(dw), np.asarray(kept)
    y = np.asarray(p.x[:, 1])
    first = (np.asarray(p.kind) == Kind.FLUID) & ((y < 0.1) | (y > 0.9))   # the rows next to the plates
    middle = (y > 0.4) & (y < 0.6)                                           # beyond every wall stencil
    tol = 1e-14 * np.abs(dw).max()                        # round-off of the projection
    assert np.abs(dw[first, 1]).min() > 1e-3            # the drift did point at the walls
    np.testing.assert_allclose(kept[first, 1], 0.0, atol=tol)   # ... and now has no normal part
    np.testing.assert_allclose(kept[:, 0], dw[:, 0], rtol=0, atol=tol)   # along the walls: kept
    changed = np.any(kept != dw, axis=1)
    np.testing.assert_allclose(kept[changed, 1], 0.0, atol=tol)
    np.testing.assert_array_equal(kept[middle], dw[middle])

    scale = float(jnp.sum(jnp.abs(dq[:, 0])))
    assert abs(float(jnp.sum(dq[:, 0]))) < 1e-13 * scale


@pytest.mark.slow
@pytest.mark.parametrize("frame,projection", [("lagrangian", False), ("ale_shift", False), ("ale_shift", True)])
def test_couette_on_moving_particles(frame, projection):
    """The same walls on moving particles (no ghosts to keep in step): measured, ny = 10, t = 1,
    cubic reconstruction: L-inf 1.70e-3 in both frames (the Eulerian 1.67e-3), max |v| 8.1e-5,
    mass change 7e-15 (Lagrangian) and 9.7e-6 (``ale_shift`` without
    ``scheme.conservation_projection``: a known defect, reported as an expected failure after the
    accuracy is asserted; with it -7e-15 and L-inf 1.66e-3, decision 112); quadratic: L-inf 0.0081,
    0.0166 before decision 60, mirror ghosts 0.0512."""
    s = _channel_run("configs/couette.toml", "boundary_integral", "case.ny=10", "time.t_end=1.0",
                     f"scheme.frame={frame}", f"scheme.conservation_projection={str(projection).lower()}")
    assert s["status"] == "ok" and s["metrics"]["linf_u_error"] < 2.5e-3, s["metrics"]
    mass = abs(s["conservation"]["mass"])
    if frame == "ale_shift" and not projection and mass >= 1e-12:
        pytest.xfail(f"{SHIFT_MASS} (this run: {mass:.2g})")
    assert mass < 1e-12


def test_a_wall_velocity_across_the_wall_is_refused_before_a_run():
    """Issue 17 bad input, "a wall moving through particles": walls stay where they were set up,
    so every run path (run.setup_run) refuses a wall velocity with a normal component, naming the
    key and value: a translating or turning body (ellipse), a boundary-integral wall segment or a
    mirror wall moving along its normal.  Tangential motion runs: a circle turning about its
    centre, plates sliding along themselves (the built-in Couette)."""
    import dataclasses

    from mlsph_jax import config
    from mlsph_jax.cases import build_problem
    from mlsph_jax.run import setup_run
    from mlsph_jax.simulation import Simulation
    from mlsph_jax.testing import CONFIG_DIR, REDUCED_OVERRIDES

    def problem(name, *sets):
        return build_problem(config.load(CONFIG_DIR / f"{name}.toml", [*REDUCED_OVERRIDES[name], *sets]))

    def refused(pb, new, *words):
        new = {k: jnp.asarray(v, jnp.float64) for k, v in new.items()}
        bad = dataclasses.replace(pb, params=pb.params.updated(new))
        with pytest.raises(InputError) as e:
            setup_run(bad)
        for w in ("moves across itself", "allowed: a finite", *words):
            assert w in str(e.value), (w, str(e.value))

    cyl = problem("cylinder")
    setup_run(dataclasses.replace(cyl, params=cyl.params.updated({"geometry.body.omega": jnp.asarray(2.0)})))
    # a float32 run (run.precision; Simulation casts the params): the turning circle's float32
    # round-off (3e-8 of its speed with XLA's default code generator; below the tolerance under this
    # suite's compile flags, tests/conftest.py, so only a script shows the failure without the float64
    # evaluation in check_motion) is not a crossing
    Simulation(dataclasses.replace(cyl, params=cyl.params.updated({"geometry.body.omega": jnp.asarray(2.0)})),
               precision="float32")
    refused(cyl, {"geometry.body.velocity": [0.5, 0.0]}, "geometry.body.velocity=[0.5, 0.0]", "'body'")
    ell = problem("cylinder", "case.body=ellipse", "case.aspect=2.0")
    refused(ell, {"geometry.body.omega": 1.0}, "geometry.body.omega=1.0")
    couette = problem("couette")
    setup_run(couette)   # the top plate slides along itself
    refused(couette, {"boundary.wall_velocity": [[0.0, 0.0], [1.0, 1e-3]]}, "boundary.wall_velocity[1]=[1.0, 0.001]")
    for v in (float("nan"), float("inf")):
        with pytest.raises(InputError, match=r"boundary\.wall_velocity\[0\]=.*has a non-finite velocity"):
            setup_run(dataclasses.replace(couette, params=couette.params.updated(
                {"boundary.wall_velocity": jnp.asarray([[0.0, v], [1.0, 0.0]])})))
    bi = problem("couette", "case.walls=boundary_integral")
    refused(bi, {"boundary.wall_velocity": [[0.0, -0.2], [1.0, 0.0]]}, "boundary.wall_velocity[0]=[0.0, -0.2]")


def test_a_particle_crossing_the_body_stops_both_run_paths(monkeypatch, tmp_path):
    """Issue 17: a particle that crosses a wall during a run stops it loudly with the step, time and
    particle, and the last good snapshot stays on disk.  The first step's candidate of the reduced
    cylinder config is corrupted (one fluid particle moved to the body's centre) on the driver's
    path and on the differentiated one (make_simulate / run_differentiable)."""
    import h5py

    from mlsph_jax import config, differentiable, integrate
    from mlsph_jax.cases import build_problem
    from mlsph_jax.differentiable import make_simulate, run_differentiable
    from mlsph_jax.errors import SimulationError
    from mlsph_jax.simulation import run_problem
    from mlsph_jax.testing import CONFIG_DIR, REDUCED_OVERRIDES

    cfg = config.load(CONFIG_DIR / "cylinder.toml", [*REDUCED_OVERRIDES["cylinder"], "output.plots=false",
                                                      "output.progress=false"])
    pb = build_problem(cfg)
    bad = int(np.flatnonzero(np.asarray(pb.particles.kind) == Kind.FLUID)[5])
    real = integrate.ssp_rk3_step

    def step(p, params, dt, scheme, geom_fn, boundary=None, cache=None):
        out, ovf, stats, *rest = real(p, params, dt, scheme, geom_fn, boundary, cache)
        return out.replace(x=out.x.at[bad].set(jnp.zeros(2))), ovf, stats, *rest

    monkeypatch.setattr(integrate, "ssp_rk3_step", step)
    monkeypatch.setattr(differentiable, "ssp_rk3_step", step)
    with pytest.raises(SimulationError) as ei:
        run_problem(pb, cfg, out_dir=tmp_path, quiet=True)
    e = ei.value
    assert (Status(e.status) & Status.WALL_CROSSED, e.step, e.time, e.particle) == (Status.WALL_CROSSED, 1, 0.0, bad)
    assert f"particle {bad}" in str(e) and "step 1" in str(e)
    with h5py.File(tmp_path / "fields.h5") as f:
        last = f["snapshots"][sorted(f["snapshots"], key=int)[-1]]
        np.testing.assert_array_equal(last["x"][()], np.asarray(pb.particles.x))
    sim = make_simulate(pb, n_steps=3, t_end=0.005, checkpoint="none")   # dt below the CFL step
    with pytest.raises(SimulationError, match=f"in step 1 starting at t=0, particle {bad}") as ei:
        run_differentiable(sim, pb.params, pb.particles)
    assert Status(ei.value.status) & Status.WALL_CROSSED


def test_each_curve_of_a_viscous_scheme_takes_its_own_wall_normal_velocity():
    """Decisions 108 and 109 on one viscous scheme with a no-slip and a free-slip body: the free-slip
    body's vn_b is the quadratic MLS at its wall points, which reproduces a quadratic velocity
    field (vn_b = (u(x_b) - u_w) . n_b to round-off, where the linear wall state is off by O(h^2)),
    and the no-slip body's is decision 108's fit without the linear normal term, point for point."""
    from mlsph_jax.geometry import curve_params
    from mlsph_jax.geometry.checks import inside_polygon, outline
    from mlsph_jax.wall_integral import no_slip_normal_weights

    sch = Scheme(eos="ideal_gas", viscous=True)
    curves = (Circle("a", centre=(-0.75, 0.0), radius=0.35, n_points=44),
              Circle("b", centre=(0.75, 0.0), radius=0.35, n_points=44))
    dx = 0.05
    x = _lattice(60, 40, dx, -1.5, -1.0)
    P = Params(curve_params(list(curves)))
    for c in curves:
        x = x[~inside_polygon(x, outline(c, P))]
    n = len(x)
    vel = np.stack([0.3 + x[:, 0] - 0.5 * x[:, 1] ** 2, 0.2 * x[:, 0] * x[:, 1] + 0.4 * x[:, 0] ** 2], axis=1)
    U = to_conservative(jnp.ones(n), jnp.asarray(vel), jnp.ones(n), get_eos(sch.eos), GAS)
    pf = make_particles(x, np.full(n, dx * dx), U)
    domain = Domain((-1.5, -1.0), (1.5, 1.0), (True, True))
    p, bw = BOUNDARIES.get("boundary_integral").setup(pf, [], 2 * dx, GAS, sch.eos, scheme=sch, domain=domain,
                                                       curves=curves, no_slip=(True, False))
    bp, st, vals = bw.state_weights(p, GAS, sch)
    vn = np.asarray(bw.normal_velocity(sch, bp, st, vals, jnp.asarray(vel)))
    xb, normal, curve = np.asarray(bp.x), np.asarray(bp.normal), np.asarray(bp.curve)
    exact = np.einsum("bd,bd->b", np.stack([0.3 + xb[:, 0] - 0.5 * xb[:, 1] ** 2,
                                             0.2 * xb[:, 0] * xb[:, 1] + 0.4 * xb[:, 0] ** 2], axis=1), normal)
    vj = np.einsum("bkd,bd->bk", vel[np.asarray(st.idx)], normal)
    linear = np.einsum("bk,bk->b", np.asarray(vals), vj)
    slip = curve == 1
    assert np.abs(vn[slip] - exact[slip]).max() <= 1e-11
    assert np.abs(linear[slip] - exact[slip]).max() >= 1e-4          # the linear state is not exact
    Nn, ok = no_slip_normal_weights(st, bp.normal, get_kernel(bw.kernel), sch.wall_fit_rcond)
    assert bool(np.all(np.asarray(ok)[~slip]))
    np.testing.assert_allclose(vn[~slip], np.einsum("bk,bk->b", np.asarray(Nn), vj)[~slip], rtol=0, atol=1e-14)
