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

from .eos import EOS, Primitive
from .registry import Registry

FLUXES: Registry = Registry("scheme.flux", protocol=("pair_flux",), doc="numerical (Riemann) fluxes")
WAVE_SPEEDS: Registry = Registry("scheme.wave_speed", protocol=("speed",), doc="wave-speed estimates")
DISSIPATION_NORMALS: Registry = Registry("scheme.dissipation_normal", protocol=("project", "needs_pair_vector"),
                                         doc="normal of the dissipation term")


def ale_flux_dot(U, pr: Primitive, w, a, eos: EOS):
    """F_w(U, w) . a for states ``U[..., nv]`` with primitives ``pr``, frame velocity ``w[..., d]``
    and direction vectors ``a[..., d]`` (thesis eq. 2.19)."""
    va = jnp.sum((pr.vel - w) * a, axis=-1)
    parts = [U[..., :1] * va[..., None],
             U[..., 1:1 + a.shape[-1]] * va[..., None] + pr.p[..., None] * a]
    if eos.has_energy:
        parts.append((U[..., -1] * va + pr.p * jnp.sum(pr.vel * a, axis=-1))[..., None])
    return jnp.concatenate(parts, axis=-1)


def _dot(u, v):
    s = u[0] * v[0]
    for a in range(1, len(u)):
        s = s + u[a] * v[a]
    return s


def primitive_components(U, eos: EOS, params):
    """``(vel, p, c)`` of states given as a list of component arrays ``[rho, rho u.., (rho E)]``.

    Same formulas as :func:`mlsph_jax.eos.to_primitive` with one reciprocal of rho per state
    (the velocity and energy are products with it), so that XLA fuses the whole pair flux into
    one loop.
    """
    d = len(U) - (2 if eos.has_energy else 1)
    rho = U[0]
    inv = 1.0 / rho
    vel = [U[1 + a] * inv for a in range(d)]
    e = U[1 + d] * inv - 0.5 * _dot(vel, vel) if eos.has_energy else jnp.zeros_like(rho)
    p = eos.pressure(rho, e, params)
    return vel, p, eos.sound_speed(rho, p, params)


class RusanovAbs:
    """S = max(|v^-_n| + c^-, |v^+_n| + c^+), non-negative (the standard Rusanov estimate; default)."""

    @staticmethod
    def speed(vm, vp, cm, cp):
        return jnp.maximum(jnp.abs(vm) + cm, jnp.abs(vp) + cp)


class PrintedCh3:
    """S = max(v^+_n + c^+, v^-_n - c^-) as printed in thesis ch. 3 (T:L1233); may be negative."""

    @staticmethod
    def speed(vm, vp, cm, cp):
        return jnp.maximum(vp + cp, vm - cm)


class PrintedCh4:
    """S = max(v + c_ij, v - c_ij, v) with interface averages v, c_ij as printed in thesis eq. 4.38."""

    @staticmethod
    def speed(vm, vp, cm, cp):
        v = 0.5 * (vm + vp)
        cij = 0.5 * (cm + cp)
        return jnp.maximum(jnp.maximum(v + cij, v - cij), v)


WAVE_SPEEDS.register("rusanov_abs", RusanovAbs())
WAVE_SPEEDS.register("printed_ch3", PrintedCh3())
WAVE_SPEEDS.register("printed_ch4", PrintedCh4())


class AreaNormal:
    """n = A_ij / |A_ij|: the dissipation is 1/2 S (U^+ - U^-) |A_ij|."""

    needs_pair_vector = False

    @staticmethod
    def project(relm, relp, A, n_pair):
        """Normal relative velocities (v^-_n, v^+_n) and n . A_ij."""
        r2 = _dot(A, A)
        pos = r2 > 0
        amag = jnp.where(pos, jnp.sqrt(jnp.where(pos, r2, 1.0)), 0.0)     # safe_norm(A)
        den = jnp.where(amag > 0, amag, 1.0)
        return _dot(relm, A) / den, _dot(relp, A) / den, amag


class PairNormal:
    """n = n_ij, the unit vector from i to j (identical to ``area`` for kernel SPH-ALE).  The
    dissipation uses |n_ij . A_ij|: MLS area vectors need not point along n_ij, and a negative
    projection would make the dissipation term anti-diffusive."""

    needs_pair_vector = True

    @staticmethod
    def project(relm, relp, A, n_pair):
        return _dot(relm, n_pair), _dot(relp, n_pair), jnp.abs(_dot(n_pair, A))


DISSIPATION_NORMALS.register("area", AreaNormal())
DISSIPATION_NORMALS.register("pair", PairNormal())


class RusanovFlux:
    """Rusanov (local Lax-Friedrichs) flux in the ALE frame (module docstring):
    G_ij . A_ij = 1/2 [F_w(U^-) + F_w(U^+)] . A_ij - 1/2 S_ij (U^+ - U^-) (n . A_ij), with S_ij from
    ``scheme.wave_speed`` and n from ``scheme.dissipation_normal``.

    Flux protocol: ``pair_flux(Um, Up, w, A, n_pair, eos, params, scheme) -> list of nv arrays``
    on lists of component arrays (structure of arrays): ``Um``/``Up`` the i-/j-side states
    ``[rho, rho u.., (rho E)]``, ``w`` the frame velocity at the interface (list of d arrays) or
    ``None`` for w = 0, ``A`` the area vector, ``n_pair`` the unit pair vector (only when the
    dissipation normal asks for it).  Pairs with A = 0 must give exactly zero.
    """

    def pair_flux(self, Um, Up, w, A, n_pair, eos: EOS, params, scheme):
        return rusanov_components(Um, Up, w, A, n_pair, eos, params, wave_speed=scheme.wave_speed,
                                  normal=scheme.dissipation_normal)


FLUXES.register("rusanov", RusanovFlux())


def rusanov_components(Um, Up, w, A, n_pair, eos: EOS, params, *, wave_speed: str = "rusanov_abs",
                       normal: str = "area"):
    """G_ij . A_ij on lists of component arrays (structure of arrays), see :func:`rusanov_dot_area`.

    ``Um``/``Up``: lists of nv arrays; ``w``: list of d arrays or ``None`` (w = 0); ``A`` and
    ``n_pair``: lists of d arrays (``n_pair`` only read when the dissipation normal needs it).
    Returns a list of nv arrays.
    """
    d = len(A)
    velm, pm, cm = primitive_components(Um, eos, params)
    velp, pp, cp = primitive_components(Up, eos, params)
    relm = velm if w is None else [velm[k] - w[k] for k in range(d)]
    relp = velp if w is None else [velp[k] - w[k] for k in range(d)]
    vam, vap = _dot(relm, A), _dot(relp, A)          # (u -+ w) . A
    vm, vp, n_dot_A = DISSIPATION_NORMALS.get(normal, "scheme.dissipation_normal").project(relm, relp, A, n_pair)
    S = WAVE_SPEEDS.get(wave_speed, "scheme.wave_speed").speed(vm, vp, cm, cp)
    diss = 0.5 * (S * n_dot_A)
    out = [0.5 * (Um[0] * vam + Up[0] * vap) - diss * (Up[0] - Um[0])]
    for k in range(d):
        out.append(0.5 * ((Um[1 + k] * vam + pm * A[k]) + (Up[1 + k] * vap + pp * A[k]))
                   - diss * (Up[1 + k] - Um[1 + k]))
    if eos.has_energy:
        out.append(0.5 * ((Um[-1] * vam + pm * _dot(velm, A)) + (Up[-1] * vap + pp * _dot(velp, A)))
                   - diss * (Up[-1] - Um[-1]))
    return out


def rusanov_dot_area(Um, Up, w_ij, A, n_pair, eos: EOS, params, *, wave_speed: str = "rusanov_abs",
                     normal: str = "area"):
    """G_ij . A_ij for reconstructed states ``Um`` (i side) and ``Up`` (j side), ``[..., nv]``.

    ``n_pair`` is the unit vector from i to j (used when ``normal == "pair"`` and by nothing
    else).  Pairs with A = 0 give exactly zero.  (Array front end of
    :func:`rusanov_components`.)
    """
    comps = lambda a: [a[..., k] for k in range(a.shape[-1])]
    out = rusanov_components(comps(Um), comps(Up), None if w_ij is None else comps(w_ij), comps(A),
                             None if n_pair is None else comps(n_pair), eos, params,
                             wave_speed=wave_speed, normal=normal)
    return jnp.stack(out, axis=-1)
