"""Riemann states at the pair midpoints (registries ``scheme.reconstruction`` and
``scheme.reconstruction_variables``).

Each pair (i, j) meets at the midpoint x_ij = (x_i + x_j)/2, where the flux needs the state seen
from i (U^-_ij) and from j (U^+_ij).  Both come from the fixed-centre MLS fit of degree
``scheme.reconstruction_degree`` of each particle's stencil (coefficients ``geom.coeffs``,
p((y - x_i)/h_i)^T C_i F_S); the j-side state is never recomputed: it is the i-side state of the
reverse pair, gathered with the neighbour list's reverse-slot map.

A **reconstruction** has ``midpoint_states(F, geom, degree, extra=None) -> own[N, K, nv]`` (the i-side
states; with ``extra`` the fit also serves the diffusive fields, see :func:`fitted_midpoint_states`):

* ``taylor`` (default): F_i + P_i(xi_ij) - P_i(0), i.e. U_i plus the MLS derivatives of U at x_i
  (thesis eq. 3.11); stable on irregular layouts;
* ``mls_direct``: the fit itself, P_i(xi_ij) (thesis eq. 4.39 read literally, SPEC §13.1 item 6);
  unstable on jittered layouts (docs/architecture.md).

**Reconstruction variables** have ``from_conservative(U, eos, params) -> F[N, nv]`` (what is
reconstructed) and ``to_conservative(F_list, eos, params) -> U_list`` (back, on lists of component
arrays): ``conservative`` (identity) or ``primitive`` (rho, u, p).
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp

from . import approximation as apx
from .approximation import mls
from .eos import conservative_components, primitive_vector
from .flux import local_mach, primitive_components
from .registry import Registry
from .stencil import columns as _cols
from .stencil import reverse_gather

RECONSTRUCTIONS: Registry = Registry("scheme.reconstruction", protocol=("midpoint_states",),
                                     doc="Riemann-state reconstruction at the pair midpoints")
RECONSTRUCTION_VARIABLES: Registry = Registry("scheme.reconstruction_variables",
                                              protocol=("from_conservative", "to_conservative"),
                                              doc="variables that are reconstructed")


def fitted_midpoint_states(F, geom, degree: int, relative: bool, extra=None):
    """i-side midpoint states ``own[N, K, nv]``: p(xi_ij)^T C_i F_S (``relative``: F_i + P_i(xi) -
    P_i(0)), with xi_ij = (x_ij - x_i)/h_i; one blocked pass (fit and evaluation).

    ``extra[N, nc]`` (the diffusive fields, :func:`mlsph_jax.viscous.diffusive_fields`): the same
    pass also fits them (same coefficients C_i) and the function returns ``(own, a[N, m, nc])``
    with their fit coefficients a_i = C_i f_S, which the pair sweep evaluates at the midpoints."""
    n, k = geom.idx.shape
    nv = F.shape[1]
    jsafe = geom.jsafe
    C = geom.coeffs
    m = C.shape[1]
    Fc = _cols(F)
    Ec = [] if extra is None else _cols(extra)
    nc = len(Ec)
    nf = nv + nc

    def block(b, rows):
        jb = rows(jsafe)
        Cb = _cols(rows(C), axis=1)
        Fj = [c[jb] for c in Fc + Ec]
        a = mls.stencil_sums([Cb[mm] * Fj[v] for mm in range(m) for v in range(nf)])
        ext = [a[mm * nf + v] for mm in range(m) for v in range(nv, nf)]
        a = [t[:, None] for t in a]                            # a_i = C_i F_S, [b, 1] each
        dx = rows(geom.dx)
        hb = rows(geom.h)[:, None]
        P = mls.monomial_planes([(0.5 * c) / hb for c in _cols(dx)], degree)
        own = []
        for v in range(nv):
            o = a[v]
            for mm in range(1, m):
                o = o + P[mm] * a[mm * nf + v]
            if relative:
                o = rows(Fc[v])[:, None] + o - a[v]       # F_i + P_i(xi) - P_i(0)
            own.append(jnp.broadcast_to(o, jb.shape))
        if not nc:
            return (jnp.stack(own, axis=-1),)
        return jnp.stack(own, axis=-1), jnp.stack(ext, axis=-1).reshape(b, m, nc)

    outs = [((n, k, nv), F.dtype)] + ([((n, m, nc), F.dtype)] if nc else [])
    res = apx.row_blocks(block, n, apx.block_rows(n, k), outs,
                         (jsafe, C, geom.dx, geom.h) + (tuple(Fc) if relative else ()))
    return res if nc else res[0]


@dataclasses.dataclass(frozen=True)
class TaylorReconstruction:
    """U^-_ij = U_i + grad U_i . d + 1/2 d^T H_i d + ... with MLS derivatives (thesis eq. 3.11)."""

    #: ``midpoint_states`` accepts ``extra`` (fits the diffusive fields in the same pass).
    fits_extra = True

    def midpoint_states(self, F, geom, degree: int, extra=None):
        return fitted_midpoint_states(F, geom, degree, relative=True, extra=extra)


@dataclasses.dataclass(frozen=True)
class DirectMLSReconstruction:
    """U^-_ij = p((x_ij - x_i)/h_i)^T C_i U_S, the MLS fit at the midpoint (thesis eq. 4.39)."""

    #: ``midpoint_states`` accepts ``extra`` (fits the diffusive fields in the same pass).
    fits_extra = True

    def midpoint_states(self, F, geom, degree: int, extra=None):
        return fitted_midpoint_states(F, geom, degree, relative=False, extra=extra)


RECONSTRUCTIONS.register("taylor", TaylorReconstruction())
RECONSTRUCTIONS.register("mls_direct", DirectMLSReconstruction())


@dataclasses.dataclass(frozen=True)
class ConservativeVariables:
    """Reconstruct U = (rho, rho u, rho E) itself."""

    def from_conservative(self, U, eos, params):
        return U

    def to_conservative(self, F, eos, params):
        return F


@dataclasses.dataclass(frozen=True)
class PrimitiveVariables:
    """Reconstruct (rho, u, p) (Tait: (rho, u)) and convert the midpoint states back."""

    def from_conservative(self, U, eos, params):
        return primitive_vector(U, eos, params)

    def to_conservative(self, F, eos, params):
        return conservative_components(F, eos, params)


RECONSTRUCTION_VARIABLES.register("conservative", ConservativeVariables())
RECONSTRUCTION_VARIABLES.register("primitive", PrimitiveVariables())


def reconstruct(F, geom, degree: int, taylor: bool, ppd):
    """Riemann states of the field ``F[N, nv]`` at the pair midpoints: (i side, j side) ``[N,K,nv]``.

    ``degree`` 0 is first order.  Pairs with min(ppd_i, ppd_j) == 0 fall back to first order
    (the MOOD parachute).  (:func:`mlsph_jax.rhs.rhs` evaluates the same states block by block.)
    """
    jsafe = geom.jsafe
    Fm0 = jnp.broadcast_to(F[:, None, :], geom.dx.shape[:2] + F.shape[1:])
    Fp0 = F[jsafe]
    if degree == 0:
        return Fm0, Fp0
    own = fitted_midpoint_states(F, geom, degree, taylor)
    other = reverse_gather(own, jsafe, geom.rev)             # j-side state = i-side of (j, i)
    high = (jnp.minimum(ppd[:, None], ppd[jsafe]) > 0)[..., None]
    return jnp.where(high, own, Fm0), jnp.where(high, other, Fp0)


# ---------------------------------------------------------------------------------------------
# low-Mach corrections of the reconstructed states (scheme.low_mach_reconstruction)
# ---------------------------------------------------------------------------------------------

LOW_MACH_RECONSTRUCTIONS: Registry = Registry(
    "scheme.low_mach_reconstruction", protocol=("correct",),
    doc="low-Mach correction of the reconstructed Riemann states (applied before any flux)")


@dataclasses.dataclass(frozen=True)
class NoLowMachCorrection:
    """No correction: the flux sees the reconstructed states as they are (default)."""

    uses_reference_mach = False

    def correct(self, Um, Up, w, eos, params, scheme):
        return Um, Up


@dataclasses.dataclass(frozen=True)
class ThornberCorrection:
    """Thornber, Mosedale, Drikakis, Youngs & Williams (2008, JCP 227, "An improved reconstruction
    method for compressible flows with low Mach number features"): the velocity
    jump between the two states is scaled by z = min(1, M_loc),

        u_L' = (u_L + u_R)/2 + z (u_L - u_R)/2,   u_R' = (u_L + u_R)/2 + z (u_R - u_L)/2,

    with M_loc = max(|u_L - w|/c_L, |u_R - w|/c_R) (:func:`mlsph_jax.flux.local_mach`, the Mach
    number relative to the interface frame), at constant density and pressure (momentum
    rho u', energy rho E + rho (|u'|^2 - |u|^2)/2: the internal energy is unchanged, so p is for
    any EOS).  The velocity dissipation of any flux then scales with |u| instead of c at low
    Mach; z = 1 (no change, bitwise) for M_loc >= 1.  Applied to every pair, before the flux
    (also to the pairs that MOOD demoted to first order).
    """

    uses_reference_mach = False

    def correct(self, Um, Up, w, eos, params, scheme):
        d = len(Um) - (2 if eos.has_energy else 1)
        velm, _, cm = primitive_components(Um, eos, params)
        velp, _, cp = primitive_components(Up, eos, params)
        relm = velm if w is None else [velm[k] - w[k] for k in range(d)]
        relp = velp if w is None else [velp[k] - w[k] for k in range(d)]
        half = 0.5 * (1.0 - jnp.minimum(1.0, local_mach(relm, relp, cm, cp)))
        dm = [-half * (velm[k] - velp[k]) for k in range(d)]      # u_L' - u_L
        dp = [-dm[k] for k in range(d)]                            # u_R' - u_R
        return shift_velocity(Um, velm, dm, eos), shift_velocity(Up, velp, dp, eos)


def shift_velocity(U, vel, du, eos):
    """The state ``U`` (list of components) with its velocity ``vel`` changed by ``du`` at constant
    density and internal energy: momentum rho (u + du), energy rho E + rho (|u + du|^2 - |u|^2)/2
    (so the pressure is unchanged for any EOS)."""
    d = len(du)
    out = [U[0]] + [U[1 + k] + U[0] * du[k] for k in range(d)]
    if eos.has_energy:
        ke = du[0] * (2.0 * vel[0] + du[0])
        for k in range(1, d):
            ke = ke + du[k] * (2.0 * vel[k] + du[k])
        out.append(U[-1] + 0.5 * U[0] * ke)
    return out


def without_wall_shear_jump(Um, Up, tangential, eos, params):
    """Fluid-ghost pairs without the jump of the wall-tangential velocity (``scheme.ghost_shear_dissipation
    = false``; docs/architecture.md decision 81): both states get the mean of the two tangential
    velocities, at constant density and internal energy.

    ``tangential``: list of d arrays, 1 where component k of the j-side particle is tangential to
    the wall it is a mirror ghost of (0 for fluid particles and corner ghosts).  The exact Riemann
    problem between a fluid state and its mirror image has zero normal velocity in the star region,
    so an inviscid wall transmits no tangential momentum; the Rusanov flux' dissipation
    -1/2 S (U^+ - U^-) instead pulls the fluid's reconstructed tangential velocity towards the
    ghost's, a numerical wall friction proportional to the wave speed S and to the jump of the two
    reconstructions at the wall (which the odd ghost extension u_G = 2 u_W - u_F makes O(h^2 u'')
    where the wall velocity profile is curved).  Without it the wall's tangential force is the
    viscous stress alone (thesis eq. 3.14 on the ghost fit)."""
    d = len(tangential)
    velm, _, _ = primitive_components(Um, eos, params)
    velp, _, _ = primitive_components(Up, eos, params)
    dm = [0.5 * tangential[k] * (velp[k] - velm[k]) for k in range(d)]
    dp = [-dm[k] for k in range(d)]
    return shift_velocity(Um, velm, dm, eos), shift_velocity(Up, velp, dp, eos)


LOW_MACH_RECONSTRUCTIONS.register("none", NoLowMachCorrection())
LOW_MACH_RECONSTRUCTIONS.register("thornber", ThornberCorrection())
