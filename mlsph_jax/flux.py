"""ALE fluxes and the Rusanov numerical flux contracted with a pair area vector.

ALE flux in the direction of a vector a (thesis eq. 2.17, 2.19, 4.3-4.5; SPEC §1.3):

    F_w(U, w) . a = ( rho v_a,  rho u v_a + p a,  rho E v_a + p u.a ),   v_a = (u - w) . a

Rusanov (local Lax-Friedrichs) flux at the interface point x_ij (thesis §3.6.2 and eq.
4.37-4.38, read as SPEC §5.4 recommends):

    G_ij . A_ij = 1/2 [F_w(U^-, w_ij) + F_w(U^+, w_ij)] . A_ij - 1/2 S_ij (U^+ - U^-) (n . A_ij)

with the non-negative wave speed S_ij = max(|v^-_n| + c^-, |v^+_n| + c^+) (``rusanov_abs``,
default).  The thesis' printed signed maxima are kept as ``printed_ch3`` (T:L1233) and
``printed_ch4`` (T(4.38)) for reproduction studies; they can be negative (anti-diffusive).
The normal is n = A/|A| (``area``, default: dissipation 1/2 S dU |A|) or the unit pair vector
n_ij (``pair``), identical for kernel SPH-ALE where A_ij is parallel to n_ij.
"""

from __future__ import annotations

import jax.numpy as jnp

from .eos import EOS, Primitive, to_primitive
from .kernels import safe_norm
from .registry import Registry

WAVE_SPEEDS = Registry("scheme.wave_speed")
for _n in ("rusanov_abs", "printed_ch3", "printed_ch4"):
    WAVE_SPEEDS.register(_n)(_n)
FLUXES = Registry("scheme.flux")
FLUXES.register("rusanov")("rusanov")


def ale_flux_dot(U, pr: Primitive, w, a, eos: EOS):
    """F_w(U, w) . a for states ``U[..., nv]`` with primitives ``pr``, frame velocity ``w[..., d]``
    and direction vectors ``a[..., d]`` (thesis eq. 2.19)."""
    va = jnp.sum((pr.vel - w) * a, axis=-1)
    parts = [U[..., :1] * va[..., None],
             U[..., 1:1 + a.shape[-1]] * va[..., None] + pr.p[..., None] * a]
    if eos.has_energy:
        parts.append((U[..., -1] * va + pr.p * jnp.sum(pr.vel * a, axis=-1))[..., None])
    return jnp.concatenate(parts, axis=-1)


def rusanov_dot_area(Um, Up, w_ij, A, n_pair, eos: EOS, params, *, wave_speed: str = "rusanov_abs",
                     normal: str = "area"):
    """G_ij . A_ij for reconstructed states ``Um`` (i side) and ``Up`` (j side), ``[..., nv]``.

    ``n_pair`` is the unit vector from i to j (used when ``normal == "pair"`` and by nothing
    else).  Pairs with A = 0 give exactly zero.
    """
    pm = to_primitive(Um, eos, params)
    pp = to_primitive(Up, eos, params)
    central = 0.5 * (ale_flux_dot(Um, pm, w_ij, A, eos) + ale_flux_dot(Up, pp, w_ij, A, eos))
    if normal == "area":
        amag = safe_norm(A)
        n = A / jnp.where(amag > 0, amag, 1.0)[..., None]
        n_dot_A = amag
    else:
        n = n_pair
        n_dot_A = jnp.sum(n_pair * A, axis=-1)
    vm = jnp.sum((pm.vel - w_ij) * n, axis=-1)
    vp = jnp.sum((pp.vel - w_ij) * n, axis=-1)
    if wave_speed == "rusanov_abs":
        S = jnp.maximum(jnp.abs(vm) + pm.c, jnp.abs(vp) + pp.c)
    elif wave_speed == "printed_ch3":
        S = jnp.maximum(vp + pp.c, vm - pm.c)
    else:  # printed_ch4: c_ij and (u - w).n from the interface average
        v = 0.5 * (vm + vp)
        cij = 0.5 * (pm.c + pp.c)
        S = jnp.maximum(jnp.maximum(v + cij, v - cij), v)
    return central - 0.5 * (S * n_dot_A)[..., None] * (Up - Um)
