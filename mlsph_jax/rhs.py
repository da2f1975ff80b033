"""Semi-discrete right-hand sides of MLSPH-ALE and SPH-ALE for y = (x, V, V U).

MLSPH-ALE (thesis eq. 4.36, 4.32, 4.28; SPEC §5.3):

    d(V_i U_i)/dt = - sum_j [G_ij - s (F_w)_i] . A_ij + V_i S_i,   A_ij = V_i grad N_ji - V_j grad N_ij
    dV_i/dt       =   sum_j (w_ij - w_i) . A_ij
    dx_i/dt       =   w_i = sum_j N_j(x_i) u_j (+ shifting drift)    (MLS interpolant, eq. 4.28)

with one particle velocity w_i in all three (docs/moving_particles.md; ``scheme.position_update``
"w_i" moves each particle with its own frame velocity instead).

SPH-ALE (thesis eq. 3.5-3.7, 4.27): the same with A_ij = 2 V_i V_j grad_i W(x_i - x_j, h_ij),
h_ij = (h_i + h_j)/2, and particles moved by the Shepard average of w (eq. 3.7).

G_ij is the numerical flux ``scheme.flux`` (:mod:`mlsph_jax.flux`: Rusanov, HLLC and its low-Mach
variants) between the Riemann states reconstructed at the pair midpoint x_ij from each side, after
the optional low-Mach correction ``scheme.low_mach_reconstruction``; pairs that MOOD demoted to
first order use ``scheme.parachute_flux`` (default: the same flux, evaluated once):

* ``mlsph_ale``: direct MLS reconstruction, U^-_ij = p((x_ij - x_i)/h_i)^T C_i U_{S_i} (eq. 4.39 as
  read in SPEC §13.1 item 6), and symmetrically from j;
* ``sph_ale``: Taylor reconstruction with MLS derivatives, U^-_ij = U_i + grad U_i . d + 1/2 d^T H_i d
  (eq. 3.11), which is U_i + [P_i(xi) - P_i(0)] for the fitted polynomial P_i;
* degree 0 (or a pair whose MOOD degree min(ppd_i, ppd_j) is 0): first order, U_i and U_j.

The j-side state is never recomputed: it is the i-side state of the reverse pair, gathered with
the neighbour list's reverse-slot map.  The self term s (F_w)_i (``scheme.self_flux``) keeps
uniform states exact on any layout; without it, the pair terms are antisymmetric and the totals
of V U are conserved to round-off (SPEC §5.5).

Implementation (performance on CPU).  Everything per pair is written on [rows, K] "planes"
(structure of arrays, one array per component) and evaluated in blocks of rows
(:func:`mlsph_jax.approximation.row_blocks`) so that the temporaries stay in cache:

1. per block, the fit a_i = C_i F_S (all m x nv sums in one variadic reduction) and the i-side
   midpoint states, stored as ``own[N, K, nv]``;
2. per block, the j-side states by a flat gather ``own.reshape(N K, nv)[j K + rev]``, the
   numerical flux, and all sums over the stencil (sum_j G.A, sum_j A, dV, dx) as one variadic
   reduction, which XLA:CPU fuses into a single loop.  Two versions of this sweep sit behind a
   ``lax.cond``: the general one, with the MOOD fallback to the first-order states U_i, U_j of
   pairs with min(ppd_i, ppd_j) = 0, and, when no particle is demoted, one without those states
   (no gathers of U_j and ppd_j, no selects): the same values up to XLA's fused multiply-add contraction (decision 89).

The results equal the straightforward array formulation to round-off
(tests/test_rhs_equivalence_perf.py); experiments/bench_rhs.py measures the throughput.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp

from . import approximation as apx
from . import fallback
from .approximation import mls
from .eos import get_eos, to_primitive
from .errors import InputError
from .flux import ale_flux_dot
from .frames import frame_velocity, shifting_velocity
from .kernels import get_kernel
from .reconstruction import reconstruct, without_wall_shear_jump
from .scheme import Scheme
from .state import Domain, Kind, Params, Particles
from .status import Status
from .stencil import columns as _cols
from .stencil import flat_reverse_index
from .viscous import diffusive_fields, pair_diffusive_flux, particle_flux, self_diffusive_flux, viscous_terms

__all__ = ["Geometry", "check_conservation_projection", "conservation_projection", "evaluate", "frame_velocity",
           "geometry", "reconstruct", "rhs", "shifting_velocity", "source"]


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Geometry:
    """Everything the fluxes need that depends only on positions and volumes.

    For Eulerian runs it is computed once per run (again only after a neighbour regrowth); for
    moving particles once per stage.
    idx/mask/rev: neighbour list; pair_mask excludes padding and self; dx[N,K,d] = x_j - x_i;
    A[N,K,d] area vectors; h[N]; coeffs[N,m,K] reconstruction fit (None for first order);
    interp[N,K] weights of the position update; degree[N,2] the active degree of the area shape
    functions and of the fit after fallback (-1: none; :mod:`mlsph_jax.fallback`); overflow the
    int32 :class:`~mlsph_jax.status.Status` bits of the geometry (neighbour overflow, an
    unconverged area correction).
    """

    idx: jax.Array
    mask: jax.Array
    rev: jax.Array
    pair_mask: jax.Array
    dx: jax.Array
    A: jax.Array
    h: jax.Array
    coeffs: jax.Array | None
    interp: jax.Array
    overflow: jax.Array
    degree: jax.Array

    @property
    def jsafe(self):
        n = self.idx.shape[0]
        return jnp.where(self.mask, self.idx, jnp.arange(n, dtype=self.idx.dtype)[:, None])


def _box(domain: Domain):
    if not domain.any_periodic:
        return None, None
    return jnp.asarray(domain.length), jnp.asarray(domain.periodic)


def geometry(x, vol, nl, scheme: Scheme, domain: Domain, complete=None) -> Geometry:
    """Area vectors, offsets, reconstruction coefficients and interpolation weights.

    ``complete``: the rows :func:`mlsph_jax.area_correction.complete_rows` (needed only by the
    area corrections that ask for it, ``linear_complete`` / ``quadratic_complete``)."""
    n, d = x.shape
    L, per = _box(domain)
    h = apx.smoothing_length(vol, scheme.beta, d)
    idx, mask, rev = nl.idx, nl.mask, nl.rev
    dx = apx.pair_offsets(x, idx, mask, L, per)
    self_i = jnp.arange(n, dtype=idx.dtype)[:, None]
    jsafe = jnp.where(mask, idx, self_i)
    pair_mask = mask & (idx != self_i)
    kern = get_kernel(scheme.kernel)
    A, values, coeffs, *area_deg = scheme.component("method").areas(dx, h, vol, idx, mask, jsafe, rev, scheme)
    area_deg = area_deg[0] if area_deg else None
    fit_deg = area_deg if coeffs is not None else None          # coefficients of the area build reused
    interp = scheme.component("position_update").weights(values, dx, h, jsafe, mask, vol, kern)
    if coeffs is None and scheme.needs_fit:
        fit = apx.build_from_offsets(dx, h, vol, idx, mask, scheme.reconstruction_spec(), coeffs_only=True)
        coeffs, fit_deg = fit.coeffs, fit.degree
    A = jnp.where(pair_mask[..., None], A, 0.0)
    A, converged = scheme.component("area_correction").apply(A, dx, h, vol, jsafe, rev, pair_mask,
                                                                   complete=complete)
    # Status bits: the list's overflow (cause unknown here: all three neighbour bits; the drivers
    # replace them by the list's own bits) and an unconverged area correction
    bits = (jnp.where(nl.overflow, jnp.int32(Status.NEIGHBOR_OVERFLOW), 0)
            | jnp.where(converged, 0, jnp.int32(Status.AREA_CORRECTION_UNCONVERGED))).astype(jnp.int32)
    return Geometry(idx, mask, rev, pair_mask, dx, A, h, coeffs, interp, bits,
                    fallback.stack(area_deg, fit_deg, n))


def rhs(particles: Particles, params: Params, geom: Geometry, scheme: Scheme, boundary=None):
    """Time derivatives ``(dx/dt, dV/dt, d(VU)/dt)`` for the given geometry (pure, jit-able).

    ``boundary`` (e.g. :class:`mlsph_jax.boundaries.MirrorWalls`): in moving frames its
    ``ghost_frame_velocity(w)``, if it has one, gives the ghosts the frame velocity they move with."""
    eos = get_eos(scheme.eos)
    x, vol, q, kind = particles.x, particles.vol, particles.q, particles.kind
    n, d = x.shape
    k = geom.idx.shape[1]
    U = q / vol[:, None]
    prim = to_primitive(U, eos, params)
    frame = scheme.component("frame")
    w = frame.velocity(U, kind, eos, params)
    dw = frame.drift(w, geom, kind, scheme, vol)
    at_walls = getattr(boundary, "drift_at_walls", None)
    if dw is not None and at_walls is not None:       # no drift into boundary-integral walls
        dw = at_walls(particles, params, dw)
    jsafe = geom.jsafe
    eulerian = not frame.moving
    ghosts = None if eulerian else getattr(boundary, "ghost_frame_velocity", None)
    if ghosts is not None:                  # mirror ghosts move with their parents (issue 16)
        w = ghosts(w)
    fluid = (kind == Kind.FLUID)[:, None]
    dxdt = None
    if not eulerian and geom.interp is not None:
        if scheme.component("position_update").fluxes_use_motion:
            # The particle velocity dx_i/dt: the interpolant of the frame velocity (eq. 4.28) plus
            # the shifting drift, a particle-scale correction an interpolant would filter out.  The
            # fluxes (eq. 4.36) and the volume rate (eq. 4.32) use this same velocity, so that the
            # volumes follow the particles (geometric conservation; docs/moving_particles.md).
            w = jnp.where(fluid, jnp.einsum("nk,nkd->nd", geom.interp, w[jsafe]), w)
        else:   # mls_literal: particles move with the interpolant of w + dw, fluxes use w_i + dw_i
            wd = w if dw is None else w + dw
            dxdt = jnp.einsum("nk,nkd->nd", geom.interp, wd[jsafe])
    if dw is not None:
        w = w + dw
    if ghosts is not None:                  # ... with their parents' actual velocity
        w = ghosts(w)
    if dxdt is None:
        dxdt = w

    variables = scheme.component("reconstruction_variables")
    flux = scheme.component("flux")
    parachute = scheme.parachute()                  # None: MOOD-demoted pairs use the scheme's flux
    low_mach = scheme.component("low_mach_reconstruction")
    normal = scheme.component("dissipation_normal")
    wall_tangential = getattr(boundary, "wall_tangential", None)
    tang = (None if scheme.ghost_shear_dissipation or wall_tangential is None
            else _cols(wall_tangential(n, d, U.dtype)))       # decision 81
    F = variables.from_conservative(U, eos, params)
    nv = F.shape[1]
    degree = scheme.reconstruction_degree
    Fc, wc, ppd = _cols(F), _cols(w), particles.ppd
    recon = scheme.component("reconstruction") if degree > 0 else None
    # one fit serves the states and the diffusive flux (a reconstruction that does not declare
    # ``fits_extra = True``: the separate pass)
    fused = scheme.diffusive and degree > 0 and getattr(recon, "fits_extra", False)
    if degree > 0:
        if fused:   # i-side states [N, K, nv] + the diffusive fields' midpoint values and gradients
            own, fitc = recon.midpoint_states(F, geom, degree, extra=diffusive_fields(prim, scheme))
            m_fit, nc = fitc.shape[1:]
            fit_flat = fitc.reshape(n, m_fit * nc)
        else:
            own = recon.midpoint_states(F, geom, degree)                            # i-side states, [N, K, nv]
        own_flat = own.reshape(n * k, own.shape[-1])

    def block(b, rows, demoted=True):
        jb = rows(jsafe)
        Fi = [rows(c)[:, None] for c in Fc]
        Fj = [c[jb] for c in Fc]
        high = None
        if degree > 0:
            flat = flat_reverse_index(jb, rows(geom.rev), k)
            ob = _cols(rows(own))
            oj = _cols(own_flat[flat])                                       # own[j, rev]
            if demoted:
                high = jnp.minimum(rows(ppd)[:, None], ppd[jb]) > 0
                Fm = [jnp.where(high, ob[v], Fi[v]) for v in range(nv)]
                Fp = [jnp.where(high, oj[v], Fj[v]) for v in range(nv)]
            else:       # no particle demoted: every pair is high order (the same values, see below)
                Fm, Fp = ob, oj
        else:
            Fm, Fp = [jnp.broadcast_to(f, jb.shape) for f in Fi], Fj
        Fm = variables.to_conservative(Fm, eos, params)
        Fp = variables.to_conservative(Fp, eos, params)
        A = _cols(rows(geom.A))
        if eulerian:
            w_ij = None
        else:
            wi = [rows(c)[:, None] for c in wc]
            wj = [c[jb] for c in wc]
            w_ij = [0.5 * (a + c) for a, c in zip(wi, wj, strict=True)]
        n_pair = None
        if normal.needs_pair_vector:
            dx = _cols(rows(geom.dx))
            r2 = dx[0] * dx[0]
            for c in dx[1:]:
                r2 = r2 + c * c
            pos = r2 > 0
            r = jnp.where(pos, jnp.sqrt(jnp.where(pos, r2, 1.0)), 0.0)
            n_pair = [c / jnp.where(r > 0, r, 1.0) for c in dx]
        if tang is not None:                # no wall-tangential jump across the mirror walls
            Fm, Fp = without_wall_shear_jump(Fm, Fp, [c[jb] for c in tang], eos, params)
        Fm, Fp = low_mach.correct(Fm, Fp, w_ij, eos, params, scheme)
        GA = flux.pair_flux(Fm, Fp, w_ij, A, n_pair, eos, params, scheme)
        if parachute is not None and high is not None:      # (needs MOOD, hence degree > 0)
            G1 = parachute.pair_flux(Fm, Fp, w_ij, A, n_pair, eos, params, scheme)
            GA = [jnp.where(high, g, g1) for g, g1 in zip(GA, G1, strict=True)]
        if fused:                                   # G - D_ij (D never order-reduced by MOOD)
            ai = _cols(rows(fit_flat)[:, None, :])
            ai = [[ai[mm * nc + c] for c in range(nc)] for mm in range(m_fit)]
            aj = _cols(fit_flat[jb])
            aj = [[aj[mm * nc + c] for c in range(nc)] for mm in range(m_fit)]
            DA = pair_diffusive_flux(ai, aj, _cols(rows(geom.dx)), rows(geom.h)[:, None],
                                     geom.h[jb], A, degree, scheme, params)
            GA = [g - dd for g, dd in zip(GA, DA, strict=True)]
        pm = rows(geom.pair_mask)
        terms = [jnp.where(pm, g, 0.0) for g in GA] + A
        if not eulerian:
            dv = (w_ij[0] - wi[0]) * A[0]
            for c in range(1, d):
                dv = dv + (w_ij[c] - wi[c]) * A[c]
            terms.append(dv)
        return (jnp.stack(mls.stencil_sums(terms), axis=-1),)

    n_out = nv + d + (0 if eulerian else 1)
    row_args = (jsafe, geom.A, geom.pair_mask, *Fc) + ((geom.rev, own, ppd) if degree > 0 else ())
    row_args += (() if eulerian else tuple(wc)) + ((geom.dx,) if normal.needs_pair_vector or fused else ())
    row_args += (fit_flat, geom.h) if fused else ()

    def sweep(demoted):
        fn = block if demoted else functools.partial(block, demoted=False)
        return apx.row_blocks(fn, n, apx.block_rows(n, k), [((n, n_out), U.dtype)], row_args)[0]

    if degree > 0:
        # MOOD demotes pairs to first order only where some ppd is 0; when none is (the common
        # case) the sweep that skips the first-order states F_j (nv gathers per pair), the
        # j-side ppd and the state selects runs instead: where(True, a, b) is a, so the values
        # are those of the general sweep up to FMA contraction (docs/performance.md, decision 89).
        sums = jax.lax.cond(jnp.min(ppd) > 0, lambda: sweep(False), lambda: sweep(True))
    else:
        sums = sweep(True)
    dq = -sums[:, :nv]
    a = sums[:, nv:nv + d]                                   # closure sum_j A_ij
    defect = None            # the terms that are not pair or wall fluxes (decision 112), [N, nv]
    if scheme.self_flux:
        defect = ale_flux_dot(U, prim, w, a, eos)
        dq = dq + defect
    if fused and scheme.self_flux:
        sd = self_diffusive_flux(prim, fitc, geom.h, a, scheme, params)
        dq = dq - sd
        defect = defect - sd
    elif scheme.diffusive and not fused:
        dq = dq + viscous_terms(prim, geom, scheme, params, scheme.fit_degree)     # self term inside
        if scheme.conservation_projection:
            defect = defect - jnp.einsum("nvd,nd->nv", particle_flux(prim, geom, scheme, params), a)
    dq = dq + vol[:, None] * source(U, prim, params, eos)
    if eulerian:
        dvol, dxdt = jnp.zeros_like(vol), jnp.zeros_like(x)
        defect_v = None
    else:
        dvol = sums[:, nv + d]
        defect_v = -jnp.sum(w * a, axis=-1)                  # the -w_i . sum_j A_ij of eq. 4.32
    # ---- boundary-integral walls (thesis eq. 4.24, SPEC §5.8; mlsph_jax/wall_integral.py) ----
    if getattr(boundary, "wall_terms", None) is not None:
        if scheme.conservation_projection:
            bq, bvol, wall_defect, wall_defect_v = boundary.wall_terms(particles, params, geom, scheme, U, prim,
                                                                       w, with_defect=True)
            defect = defect + wall_defect
            defect_v = None if eulerian else defect_v + wall_defect_v
        else:
            bq, bvol = boundary.wall_terms(particles, params, geom, scheme, U, prim, w)
        dq = dq - bq
        dvol = dvol if eulerian else dvol + bvol
    # ---- end of the boundary-integral walls ----
    if scheme.conservation_projection:
        dq = dq - conservation_projection(defect, vol, fluid[:, 0])
        if not eulerian:
            dvol = dvol - conservation_projection(defect_v[:, None], vol, fluid[:, 0])[:, 0]
    return (jnp.where(fluid, dxdt, 0.0), jnp.where(fluid[:, 0], dvol, 0.0), jnp.where(fluid, dq, 0.0))


def conservation_projection(defect, vol, fluid):
    """``V_i R / sum_fluid V`` on the fluid rows (0 elsewhere), R = sum_fluid defect_i [nc]: the
    volume-weighted least change of the fluid rows' rates that removes the net rate of their terms
    that are not pair or wall fluxes (decision 112; docs/moving_particles.md §9):

    * d(V U)/dt: the self-flux term s F_i . sum_j A_ij of eq. 4.36, the wall bracket's
      s F_i . beta_i and decision 60's first-moment correction;
    * dV/dt (moving frames): the -w_i . sum_j A_ij of eq. 4.32, the wall's -s w_i . beta_i and the
      correction's -V_i E_i : grad w_i.

    Subtracted, the totals of V U change by the wall fluxes and the sources alone, as in the
    continuum and the s = 0 scheme (SPEC §5.5), and the fluid's total volume by the walls' motion
    alone.  Both projections are uniform relative rates, and for a uniform state U the defect of
    V U is U times the volume's (the pair closures sum to zero over the fluid when every neighbour
    of a fluid particle is one, the condition :func:`check_conservation_projection` enforces), so
    a uniform state stays exact."""
    f = fluid[:, None]
    R = jnp.sum(jnp.where(f, defect, 0.0), axis=0)
    return jnp.where(f, vol[:, None] * (R / jnp.sum(jnp.where(fluid, vol, 0.0))), 0.0)


def check_conservation_projection(scheme: Scheme, kind, boundary=None, params=None) -> None:
    """Refuse (``InputError``) ``scheme.conservation_projection`` where the fluid's closures do not
    cancel, so that the defect R of a uniform state would not be zero and the projection would
    accelerate a fluid at rest: a layout with particles that are not fluid (mirror ghosts, a frozen
    far field, boundary particles: the pairs between fluid and other particles are boundary fluxes)
    or boundary-integral walls that are not closed (sum_b dGamma_b n_b != 0).  ``kind``: the
    set-up particles' kinds (host array); ``params``: for the walls' quadrature."""
    import numpy as np

    if not scheme.conservation_projection:
        return
    other = int(np.sum(np.asarray(kind) != int(Kind.FLUID)))
    if other:
        raise InputError(f"invalid scheme.conservation_projection=true with {other} particles that are not "
                         "fluid (mirror ghosts, a frozen far field or boundary particles): the global balance "
                         "needs every neighbour of a fluid particle to be a fluid particle; allowed: periodic "
                         "domains and closed boundary-integral walls without a far field "
                         "(case.walls=\"boundary_integral\"), or scheme.conservation_projection=false")
    points = getattr(boundary, "points", None)
    if points is not None and getattr(boundary, "wall_terms", None) is not None:
        bp = points({} if params is None else params)
        dg = np.asarray(bp.dgamma)
        gap = float(np.linalg.norm(np.sum(dg[:, None] * np.asarray(bp.normal), axis=0)))
        if gap > 1e-10 * float(np.sum(dg)):
            raise InputError(f"invalid scheme.conservation_projection=true with walls that are not closed: "
                             f"|sum_b dGamma_b n_b| = {gap:.3g} of a total length {float(np.sum(dg)):.3g}, so a "
                             "fluid at rest has a net wall defect; allowed: closed walls (or walls closed by a "
                             "periodic direction), or scheme.conservation_projection=false")


def source(U, prim, params: Params, eos):
    """Source S per unit volume (thesis eq. 2.7): body force rho f and its work rho f.u."""
    if "physics.body_force" not in params:
        return jnp.zeros_like(U)
    f = jnp.broadcast_to(params["physics.body_force"], prim.vel.shape)
    parts = [jnp.zeros_like(prim.rho)[..., None], prim.rho[..., None] * f]
    if eos.has_energy:
        parts.append((prim.rho * jnp.sum(f * prim.vel, axis=-1))[..., None])
    return jnp.concatenate(parts, axis=-1)


@functools.partial(jax.jit, static_argnames=("scheme", "domain"))
def evaluate(particles: Particles, params: Params, nl, scheme: Scheme, domain: Domain):
    """Convenience: geometry + right-hand side in one jitted call (tests, benchmarks)."""
    geom = geometry(particles.x, particles.vol, nl, scheme, domain)
    return rhs(particles, params, geom, scheme)
