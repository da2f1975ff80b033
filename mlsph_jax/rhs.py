"""Semi-discrete right-hand sides of MLSPH-ALE and SPH-ALE for y = (x, V, V U).

MLSPH-ALE (thesis eq. 4.36, 4.32, 4.28; SPEC §5.3):

    d(V_i U_i)/dt = - sum_j [G_ij - s (F_w)_i] . A_ij + V_i S_i,   A_ij = V_i grad N_ji - V_j grad N_ij
    dV_i/dt       =   sum_j (w_ij - w_i) . A_ij
    dx_i/dt       =   sum_j N_j(x_i) w_j                              (MLS interpolant of w)

SPH-ALE (thesis eq. 3.5-3.7, 4.27): the same with A_ij = 2 V_i V_j grad_i W(x_i - x_j, h_ij),
h_ij = (h_i + h_j)/2, and particles moved by the Shepard average of w (eq. 3.7).

G_ij is the Rusanov flux (:mod:`mlsph_jax.flux`) between the Riemann states reconstructed at the
pair midpoint x_ij from each side:

* ``mlsph_ale``: direct MLS reconstruction, U^-_ij = p((x_ij - x_i)/h_i)^T C_i U_{S_i} (eq. 4.39 as
  read in SPEC §13.1 item 6), and symmetrically from j;
* ``sph_ale``: Taylor reconstruction with MLS derivatives, U^-_ij = U_i + grad U_i . d + 1/2 d^T H_i d
  (eq. 3.11), which is U_i + [P_i(xi) - P_i(0)] for the fitted polynomial P_i;
* degree 0 (or a pair whose MOOD degree min(ppd_i, ppd_j) is 0): first order, U_i and U_j.

The j-side state is never recomputed: it is the i-side state of the reverse pair, gathered with
the neighbour list's reverse-slot map.  The self term s (F_w)_i (``scheme.self_flux``) keeps
uniform states exact on any layout; without it, the pair terms are antisymmetric and the totals
of V U are conserved to round-off (SPEC §5.5).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp

from . import approximation as apx
from .approximation import basis
from .eos import from_primitive_vector, get_eos, primitive_vector, to_primitive
from .flux import ale_flux_dot, rusanov_dot_area
from .kernels import get_kernel, safe_norm
from .scheme import Scheme
from .state import Domain, Kind, Params, Particles


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Geometry:
    """Everything the fluxes need that depends only on positions and volumes.

    For Eulerian runs it is computed once per chunk; for moving particles once per stage.
    idx/mask/rev: neighbour list; pair_mask excludes padding and self; dx[N,K,d] = x_j - x_i;
    A[N,K,d] area vectors; h[N]; coeffs[N,m,K] reconstruction fit (None for first order);
    interp[N,K] weights of the position update.
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

    @property
    def jsafe(self):
        n = self.idx.shape[0]
        return jnp.where(self.mask, self.idx, jnp.arange(n)[:, None])


def _box(domain: Domain):
    if not domain.any_periodic:
        return None, None
    return jnp.asarray(domain.length), jnp.asarray(domain.periodic)


def _shepard_weights(dx, h, jsafe, mask, vol, kernel):
    hij = 0.5 * (h[:, None] + h[jsafe])
    w = kernel.w_vec(dx, hij) * jnp.where(mask, vol[jsafe], 0.0)
    return w / jnp.sum(w, axis=1, keepdims=True)


def geometry(x, vol, nl, scheme: Scheme, domain: Domain) -> Geometry:
    """Area vectors, offsets, reconstruction coefficients and interpolation weights."""
    n, d = x.shape
    L, per = _box(domain)
    h = apx.smoothing_length(vol, scheme.beta, d)
    idx, mask, rev = nl.idx, nl.mask, nl.rev
    dx = apx.pair_offsets(x, idx, mask, L, per)
    self_i = jnp.arange(n)[:, None]
    jsafe = jnp.where(mask, idx, self_i)
    pair_mask = mask & (idx != self_i)
    kern = get_kernel(scheme.kernel)
    coeffs = None
    if scheme.method == "mlsph_ale":
        aspec = scheme.area_spec()
        ops = apx.build(x, h, vol, idx, mask, aspec, L, per)
        G = ops.gradients                      # grad N_j(x_i) = grad N_ji
        G_rev = G[jsafe, rev]                  # grad N_i(x_j) = grad N_ij
        A = vol[:, None, None] * G - vol[jsafe][..., None] * G_rev      # thesis eq. 5.77
        interp = ops.values
        if aspec.with_coeffs:
            coeffs = ops.coeffs
    else:
        hij = 0.5 * (h[:, None] + h[jsafe])
        gradW = kern.grad(-dx, hij)            # grad_i W(x_i - x_j, h_ij)
        A = 2.0 * vol[:, None, None] * vol[jsafe][..., None] * gradW    # thesis eq. 3.5 / 5.84
        interp = None
    if scheme.position_update == "shepard" or (interp is None and scheme.position_update == "mls"):
        interp = _shepard_weights(dx, h, jsafe, mask, vol, kern)
    if coeffs is None and scheme.reconstruction_degree > 0:
        coeffs = apx.build(x, h, vol, idx, mask, scheme.reconstruction_spec(), L, per).coeffs
    A = jnp.where(pair_mask[..., None], A, 0.0)
    return Geometry(idx, mask, rev, pair_mask, dx, A, h, coeffs, interp, nl.overflow)


def frame_velocity(U, kind, scheme: Scheme, params: Params):
    """w_i: zero (Eulerian) or the fluid velocity (Lagrangian); non-fluid particles do not move."""
    eos = get_eos(scheme.eos)
    if scheme.frame == "eulerian":
        d = U.shape[1] - eos.n_vars(1) + 1
        return jnp.zeros((U.shape[0], d), U.dtype)
    vel = to_primitive(U, eos, params).vel
    return jnp.where((kind == Kind.FLUID)[:, None], vel, 0.0)


def reconstruct(F, geom: Geometry, degree: int, taylor: bool, ppd):
    """Riemann states of the field ``F[N, nv]`` at the pair midpoints: (i side, j side) ``[N,K,nv]``.

    ``degree`` 0 is first order.  Pairs with min(ppd_i, ppd_j) == 0 fall back to first order
    (the MOOD parachute).
    """
    jsafe = geom.jsafe
    Fm0 = jnp.broadcast_to(F[:, None, :], geom.dx.shape[:2] + F.shape[1:])
    Fp0 = F[jsafe]
    if degree == 0:
        return Fm0, Fp0
    a = jnp.einsum("nmk,nkv->nmv", geom.coeffs, Fp0)          # a_i = C_i F_S
    xi = 0.5 * geom.dx / geom.h[:, None, None]                 # (x_ij - x_i) / h_i
    own = jnp.einsum("nkm,nmv->nkv", basis.evaluate(xi, degree), a)
    if taylor:
        own = Fm0 + own - a[:, None, 0, :]                     # F_i + P_i(xi) - P_i(0)
    other = own[jsafe, geom.rev]                               # j-side state = i-side of (j, i)
    high = (jnp.minimum(ppd[:, None], ppd[jsafe]) > 0)[..., None]
    return jnp.where(high, own, Fm0), jnp.where(high, other, Fp0)


def rhs(particles: Particles, params: Params, geom: Geometry, scheme: Scheme):
    """Time derivatives ``(dx/dt, dV/dt, d(VU)/dt)`` for the given geometry (pure, jit-able)."""
    eos = get_eos(scheme.eos)
    x, vol, q, kind = particles.x, particles.vol, particles.q, particles.kind
    U = q / vol[:, None]
    prim = to_primitive(U, eos, params)
    w = frame_velocity(U, kind, scheme, params)
    jsafe = geom.jsafe

    primitive = scheme.reconstruction_variables == "primitive"
    F = primitive_vector(U, eos, params) if primitive else U
    Fm, Fp = reconstruct(F, geom, scheme.reconstruction_degree, scheme.reconstruction == "taylor", particles.ppd)
    if primitive:
        Um, Up = from_primitive_vector(Fm, eos, params), from_primitive_vector(Fp, eos, params)
    else:
        Um, Up = Fm, Fp

    w_ij = 0.5 * (w[:, None, :] + w[jsafe])
    r = safe_norm(geom.dx)
    n_pair = geom.dx / jnp.where(r > 0, r, 1.0)[..., None]
    GA = rusanov_dot_area(Um, Up, w_ij, geom.A, n_pair, eos, params,
                          wave_speed=scheme.wave_speed, normal=scheme.dissipation_normal)
    GA = jnp.where(geom.pair_mask[..., None], GA, 0.0)
    dq = -jnp.sum(GA, axis=1)
    if scheme.self_flux:
        dq = dq + ale_flux_dot(U, prim, w, jnp.sum(geom.A, axis=1), eos)
    dq = dq + vol[:, None] * source(U, prim, params, eos)
    dvol = jnp.sum(jnp.sum((w_ij - w[:, None, :]) * geom.A, axis=-1), axis=1)
    if scheme.frame == "eulerian":
        dxdt = jnp.zeros_like(x)
    elif scheme.position_update == "w_i":
        dxdt = w
    else:
        dxdt = jnp.einsum("nk,nkd->nd", geom.interp, w[jsafe])
    fluid = kind == Kind.FLUID
    return (jnp.where(fluid[:, None], dxdt, 0.0), jnp.where(fluid, dvol, 0.0),
            jnp.where(fluid[:, None], dq, 0.0))


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
