"""Walls and bodies by the boundary integral of thesis eq. 4.24 (SPEC §5.8, §8.4): no ghosts.

Thesis eq. 4.24 carries, for every pair, the boundary term
B_ij = int_dOmega N_i N_j n dGamma.  With quadrature points x_b, lengths dGamma_b and normals n_b
out of the fluid (:mod:`mlsph_jax.geometry`), B_ij ~ sum_b N_i(x_b) N_j(x_b) n_b dGamma_b.  Eq. 4.22
averages the integrated-by-parts form 4.20 (which holds the boundary integral, where the wall
flux F_b enters) with the plain form 4.19, so the term added to the left-hand side of eq. 4.36
(SPEC §5.8; docs/architecture.md decisions 54 and 58) is

    B_i = sum_b dGamma_b N_i(x_b) [F_b - F_h(x_b)/2 - (s - 1/2) F_i] . n_b,   s = ``scheme.self_flux``,

F_h(x_b) = sum_j N_j(x_b) F_j the particles' own flux at the wall point (for s = 1: half the
jump to the wall flux from eq. 4.22's [(F_j + F_i)/2 - F_i] . B_ij, the other half from 4.20),
with F = F_w - D the total (ALE convective minus diffusive) flux, N_i(x_b) the MLS shape
function of particle i evaluated at x_b over the particles around x_b (linear,
:data:`WALL_STATE_DEGREE`; smoothing length h_b = beta V^(1/d) of the particle nearest to x_b),
and

* F_b . n_b = (0, p* n_b - tau_b n_b, p* u_w.n_b - (tau_b n_b).u_w): no mass through the wall
  (the wall moves with its own normal velocity u_w.n_b); p* = p_b + rho_b vn (vn + |vn| + c_b)
  the pressure of the Rusanov flux between the wall state (rho, u, p, c)_b = sum_j N_j(x_b)
  (rho, u, p, c)_j and its mirror image, vn = (u_b - u_w) . n_b (SPEC §5.8's Riemann
  alternative; it damps wall-normal acoustic modes; on the no-slip walls of a viscous scheme vn
  comes from the fit that holds the no-slip profile u_n = O(y^2) exactly,
  :func:`no_slip_normal_weights`, decision 108; on free-slip walls and on every wall of an
  inviscid scheme from the quadratic fixed-centre MLS at x_b, :data:`FREE_SLIP_NORMAL_DEGREE`,
  decision 109); tau_b the viscous stress at the wall;
  adiabatic walls (the default) pass no heat; an *isothermal* wall (``wall_energy`` of
  :meth:`BoundaryIntegral.setup`: the specific internal energy e_w of the wall, Params key
  ``geometry.<name>.wall_e``, differentiable) adds the conductive flux -kappa grad(e)_b . n_b to
  the energy row, grad(e)_b from the fixed-centre MLS fit at x_b constrained to e(x_b) = e_w (the
  velocity's constrained fit applied to e; needs ``scheme.heat_conduction`` and an EOS with an
  energy equation; to differentiate with respect to e_w, put ``walls.default_params()``'s
  ``wall_e`` keys into the problem's Params, as the cases do with their curves' parameters);
* no-slip walls: tau_b from the velocity gradient of a fixed-centre MLS fit at x_b of degree
  ``scheme.fit_degree`` *constrained* to pass through the wall velocity, u(x_b) = u_w (the
  constant coefficient is u_w; the others are the weighted least-squares fit of u_j - u_w),
  falling back in degree where the stencil cannot carry it (:func:`constrained_fit_degrees`:
  the cubic fit, ill-conditioned on the three particle rows of a lattice wall and singular at
  the corners of a box; decision 61);
* free-slip walls: tau_b = 0.

The volume of moving particles follows the same rule (thesis eq. 4.32 with the boundary term,
the FVPM form T(5.67)): dV_i/dt += sum_b dGamma_b N_i(x_b) (u_w - w_h(x_b)/2 - (s - 1/2) w_i) . n_b.
Summed over the particles, with s = 0 the boundary terms give exactly the wall fluxes
sum_b F_b . n_b dGamma_b (sum_i N_i(x_b) F_i = F_h(x_b); no mass crosses a wall, to round-off);
with s = 1 a uniform state on the walls' own velocity stays uniform exactly.

Linear consistency (s = 1, decision 60): the one-point pair areas of the rows whose neighbours'
supports the wall truncates, with the wall quadrature, give a linear flux F the rate
G : V_i (I + E_i) instead of G : V_i I (E_i = O(1), the same at every resolution).  The rows within
:data:`NEAR_SUPPORTS` supports of a wall point therefore get -V_i E_i : grad F_i (and
-V_i E_i : grad w_i in dV_i/dt), grad from the particle's own fit: the exact steady Poiseuille
state has a round-off residual in every row.

Stencils: every stage, each x_b takes the ``capacity`` nearest non-ghost particles within the
kernel support 2 h_b, searched among the particles of the cells around x_b on a cell grid sized
at set-up (:func:`mlsph_jax.neighbors.cell_candidates`, O((N + N_b) log N); the same stencils bit
for bit as the brute-force O(N_b N) pass it replaced).  The set-up sizes the capacity and the
grid; a stencil that outgrows it, or a fluid particle beyond a wall (inside a body,
outside a container, past a segment within the support band), stops the run with
``Status.BOUNDARY_OVERFLOW`` / ``Status.WALL_CROSSED`` (checked on every committed step against
the set-up geometry).  Nothing *guarantees* that Lagrangian or shifted particles stay in the
fluid: the wall pressure term pushes them back, and the check stops the run loudly when it
does not (docs/architecture.md decision 54).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping

import jax
import jax.numpy as jnp
import numpy as np

from .approximation import basis, mls
from .approximation.mls import cholesky_pivots
from .boundaries import BOUNDARIES
from .eos import Primitive, get_eos
from .errors import InputError
from .flux import ale_flux_dot
from .geometry import Segment, check_geometry, curve_params, quadrature
from .geometry.checks import beyond_segment, inside_polygon, outline
from .kernels import get_kernel
from .neighbors import NeighborSpec, cell_candidates, plan
from .state import Kind, Params, Particles, minimum_image
from .viscous import particle_flux, wall_flux

#: MLS degree of the wall state (rho, u, p, c at x_b): linear.  Measured on the Couette start-up
#: (ny = 10, CFL 0.6): with the quadratic MLS the extrapolating weights N_j(x_b) make the wall
#: terms stiff (the acoustic damping rho c vn of the wall flux exceeds SSP-RK3's stability range
#: at CFL 0.6, and without it the wall-normal velocity grows from 1e-14 to 0.4 by t = 10); the
#: linear MLS keeps it at round-off at CFL 0.3 and 0.6 and is exact for hydrostatic pressure.  The
#: no-slip walls' vn of decision 108 (:func:`no_slip_normal_weights`, milder weights than the linear
#: MLS) keeps it at round-off too (max |v| / u_max 6e-15 at t = 10, CFL 0.6, ny = 10, nx = 8).
WALL_STATE_DEGREE = 1

#: MLS degree of the wall-normal velocity vn_b = (u_b - u_w) . n_b in the acoustic term of the wall
#: pressure on free-slip walls and on every wall of an inviscid scheme (decision 109): quadratic.  A
#: free-slip wall bends the normal velocity (potential flow past a circle: u_n ~ 1 - R^2 / r^2), and
#: the linear state extrapolates that curvature with an O(h^2) error that c = U / M multiplies
#: (docs/validation.md "Euler flow past the circle").  The quadratic fit reproduces it, and keeps a
#: uniform penetration's whole restoring force.  Only vn changes; rho, p and c stay linear.  Measured
#: not stiff: a free-slip channel (ideal gas and Tait, random initial state) at CFL 0.6 behaves as
#: with the linear vn; only the whole quadratic wall state was (above).
FREE_SLIP_NORMAL_DEGREE = 2

#: Pivot threshold of that quadratic fit (:func:`mlsph_jax.approximation.mls.cholesky_pivots`): a wall
#: point's stencil lies on one side of the wall, so its normal-direction pivot is small on every
#: layout (0.012-0.13 on the cylinder's polar layouts at 48 and 96 on the body, 0.015 on the
#: cavity's lattice walls), below ``scheme.wall_fit_rcond`` (0.1) that guards the particles' own
#: truncated fits (it would reject all 48 points at 48 and 88 of 96 at 96).  Points whose stencil
#: falls below this (a single row of particles: 0) keep the linear wall state; the margin to the
#: smallest measured pivot bounds the weights (sum |N_j| 2.87 at 48 on the body, the linear state's
#: 1.79).
FREE_SLIP_NORMAL_RCOND = 5e-3


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class WallStencils:
    """Particles around each quadrature point: ``idx[Nb, K]`` (valid where ``mask``), offsets
    ``dx[Nb, K, d] = x_j - x_b``, smoothing lengths ``h[Nb]`` and the number ``count[Nb]`` of
    particles within the support (> K: overflow)."""

    idx: jax.Array
    mask: jax.Array
    dx: jax.Array
    h: jax.Array
    count: jax.Array


def search_grid(x, h, domain, support: float, headroom: float = 1.5, reach_h: float | None = None) -> NeighborSpec:
    """The cell grid of a wall-stencil search (:func:`wall_stencils` ``grid``): cells of the
    support radius ``support * reach_h`` with ``headroom`` (volumes of moving particles grow; a
    support beyond the cells stops the run loudly).  ``reach_h``: the largest smoothing length
    h_b of a wall point (the stencils' ``h``, that of the particle nearest to the point), default
    the largest ``h`` of all particles.  On a graded layout the wall points see only the small
    particles next to the body, whose supports are a small fraction of the far field's."""
    h = np.asarray(h)
    reach = float(h.max()) if reach_h is None else float(reach_h)
    # h is capped at the reach only so that plan()'s check "cell >= support * max h" accepts the
    # cells: the particles' own supports are not searched here, the wall points' are
    return plan(np.asarray(x), np.minimum(h, reach), domain, support=support, headroom=headroom,
                cell_size=support * reach * headroom)


def wall_stencils(x, vol, kind, xb, *, beta: float, support: float, capacity: int, box=None,
                  grid=None) -> WallStencils:
    """The ``capacity`` nearest non-ghost particles within ``support * h_b`` of each ``xb``
    (``box = (lengths, periodic)`` for minimum images).  ``grid``: a
    :class:`~mlsph_jax.neighbors.NeighborSpec` whose cells are at least the largest support
    radius: the candidates are the particles of the cells around x_b
    (:func:`~mlsph_jax.neighbors.cell_candidates`, O((N + N_b) log N)); without it every particle
    is a candidate (O(N_b N)).  Both give the same stencils bit for bit (candidates in ascending
    index order, so ties in distance break alike); a cell-list search that cannot see the whole
    support (a full cell, or support * h_b beyond the cell size) reports ``count`` = int32 max,
    which the in-run check turns into ``Status.BOUNDARY_OVERFLOW``."""
    d = x.shape[1]
    n = x.shape[0]
    L, per = box if box is not None else (None, None)
    if grid is None:
        cand = None
        r = minimum_image(x[None, :, :] - xb[:, None, :], L, per)             # [Nb, N, d]
        ok = jnp.broadcast_to((kind != Kind.GHOST)[None, :], r.shape[:2])
    else:
        cand, complete = cell_candidates(jax.lax.stop_gradient(xb), jax.lax.stop_gradient(x), grid)
        if cand.shape[1] < capacity:      # top_k needs at least ``capacity`` candidates
            cand = jnp.pad(cand, ((0, 0), (0, capacity - cand.shape[1])), constant_values=n)
        safe = jnp.minimum(cand, n - 1)
        r = minimum_image(x[safe] - xb[:, None, :], L, per)                   # [Nb, C, d]
        ok = (cand < n) & (kind[safe] != Kind.GHOST)
    r2 = jnp.where(ok, jnp.sum(r * r, axis=-1), jnp.inf)
    r2s = jax.lax.stop_gradient(r2)
    nearest = jnp.argmin(r2s, axis=1)
    if cand is not None:
        nearest = jnp.take_along_axis(safe, nearest[:, None], axis=1)[:, 0]
    h = beta * vol[nearest] ** (1.0 / d)
    within = r2s < jax.lax.stop_gradient(support * h)[:, None] ** 2
    score, slot = jax.lax.top_k(jnp.where(within, -r2s, -jnp.inf), capacity)
    mask = jnp.isfinite(score)
    dx = jnp.take_along_axis(r, slot[..., None], axis=1)
    count = jnp.sum(within, axis=1)
    idx = slot
    if cand is not None:
        idx = jnp.take_along_axis(safe, slot, axis=1)
        # the cells see the whole support, and the nearest particle found is the nearest of all
        # (one within a cell size of x_b; else a farther one could be missed)
        reach = ((jax.lax.stop_gradient(support * h) <= grid.cell_size)
                 & (jnp.min(r2s, axis=1) <= grid.cell_size ** 2))
        count = jnp.where(complete & reach, count, jnp.iinfo(jnp.int32).max)
    idx = jnp.where(mask, idx, 0)                                             # padding: particle 0
    return WallStencils(idx, mask, jnp.where(mask[..., None], dx, 0.0), h, count)


def _constrained_moments(st: WallStencils, kernel, degree: int):
    """Weights ``w[Nb, K]``, the basis without its constant ``P[Nb, K, m-1]`` (h-scaled offsets)
    and the moment matrices ``M[Nb, m-1, m-1]`` of the constrained wall fit."""
    xi = st.dx / st.h[:, None, None]
    P = basis.evaluate(xi, degree)[..., 1:]
    w = kernel.w_vec(st.dx, st.h[:, None]) * st.mask
    return w, P, jnp.einsum("bk,bkm,bkn->bmn", w, P, P)


def constrained_fit_degrees(M, degree: int, dim: int, rcond: float):
    """``(active[Nb, m-1], degree[Nb])``: the degree fallback of the constrained wall fit with the
    pivot test of the particles' own fits (decision 2: Cholesky pivot ratio s_j / M_jj <
    ``rcond`` drops the degree level of monomial j and every higher one), down to linear (which a
    stencil of more than 3 particles that are not collinear always carries).  A wall point whose
    stencil is cut by a second wall (the corners of a box, decision 61) has too few particles for
    a cubic fit (8 for 9 unknowns on a lattice) and drops to the degree they support; on the
    three particle rows of a straight lattice wall the cubic fit is ill-conditioned (pivot ratio
    0.0085 at beta = 1.5) and drops to quadratic too."""
    mdeg = np.asarray(basis.monomial_degrees(degree, dim))[1:]
    ok = jax.vmap(lambda A: cholesky_pivots(A, rcond)[1])(jax.lax.stop_gradient(M))       # [Nb, m-1]
    run = jnp.ones(M.shape[0], bool)
    top = jnp.ones(M.shape[0], jnp.int32)
    for lev in range(2, degree + 1):
        run = run & jnp.all(jnp.where(jnp.asarray(mdeg == lev)[None, :], ok, True), axis=-1)
        top = top + run.astype(jnp.int32)
    return jnp.asarray(mdeg)[None, :] <= top[:, None], top


def constrained_gradient(st: WallStencils, u, u_wall, kernel, degree: int, rcond: float | None = None):
    """Gradient ``G[Nb, d, d]`` (G[a, c] = du_a/dx_c) at x_b of the weighted least-squares
    polynomial of ``degree`` through ``u_wall[Nb, d]`` at x_b fitted to ``u[N, d]`` on the
    stencil (the wall constraint u(x_b) = u_w of SPEC §5.8, imposed exactly).  ``rcond``: the
    degree fallback of :func:`constrained_fit_degrees` (None: none; a point whose stencil cannot
    carry ``degree`` then gives a singular fit); where every level is kept the solve is the
    plain one, bit for bit."""
    d = st.dx.shape[-1]
    w, P, M = _constrained_moments(st, kernel, degree)
    rhs = jnp.einsum("bk,bkm,bka->bma", w, P, u[st.idx] - u_wall[:, None, :])
    if rcond is not None:
        active, _ = constrained_fit_degrees(M, degree, d, rcond)
        eye = jnp.eye(M.shape[-1], dtype=M.dtype)
        M = jnp.where(active[:, :, None] & active[:, None, :], M, eye)
        rhs = jnp.where(active[..., None], rhs, 0.0)
    coef = jnp.linalg.solve(M, rhs)                                           # [Nb, m-1, d]
    g0 = jnp.asarray(basis.gradient_at_origin(degree, d)[1:], st.h.dtype)     # [m-1, d]
    return jnp.einsum("mc,bma->bac", g0, coef) / st.h[:, None, None]


def no_slip_normal_weights(st: WallStencils, normal, kernel, rcond: float):
    """Weights ``Nn[Nb, K]`` of the wall-normal velocity at a no-slip wall point: the value at x_b
    of the weighted least-squares quadratic in the offsets *without the term linear in the
    wall-normal coordinate* (decision 108).  At a no-slip wall the velocity relative to the wall
    vanishes along it and (mass, div u = -(1/rho) D rho/Dt ~ 0) so does the normal derivative of
    its normal component: u_n = O(y^2) with y the distance from the wall.  The linear wall state
    extrapolates that profile with an O(h^2) negative intercept that the acoustic term rho c vn of
    the mirror Riemann problem multiplies by c = U / M (docs/validation.md "Euler flow past the
    circle"); this basis, {1, t, t^2, t y, y^2} in 2D (t tangential, from a Householder frame whose
    first axis is n_b), reproduces u_n = a + b . t + (quadratic) exactly, so a quadratic no-slip
    profile gives vn_b = 0 (on a curved wall, whose tilt enters as t y, the error of a smooth
    no-slip field converges at order ~2.6 on the polar layout; the linear state's at ~1.4) while
    a uniform penetration V keeps its whole restoring force (vn_b = V).  Its one-sided weights
    extrapolate less than the linear state's (4/3, -1/3 against 2, -1 on rows at h and 2h from
    the wall).  The premise needs D rho/Dt ~ 0 at the wall: in an acoustic transient part of a
    linear u_n reads as a penetration.  Wall points whose stencil cannot carry the fit (the pivot
    test of :func:`constrained_fit_degrees`, ``rcond``; none on the shipped layouts, the cavity's
    corners included) keep the linear wall state: ``ok[Nb]`` says which carry it."""
    nb, d = normal.shape
    e = basis.exponents(2, d)
    keep = np.asarray([k for k, row in enumerate(e) if not (row.sum() == 1 and row[0] == 1)])
    e0 = jnp.zeros((d,), normal.dtype).at[0].set(1.0)
    v = e0[None, :] + jnp.where(normal[:, :1] >= 0, 1.0, -1.0) * normal      # |v|^2 = 2 (1 + |n_0|) >= 2
    frame = jnp.eye(d, dtype=normal.dtype) - 2.0 * v[:, :, None] * v[:, None, :] / jnp.sum(v * v, -1)[:, None, None]
    y = jnp.einsum("bcd,bkd->bkc", frame, st.dx / st.h[:, None, None])          # y_0 = -+ n_b . xi
    P = basis.evaluate(y, 2)[..., keep]                                          # [Nb, K, m - 1]
    w = kernel.w_vec(st.dx, st.h[:, None]) * st.mask
    M = jnp.einsum("bk,bkm,bkn->bmn", w, P, P)
    ok = jnp.all(jax.vmap(lambda A: cholesky_pivots(A, rcond)[1])(jax.lax.stop_gradient(M)), axis=-1)
    M = jnp.where(ok[:, None, None], M, jnp.eye(M.shape[-1], dtype=M.dtype))
    a = jnp.linalg.solve(M, jnp.broadcast_to(jnp.eye(M.shape[-1], dtype=M.dtype)[0], M.shape[:2])[..., None])[..., 0]
    return jnp.einsum("bm,bkm,bk->bk", a, P, w), ok


#: Radius, in kernel supports of the wall point, within which particles get the first-moment
#: correction (:meth:`BoundaryIntegralWalls.wall_terms`): a particle's defect comes from its own
#: wall weights and from neighbours whose supports the wall truncates, so two supports and a margin.
NEAR_SUPPORTS = 2.25


def moment_defect(p: Particles, geom, st: WallStencils, weight, normal, rows):
    """``V_i E_i [R, d, d]`` of the particles ``rows[R]`` (padding ``N``): the first-moment defect
    sum_j dx_ij (x) A_ij / 2 + sum_b dGamma_b N_i(x_b) (x_b - x_i) (x) n_b / 2 - V_i I
    (zero to round-off in the interior of a lattice; ``weight[Nb, K]`` = dGamma_b N_j(x_b))."""
    n, d = p.x.shape
    r = jnp.minimum(rows, n - 1)
    pairs = 0.5 * jnp.einsum("nk,nka,nkc->nac", geom.pair_mask[r], geom.dx[r], geom.A[r])
    wall = jnp.einsum("bk,bka,bc->bkac", jnp.where(st.mask, weight, 0.0), -st.dx, normal)
    wall = jnp.zeros((n, d, d), pairs.dtype).at[st.idx.reshape(-1)].add(0.5 * wall.reshape(-1, d, d))
    return pairs + wall[r] - p.vol[r, None, None] * jnp.eye(d, dtype=pairs.dtype)


def fit_gradient(geom, f, degree: int, rows):
    """Gradient ``[R, ..., d]`` at the particles ``rows[R]`` (padding ``N``) of the fields
    ``f[N, ...]`` from each particle's own fixed-centre fit (``geom.coeffs``, degree ``degree``),
    applied to f_j - f_i (exactly zero for a uniform field)."""
    d = geom.dx.shape[-1]
    r = jnp.minimum(rows, f.shape[0] - 1)
    js = geom.jsafe[r]
    df = (f[js] - f[r][:, None]).reshape(js.shape + (-1,))                              # [R, K, c]
    a = jnp.einsum("nmk,nkc->nmc", geom.coeffs[r], jnp.where(geom.mask[r][..., None], df, 0.0))
    dP0 = jnp.asarray(basis.gradient_at_origin(degree, d), geom.h.dtype) / geom.h[r][:, None, None]
    return jnp.einsum("nmd,nmc->ncd", dP0, a).reshape((r.shape[0],) + f.shape[1:] + (d,))


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class BoundaryIntegralWalls:
    """Boundary-integral walls (module docstring): the ``curves`` (static), whether each is a
    no-slip wall, the stencil capacity, the outlines of the set-up geometry used by the in-run
    crossing check (closed outlines ``polys``, segments ``segments[S, 2, 2]``)."""

    polys: tuple
    segments: jax.Array
    curves: tuple = dataclasses.field(metadata=dict(static=True))
    no_slip: tuple = dataclasses.field(metadata=dict(static=True))
    fluid_inside: tuple = dataclasses.field(metadata=dict(static=True))
    capacity: int = dataclasses.field(metadata=dict(static=True))
    beta: float = dataclasses.field(metadata=dict(static=True))
    kernel: str = dataclasses.field(metadata=dict(static=True))
    band: float = dataclasses.field(metadata=dict(static=True))
    box: tuple | None = dataclasses.field(metadata=dict(static=True), default=None)
    n_walls: int = dataclasses.field(metadata=dict(static=True), default=0)
    grid: NeighborSpec | None = dataclasses.field(metadata=dict(static=True), default=None)
    near_grid: NeighborSpec | None = dataclasses.field(metadata=dict(static=True), default=None)
    near_capacity: int = dataclasses.field(metadata=dict(static=True), default=0)
    n_rows: int = dataclasses.field(metadata=dict(static=True), default=0)
    #: ``(stencils, rows, rows_overflow)`` of particles that do not move (:meth:`fix`), or None
    fixed: tuple | None = None
    #: isothermal curves: ``((name, e_w), ...)`` at construction (the values are the defaults of the
    #: Params keys ``geometry.<name>.wall_e``); the other curves are adiabatic
    wall_energy: tuple = dataclasses.field(metadata=dict(static=True), default=())

    # -- the geometry ------------------------------------------------------------------------
    def default_params(self) -> dict:
        """``geometry.*`` parameters of the curves at their construction values (with the wall
        energies ``geometry.<name>.wall_e`` of isothermal curves)."""
        return {**curve_params(self.curves),
                **{f"geometry.{name}.wall_e": jnp.asarray(e, jnp.float64) for name, e in self.wall_energy}}

    def heat_flux(self, p: Particles, params, scheme, st, prim, bp):
        """``kappa grad(e)_b . n_b [Nb]`` at the isothermal wall points (0 at adiabatic ones):
        grad(e)_b of the fit at x_b constrained to the wall energy (module docstring)."""
        if not self.wall_energy:
            return jnp.zeros(bp.x.shape[0], bp.x.dtype)
        full = {**self.default_params(), **dict(params)}
        names = dict(self.wall_energy)
        e_c = jnp.stack([jnp.asarray(full[f"geometry.{c.name}.wall_e"], bp.x.dtype) if c.name in names
                         else jnp.zeros((), bp.x.dtype) for c in self.curves])
        iso = jnp.asarray([c.name in names for c in self.curves])[bp.curve]
        ew = e_c[bp.curve]
        G = constrained_gradient(st, prim.e[:, None], ew[:, None], get_kernel(self.kernel), scheme.fit_degree,
                                 scheme.wall_fit_rcond)                                 # [Nb, 1, d]
        return jnp.where(iso, params["physics.kappa"] * jnp.einsum("bd,bd->b", G[:, 0, :], bp.normal), 0.0)

    def points(self, params):
        """The :class:`~mlsph_jax.geometry.BoundaryPoints` for ``params`` (construction values
        for ``geometry.*`` keys the Params do not hold; the first ``n_walls`` curves, made from
        axis-aligned walls, move with ``boundary.wall_velocity[k]`` when the Params hold it, as
        mirror walls do)."""
        full = {**self.default_params(), **dict(params)}
        if self.n_walls and "boundary.wall_velocity" in params:
            for k in range(self.n_walls):
                full[self.curves[k].key("velocity")] = params["boundary.wall_velocity"][k]
        return quadrature(self.curves, Params(full))

    def check_motion(self, params) -> None:
        """Refuse a wall velocity that crosses its wall or is not finite
        (:func:`mlsph_jax.geometry.checks.normal_wall_motion`): the outlines stay where they were
        set up during a run, so such a wall would move through the particles.  Called by
        :func:`mlsph_jax.run.setup_run` with the problem's Params (evaluated in float64, so that a
        float32 run's turning circle is not refused for its round-off)."""
        from .geometry.checks import WALL_MOTION_RTOL, normal_wall_motion, wall_motion_problem

        p64 = Params({k: np.asarray(v, np.float64) if np.issubdtype(np.asarray(v).dtype, np.floating) else v
                      for k, v in dict(params).items()})
        bp = self.points(p64)
        hit = normal_wall_motion(bp.velocity, bp.normal)
        if hit is None:
            return
        b, vn = hit
        k = int(np.asarray(bp.curve)[b])
        c = self.curves[k]
        if k < self.n_walls and "boundary.wall_velocity" in params:
            what = f"boundary.wall_velocity[{k}]={np.asarray(params['boundary.wall_velocity'])[k].tolist()}"
        else:
            full = {**self.default_params(), **dict(params)}
            what = ", ".join(f"{c.key(f)}={np.asarray(full[c.key(f)]).tolist()}" for f in ("velocity", "omega")
                            if c.key(f) in full)
        raise InputError(f"invalid {what}: the wall {c.name!r} {wall_motion_problem(vn)} at "
                         f"x={np.round(np.asarray(bp.x[b]), 6).tolist()}, but walls stay where they were set up, "
                         f"so it would move through the particles; allowed: a finite wall velocity along the wall "
                         f"(|u . n| <= {WALL_MOTION_RTOL:g} of the largest wall speed: a segment sliding along "
                         "itself, a circle turning about its centre)")

    def _box(self):
        return None if self.box is None else (jnp.asarray(self.box[0]), jnp.asarray(self.box[1]))

    def stencils(self, p: Particles, xb):
        kern = get_kernel(self.kernel)
        return wall_stencils(p.x, p.vol, p.kind, xb, beta=self.beta, support=kern.support,
                             capacity=self.capacity, box=self._box(), grid=self.grid)

    def near_rows(self, p: Particles, xb):
        """``(rows[n_rows], overflow)``: the particles within :data:`NEAR_SUPPORTS` supports of a
        wall point, ascending, padded with N (the rows that get the first-moment correction);
        ``overflow`` when a point sees more than ``near_capacity`` of them or they outnumber
        ``n_rows``."""
        kern = get_kernel(self.kernel)
        st = wall_stencils(p.x, p.vol, p.kind, xb, beta=self.beta, support=NEAR_SUPPORTS * kern.support,
                           capacity=self.near_capacity, box=self._box(), grid=self.near_grid)
        n = p.x.shape[0]
        flat = jnp.sort(jnp.where(st.mask, st.idx, n).reshape(-1))
        distinct = jnp.sum((flat < n) & jnp.concatenate([jnp.ones(1, bool), flat[1:] != flat[:-1]]))
        rows = jnp.unique(flat, size=self.n_rows, fill_value=n)
        return rows, (distinct > self.n_rows) | jnp.any(st.count > self.near_capacity)

    def wall_rows(self, p: Particles):
        """``[N]`` bool: the particles with a boundary term, i.e. in the stencil of a wall point
        (N_i(x_b) != 0 for some b) at the curves' construction values (decision 92: their rows'
        consistency identity holds the wall integral, which the area correction's (*) lacks)."""
        st = self.point_stencils(p, self.points({}).x)
        hits = jnp.zeros(p.x.shape[0], jnp.int32).at[st.idx.reshape(-1)].add(st.mask.reshape(-1).astype(jnp.int32))
        return hits > 0

    def apply(self, p: Particles, params) -> Particles:
        """Nothing to regenerate (no ghosts)."""
        return p

    def fix(self, p: Particles, params) -> BoundaryIntegralWalls:
        """These walls with the wall-point stencils and the near-wall rows of ``p`` computed once
        (``fixed``), for particles that do not move (Eulerian frame: positions, volumes and kinds
        constant, so the searches of every stage would return the same stencils; the offsets
        x_j - x_b stay functions of ``p`` and ``params``, so gradients flow as before).  The
        searches are most of the walls' cost (cylinder, 1,920 particles: 15 of 19 ms per stage)."""
        xb = self.points(params).x
        return dataclasses.replace(self, fixed=(self.stencils(p, xb), *self.near_rows(p, xb)))

    def point_stencils(self, p: Particles, xb):
        """The stencils of the wall points ``xb``: the fixed ones if set."""
        return self.fixed[0] if self.fixed is not None else self.stencils(p, xb)

    def _stencils_and_rows(self, p: Particles, xb):
        """``(stencils, rows, rows_overflow)`` at the wall points ``xb``: the fixed ones if set."""
        return self.fixed if self.fixed is not None else (self.stencils(p, xb), *self.near_rows(p, xb))

    # -- the shifting drift at the walls ----------------------------------------------------
    def drift_at_walls(self, p: Particles, params, dw):
        """The shifting drift ``dw`` without its component normal to the walls (decision 78).

        A particle whose support reaches a wall has no neighbours beyond it, so the shifting laws
        (which move particles from where neighbours crowd to where they are missing) drive it
        into the wall; mirror ghosts fill that part of the support, boundary-integral walls do
        not.  Every particle in the stencil of a wall point loses the component of dw_i along the
        wall's mean normal n_i = sum_b dGamma_b W(x_i - x_b, h_b) n_b / |...| (both signs: a
        drift along n_i makes (u - w) . n nonzero in the wall rows, where the self term and the
        first-moment correction of the boundary integral, decision 54, then carry mass through
        the wall); drift along the wall is kept, and every other particle keeps its drift."""
        bp = self.points(params)
        st = self.point_stencils(p, bp.x)
        kern = get_kernel(self.kernel)
        wgt = jnp.where(st.mask, kern.w_vec(st.dx, st.h[:, None]), 0.0) * bp.dgamma[:, None]   # [Nb, K]
        rows = wgt[..., None] * bp.normal[:, None, :]                                          # [Nb, K, d]
        n_i = jnp.zeros_like(dw).at[st.idx.reshape(-1)].add(rows.reshape(-1, dw.shape[1]), mode="drop")
        s2 = jnp.sum(n_i * n_i, axis=-1, keepdims=True)
        unit = n_i / jnp.sqrt(jnp.where(s2 > 0, s2, 1.0))     # 0 beyond the walls' stencils (and
        #                                                       no NaN in its derivative there)
        return dw - jnp.sum(dw * unit, axis=-1, keepdims=True) * unit

    # -- the wall fluxes ---------------------------------------------------------------------
    def wall_state(self, p: Particles, params, scheme, prim):
        """``(points, stencils, N_j(x_b)[Nb, K], p_b[Nb], tau_b n_b [Nb, d], q_b[Nb])`` for a state,
        q_b = kappa grad(e)_b . n_b the conductive flux of isothermal walls (:meth:`heat_flux`)."""
        bp, st, vals = self.state_weights(p, params, scheme)
        kern = get_kernel(self.kernel)
        interp = lambda f: jnp.einsum("bk,bk...->b...", vals, f[st.idx])  # noqa: E731
        rho_b, c_b = interp(prim.rho), interp(prim.c)
        vn = self.normal_velocity(scheme, bp, st, vals, prim.vel)                  # into the wall
        # Rusanov flux between the interpolated state and its mirror image across the wall:
        # no mass, momentum (p + rho vn (vn + |vn| + c)) n  (SPEC §5.8, the Riemann alternative)
        pb = interp(prim.p) + rho_b * vn * (vn + jnp.abs(vn) + c_b)
        tn = jnp.zeros_like(bp.x)
        if scheme.viscous and any(self.no_slip):
            G = constrained_gradient(st, prim.vel, bp.velocity, kern, scheme.fit_degree, scheme.wall_fit_rcond)
            D = wall_flux(G, bp.velocity, params["physics.mu"], scheme)          # [Nb, nv, d]
            noslip = jnp.asarray(self.no_slip)[bp.curve]
            d = bp.x.shape[1]
            tn = jnp.where(noslip[:, None], jnp.einsum("bad,bd->ba", D[:, 1:1 + d, :], bp.normal), 0.0)
        return bp, st, vals, pb, tn, self.heat_flux(p, params, scheme, st, prim, bp)

    def state_weights(self, p: Particles, params, scheme):
        """``(points, stencils, N_j(x_b)[Nb, K])``: the wall points, their stencils and the weights of
        the linear wall state (:data:`WALL_STATE_DEGREE`, fixed-centre MLS at x_b)."""
        bp = self.points(params)
        st = self.point_stencils(p, bp.x)
        vals, _, _, _ = mls.operators_block(st.dx, st.mask, st.h, kernel=get_kernel(self.kernel),
                                            degree=WALL_STATE_DEGREE, rcond=scheme.wall_fit_rcond,
                                            derivative="fixed_centre", with_coeffs=False)
        return bp, st, vals

    def normal_velocity(self, scheme, bp, st: WallStencils, vals, vel):
        """vn_b = (u_b - u_w) . n_b ``[Nb]`` (into the wall) of the mirror Riemann problem: on no-slip
        walls of a viscous scheme from the fit without the linear normal term
        (:func:`no_slip_normal_weights`, decision 108), on the others (free-slip walls, every wall of
        an inviscid scheme) from the quadratic fixed-centre MLS at x_b
        (:data:`FREE_SLIP_NORMAL_DEGREE`, decision 109); the linear wall state ``vals`` where a
        stencil cannot carry either fit."""
        vj = jnp.sum((vel[st.idx] - bp.velocity[:, None, :]) * bp.normal[:, None, :], axis=-1)   # [Nb, K]
        vn = jnp.einsum("bk,bk->b", vals, vj)
        no_slip = jnp.asarray(self.no_slip)[bp.curve] & scheme.viscous
        if not (scheme.viscous and all(self.no_slip)):
            # where the stencil cannot carry the quadratic (its active degree falls below it), the
            # linear wall state's vn_b stays
            Nq, _, _, dq = mls.operators_block(st.dx, st.mask, st.h, kernel=get_kernel(self.kernel),
                                               degree=FREE_SLIP_NORMAL_DEGREE, rcond=FREE_SLIP_NORMAL_RCOND,
                                               derivative="fixed_centre", with_coeffs=False)
            quadratic = ~no_slip & (dq >= FREE_SLIP_NORMAL_DEGREE)
            vn = jnp.where(quadratic, jnp.einsum("bk,bk->b", Nq, vj), vn)
        if scheme.viscous and any(self.no_slip):
            Nn, ok = no_slip_normal_weights(st, bp.normal, get_kernel(self.kernel), scheme.wall_fit_rcond)
            vn = jnp.where(no_slip & ok, jnp.einsum("bk,bk->b", Nn, vj), vn)
        return vn

    def wall_terms(self, p: Particles, params, geom, scheme, U, prim, w, *, with_defect: bool = False):
        """``(B[N, nv], dV[N])``: the boundary term B_i of eq. 4.24 (to subtract from d(VU)/dt)
        and the boundary part of dV_i/dt (module docstring).

        ``with_defect``: also ``(D[N, nv], D_V[N])``, the parts of -B_i and of dV_i/dt that are
        not wall fluxes, s F_i . beta_i and -s w_i . beta_i plus decision 60's first-moment
        corrections, so that sum_i (B_i + D_i) = sum_b dGamma_b F_b . n_b and
        sum_i (dV_i - D_V,i) = sum_b dGamma_b u_w . n_b exactly (the wall fluxes: no mass through a
        wall, a closed wall's area kept); ``scheme.conservation_projection`` sums them (decision 112)."""
        eos = get_eos(scheme.eos)
        n, d = p.x.shape
        bp, st, vals, pb, tn, qb = self.wall_state(p, params, scheme, prim)
        weight = bp.dgamma[:, None] * vals                                        # dGamma_b N_j(x_b)
        un = jnp.sum(bp.velocity * bp.normal, axis=-1)
        Fb = [jnp.zeros_like(pb)[:, None], pb[:, None] * bp.normal - tn]
        if eos.has_energy:
            Fb.append((pb * un - jnp.sum(tn * bp.velocity, axis=-1) - qb)[:, None])
        Fb = jnp.concatenate(Fb, axis=-1)                                          # F_b . n_b [Nb, nv]
        flat = st.idx.reshape(-1)
        wflat = jnp.where(st.mask, weight, 0.0).reshape(-1)

        def scatter(v):   # sum_b dGamma_b N_i(x_b) v_b  -> [N, ...]
            rows = (wflat.reshape(wflat.shape + (1,) * (v.ndim - 1)) * jnp.repeat(v, st.idx.shape[1], axis=0))
            return jnp.zeros((n,) + v.shape[1:], v.dtype).at[flat].add(rows)

        # F_h(x_b) . n_b = sum_j N_j(x_b) F_j . n_b: the particles' own total flux interpolated to
        # the wall point (the flux that the symmetric pair sum of eq. 4.22 already carries to the
        # wall; decision 54): B_i = sum_b dGamma_b N_i(x_b) [F_b - F_h/2 - (s - 1/2) F_i] . n_b
        pick = lambda a: a[st.idx]  # noqa: E731
        prim_j = Primitive(*(pick(getattr(prim, f.name)) for f in dataclasses.fields(Primitive)))
        nb = jnp.broadcast_to(bp.normal[:, None, :], st.dx.shape)
        Fj = ale_flux_dot(pick(U), prim_j, pick(w), nb, eos)                      # [Nb, K, nv]
        if scheme.diffusive:
            Dp = particle_flux(prim, geom, scheme, params)                        # [N, nv, d]
            Fj = Fj - jnp.einsum("bkvd,bkd->bkv", pick(Dp), nb)
        Fh = jnp.einsum("bk,bkv->bv", jnp.where(st.mask, vals, 0.0), Fj)
        wh = jnp.einsum("bk,bkd,bd->b", jnp.where(st.mask, vals, 0.0), pick(w), bp.normal)
        B = scatter(Fb - 0.5 * Fh)
        dvol = scatter(un - 0.5 * wh)
        beta_n = scatter(bp.normal)                                                # sum_b dGamma N_i(x_b) n_b
        s = 1.0 if scheme.self_flux else 0.0
        c = 0.5 - s                                                                # 1/2 - s
        Fi = ale_flux_dot(U, prim, w, beta_n, eos)
        if scheme.diffusive:
            Dn = jnp.einsum("nvd,nd->nv", Dp, beta_n)
            Fi = Fi - Dn
        B = B + c * Fi
        dvol = dvol + c * jnp.sum(w * beta_n, axis=-1)
        defect, defect_v = s * Fi, -s * jnp.sum(w * beta_n, axis=-1)     # s F_i . beta_i, -s w_i . beta_i
        # first-moment correction of the rows near a wall (decision 54): the one-point pair areas
        # of rows whose neighbours have truncated supports and the wall quadrature leave
        # V_i E_i = sum_j dx_ij (x) A_ij / 2 + sum_b dGamma_b N_i(x_b) (x_b - x_i) (x) n_b / 2 - V_i I
        # != 0, so a linear flux F gets the rate V_i (I + E_i) : grad F; subtracting
        # V_i E_i : grad F_i (grad F_i from the particle's own fit, exact for linear F) makes the
        # wall rows linearly consistent; it vanishes for a uniform state and in the interior.  Only
        # with the self term: it is not a pair difference, and s = 0 is the conservative form; and
        # only with a fit (first-order schemes without one are not linearly consistent anyway)
        if not scheme.self_flux or geom.coeffs is None:
            return (B, dvol, defect, defect_v) if with_defect else (B, dvol)
        rows = self.fixed[1] if self.fixed is not None else self.near_rows(p, bp.x)[0]
        VE = moment_defect(p, geom, st, weight, bp.normal, rows)                  # [R, d, d]
        Ft = jnp.stack([ale_flux_dot(U, prim, w, jnp.broadcast_to(e, w.shape), eos)
                        for e in jnp.eye(d, dtype=w.dtype)], axis=-1)             # [N, nv, d]
        if scheme.diffusive:
            Ft = Ft - Dp
        corr = jnp.einsum("nac,nvca->nv", VE, fit_gradient(geom, Ft, scheme.fit_degree, rows))
        B = B.at[rows].add(-corr, mode="drop")
        defect = defect.at[rows].add(corr, mode="drop")
        if not scheme.frame == "eulerian":
            cv = jnp.einsum("nac,nca->n", VE, fit_gradient(geom, w, scheme.fit_degree, rows))
            dvol = dvol.at[rows].add(-cv, mode="drop")
            defect_v = defect_v.at[rows].add(-cv, mode="drop")
        return (B, dvol, defect, defect_v) if with_defect else (B, dvol)

    def forces(self, p: Particles, params, scheme):
        """Force of the fluid on each curve ``[n_curves, d]``: sum_b (p_b n_b - tau_b n_b) dGamma_b
        (n_b points into the body; SPEC §5.8), pressure and viscous parts ``(total, pressure)``."""
        from .eos import to_primitive

        prim = to_primitive(p.q / p.vol[:, None], get_eos(scheme.eos), params)
        bp, _, _, pb, tn, _ = self.wall_state(p, params, scheme, prim)
        nc = len(self.curves)
        fp = jax.ops.segment_sum(pb[:, None] * bp.normal * bp.dgamma[:, None], bp.curve, nc)
        fv = jax.ops.segment_sum(-tn * bp.dgamma[:, None], bp.curve, nc)
        return fp + fv, fp

    def heat_rates(self, p: Particles, params, scheme):
        """Heat passed from each curve into the fluid per unit span ``[n_curves]`` (jnp,
        differentiable): sum_b dGamma_b kappa grad(e)_b . n_b of the isothermal walls (0 for the
        adiabatic ones; :meth:`heat_flux`), and each curve's length ``[n_curves]``."""
        from .eos import to_primitive

        prim = to_primitive(p.q / p.vol[:, None], get_eos(scheme.eos), params)
        bp, _, _, _, _, qb = self.wall_state(p, params, scheme, prim)
        nc = len(self.curves)
        return jax.ops.segment_sum(qb * bp.dgamma, bp.curve, nc), jax.ops.segment_sum(bp.dgamma, bp.curve, nc)

    def coefficients(self, p: Particles, params, scheme, *, rho_inf, u_inf, length, curve: str):
        """Force coefficients of ``curve`` (jnp, differentiable; SPEC §5.8): ``cd``, ``cl`` (the
        force along and across the free stream ``u_inf[d]``, over 1/2 rho_inf |u_inf|^2
        ``length``) and their pressure parts ``cd_pressure``, ``cl_pressure``."""
        names = [c.name for c in self.curves]
        if curve not in names:
            raise InputError(f"unknown curve={curve!r}; allowed: {', '.join(names)}")
        k = names.index(curve)
        total, pressure = self.forces(p, params, scheme)
        u = jnp.asarray(u_inf, total.dtype)
        speed = jnp.linalg.norm(u)
        e_d = u / speed
        e_l = jnp.stack([-e_d[1], e_d[0]])
        q = 0.5 * rho_inf * speed ** 2 * length
        return {"cd": total[k] @ e_d / q, "cl": total[k] @ e_l / q,
                "cd_pressure": pressure[k] @ e_d / q, "cl_pressure": pressure[k] @ e_l / q}

    # -- the in-run checks -------------------------------------------------------------------
    def band_status(self, p: Particles, params=None):
        """``(bits, particle)``: WALL_CROSSED for a fluid particle beyond a wall of the set-up
        geometry, BOUNDARY_OVERFLOW for a wall stencil with more than ``capacity`` particles, a
        wall point's support beyond the search cells (or no particle within a cell of it), or more
        particles near the walls than the correction rows hold.  The stencils are those of the
        wall points at ``params`` (the walls' own values if None), as in the wall terms."""
        from .status import Status

        p = jax.lax.stop_gradient(p)
        fluid = p.kind == Kind.FLUID
        crossed = jnp.zeros_like(fluid)
        for poly, inside in zip(self.polys, self.fluid_inside, strict=True):
            inn = inside_polygon(p.x, poly, jnp)
            crossed = crossed | (~inn if inside else inn)
        for s in range(self.segments.shape[0]):
            crossed = crossed | beyond_segment(p.x, self.segments[s, 0], self.segments[s, 1], self.band, jnp)
        crossed = crossed & fluid
        st, _, rows_over = self._stencils_and_rows(p, self.points({} if params is None else params).x)
        over = jnp.any(st.count > self.capacity) | rows_over
        hit = jnp.any(crossed)
        bits = (jnp.where(hit, jnp.int32(Status.WALL_CROSSED), 0)
                | jnp.where(over, jnp.int32(Status.BOUNDARY_OVERFLOW), 0)).astype(jnp.int32)
        nearest = jnp.argmax(st.count > self.capacity)
        bad = jnp.where(hit, jnp.argmax(crossed), jnp.where(over, st.idx[nearest, 0], -1))
        return bits, bad.astype(jnp.int32)


def walls_to_segments(walls, domain, spacing: float, velocities=None):
    """Axis-aligned :class:`~mlsph_jax.boundaries.Wall` planes (2D) as :class:`Segment` curves
    ``wall<k>`` spanning the domain box, one quadrature point per ``spacing``; ``velocities[k]``:
    wall k's velocity.  Returns ``[(segment, no_slip)]``."""
    out = []
    lo, hi = domain.lower, domain.upper
    for k, w in enumerate(walls):
        if domain.dim != 2:
            raise InputError(f"invalid domain of dimension {domain.dim} for boundary-integral walls; allowed: 2D")
        t = 1 - w.axis                                       # the axis along the wall
        a = [0.0, 0.0]
        b = [0.0, 0.0]
        a[w.axis] = b[w.axis] = w.position
        # fluid on the left of a -> b
        forward = (w.side > 0) == (w.axis == 1)
        a[t], b[t] = (lo[t], hi[t]) if forward else (hi[t], lo[t])
        n = max(1, int(math.ceil((hi[t] - lo[t]) / spacing - 1e-9)))
        vel = (0.0, 0.0) if velocities is None else tuple(float(v) for v in np.asarray(velocities[k]))
        out.append((Segment(f"wall{k}", start=tuple(a), end=tuple(b), n_points=n, velocity=vel), not w.slip))
    return out


class BoundaryIntegral:
    """Walls by the boundary integral of thesis eq. 4.24 (:mod:`mlsph_jax.wall_integral`)."""

    @staticmethod
    def setup(p_fluid: Particles, walls, band, params, eos, *, scheme, domain, curves=(), no_slip=None,
              headroom: float = 1.5, max_spacing_ratio: float = 1.0, wall_energy=None):
        """``(particles, BoundaryIntegralWalls)``: no particle is added.  ``walls``: axis-aligned
        :class:`~mlsph_jax.boundaries.Wall` planes (segments ``wall<k>`` spanning the domain, one
        point per particle spacing, velocity ``boundary.wall_velocity[k]`` of the Params if present,
        no-slip unless ``Wall.slip``); ``curves``: further curves, no-slip where ``no_slip[k]``
        (default: all); ``band``: depth beyond a wall segment within which a particle counts as
        having crossed it; ``headroom``: stencil capacity over the largest set-up count;
        ``wall_energy``: ``{curve name: e_w}`` of isothermal walls (the axis-aligned walls are
        ``wall<k>``; module docstring), the others adiabatic."""
        if scheme.method != "mlsph_ale":
            raise InputError(f"invalid scheme.method={scheme.method!r} with boundary-integral walls; allowed: "
                             "\"mlsph_ale\" (the boundary term of thesis eq. 4.24 is derived for MLS shape functions)")
        spacing = float(jnp.min(p_fluid.vol)) ** (1.0 / p_fluid.dim)
        wv = params["boundary.wall_velocity"] if walls and "boundary.wall_velocity" in params else None
        pairs = walls_to_segments(list(walls or []), domain, spacing, wv)
        curves = tuple(c for c, _ in pairs) + tuple(curves)
        ns_flags = [ns for _, ns in pairs] + list([True] * (len(curves) - len(pairs)) if no_slip is None
                                                     else no_slip)
        if len(ns_flags) != len(curves):
            raise InputError(f"invalid no_slip={no_slip!r}; allowed: one flag per curve ({len(curves) - len(pairs)})")
        wall_energy = _check_wall_energy(wall_energy, curves, scheme)
        full = Params({**curve_params(curves), **dict(params)})
        check_geometry(curves, full, p_fluid.x, p_fluid.vol, p_fluid.kind, domain=domain,
                       max_spacing_ratio=max_spacing_ratio)
        kern = get_kernel(scheme.kernel)
        L = np.asarray(domain.length)
        box = (tuple(L.tolist()), tuple(domain.periodic)) if domain.any_periodic else None
        xb = quadrature(curves, full).x
        big = wall_stencils(p_fluid.x, p_fluid.vol, p_fluid.kind, xb, beta=scheme.beta, support=kern.support,
                            capacity=min(p_fluid.n, 512), box=None if box is None else tuple(map(jnp.asarray, box)))
        count = np.asarray(big.count)
        # the wall state is a linear MLS and the constrained wall fit falls back to linear where its
        # stencil cannot carry fit_degree (a corner, decision 61): both need more than the linear basis
        m = basis.basis_size(WALL_STATE_DEGREE, p_fluid.dim)
        if count.min() < m + 1:
            b = int(np.argmin(count))
            raise InputError(f"invalid layout near the wall point x={np.round(np.asarray(xb[b]), 6).tolist()}: "
                             f"{int(count[b])} particles within its support, the linear MLS fits at a wall "
                             f"point need more than {m}; allowed: a larger scheme.beta or more particles near "
                             "the walls")
        # the cell grid of the stencil search: cells of the largest wall-point support radius
        # (support * h_b, h_b of the particle nearest to the point) with headroom (volumes of
        # moving particles grow; a support beyond the cells stops the run loudly).  Not the
        # largest support of all particles: on the cylinder's graded rings (h growing 100-fold)
        # cells of that size hold nearly every particle near the body
        h_set = scheme.beta * np.asarray(p_fluid.vol) ** (1.0 / p_fluid.dim)
        h_wall = float(np.max(np.asarray(big.h)))
        grid = search_grid(p_fluid.x, h_set, domain, kern.support, headroom, reach_h=h_wall)
        near_grid = search_grid(p_fluid.x, h_set, domain, NEAR_SUPPORTS * kern.support, headroom, reach_h=h_wall)
        # a grid pays only when the cells around a wall point hold fewer candidates than the whole
        # fluid (small layouts keep the distance pass); both give the same stencils
        grid, near_grid = (g if 2 * 3 ** p_fluid.dim * g.cell_capacity < p_fluid.n else None
                           for g in (grid, near_grid))
        near = wall_stencils(p_fluid.x, p_fluid.vol, p_fluid.kind, xb, beta=scheme.beta,
                             support=NEAR_SUPPORTS * kern.support,
                             capacity=(p_fluid.n if near_grid is None
                                       else min(p_fluid.n, 3 ** p_fluid.dim * near_grid.cell_capacity)),
                             box=None if box is None else tuple(map(jnp.asarray, box)), grid=near_grid)
        near_capacity = min(p_fluid.n, int(math.ceil(int(jnp.max(near.count)) * headroom)))
        n_near = np.unique(np.asarray(near.idx)[np.asarray(near.mask)]).size
        n_rows = min(p_fluid.n, int(math.ceil(n_near * headroom)))
        closed = [(np.asarray(outline(c, full)), c.fluid == "inside") for c in curves if c.closed]
        segs = [outline(c, full) for c in curves if not c.closed]
        obj = BoundaryIntegralWalls(
            polys=tuple(jnp.asarray(pl) for pl, _ in closed),
            segments=jnp.asarray(np.asarray(segs, float).reshape(-1, 2, 2)),
            curves=curves, no_slip=tuple(bool(s) for s in ns_flags),
            fluid_inside=tuple(ins for _, ins in closed), capacity=int(math.ceil(count.max() * headroom)),
            beta=float(scheme.beta), kernel=scheme.kernel, band=float(band), box=box, n_walls=len(pairs),
            grid=grid, near_grid=near_grid, near_capacity=near_capacity, n_rows=n_rows, wall_energy=wall_energy)
        return p_fluid, obj


def _check_wall_energy(wall_energy, curves, scheme) -> tuple:
    """``((name, e_w), ...)`` of the isothermal walls, checked: known curve names, finite e_w > 0,
    and a scheme that conducts heat in an EOS with an energy equation."""
    if not wall_energy:
        return ()
    if not isinstance(wall_energy, Mapping):
        raise InputError(f"invalid wall_energy={wall_energy!r}; allowed: a mapping {{curve name: e_w}}")
    names = [c.name for c in curves]
    out = []
    for name, e in wall_energy.items():
        if name not in names:
            raise InputError(f"invalid wall_energy curve {name!r} (= {e!r}); allowed: one of "
                             f"{', '.join(map(repr, names))}")
        try:
            ok = not isinstance(e, bool) and math.isfinite(float(e)) and float(e) > 0.0
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise InputError(f"invalid wall_energy[{name!r}]={e!r}; allowed: a finite specific internal energy > 0")
        out.append((name, float(e)))
    if not (scheme.heat_conduction and get_eos(scheme.eos).has_energy):
        raise InputError(f"invalid wall_energy={dict(wall_energy)!r} with scheme.heat_conduction="
                         f"{scheme.heat_conduction} and eos {scheme.eos!r}: an isothermal wall conducts heat; "
                         "allowed: scheme.heat_conduction = true and an EOS with an energy equation (ideal_gas, "
                         "stiffened_gas)")
    return tuple(out)


BOUNDARIES.register("boundary_integral", BoundaryIntegral())
