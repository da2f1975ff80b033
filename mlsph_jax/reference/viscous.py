"""Exact start-up solutions of plane Couette and Poiseuille flow (thesis §3.7.4, eq. 3.20-3.21).

Incompressible fluid of kinematic viscosity ``nu`` at rest between plates at y = 0 (fixed) and
y = L; at t = 0 the top plate starts moving at ``u_plate`` and/or a body force ``f_x`` along
the plates is switched on.  u(y, t) solves u_t = nu u_yy + f_x with u(0) = 0, u(L) = u_plate,
u(y, 0) = 0 (0 <= y < L); by linearity the two drives superpose:

Couette (thesis eq. 3.20, Morris et al. 1997):

    u_C = u_plate y / L + sum_{n>=1} 2 u_plate (-1)^n / (n pi) sin(n pi y / L) exp(-nu n^2 pi^2 t / L^2)

Poiseuille, with the sign of the series corrected (SPEC §12.1 V6 and §13 item 35; the printed
eq. 3.21 has y (y - L) and a "+" series, which is u < 0 at steady state for f_x > 0):

    u_P = f_x / (2 nu) y (L - y) - sum_{n>=0} 4 f_x L^2 / (nu pi^3 k^3) sin(k pi y / L)
          exp(-k^2 pi^2 nu t / L^2),   k = 2n + 1.

Check of the sign: the sine series of y (L - y) on (0, L) is sum_{k odd} 8 L^2 / (pi^3 k^3)
sin(k pi y / L), so u_P(y, 0) = 0 and u_P -> f_x y (L - y) / (2 nu) (peak f_x L^2 / (8 nu))
as t -> infinity; tests/test_channel_flows.py checks both limits and the PDE numerically.

Truncation: terms are summed until exp(-nu k^2 pi^2 t / L^2) < 1e-17 (at most
:data:`MAX_TERMS`); at t = 0 the initial state is returned exactly.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError

#: Upper bound on the number of series terms (reached only for nu t / L^2 < ~4e-10).
MAX_TERMS = 200_000


def _check(nu: float, gap: float, t: float) -> None:
    if not (math.isfinite(nu) and nu > 0):
        raise InputError(f"invalid nu={nu!r}; allowed: a finite float > 0")
    if not (math.isfinite(gap) and gap > 0):
        raise InputError(f"invalid gap={gap!r}; allowed: a finite float > 0")
    if not (math.isfinite(t) and t >= 0):
        raise InputError(f"invalid t={t!r}; allowed: a finite float >= 0")


def _n_terms(nu: float, gap: float, t: float) -> int:
    """Largest wave number k with exp(-nu k^2 pi^2 t / L^2) >= 1e-17 (capped)."""
    decay = nu * math.pi**2 * t / gap**2
    return min(MAX_TERMS, int(math.ceil(math.sqrt(39.2 / decay))) + 1)


def _sine_sum(y: np.ndarray, k: np.ndarray, coef: np.ndarray, nu: float, gap: float, t: float) -> np.ndarray:
    """sum_k coef_k sin(k pi y / L) exp(-nu k^2 pi^2 t / L^2), in blocks (memory)."""
    out = np.zeros_like(y)
    damp = coef * np.exp(-nu * (k * math.pi / gap) ** 2 * t)
    block = max(1, 2_000_000 // max(y.size, 1))
    for s in range(0, k.size, block):
        kk, dd = k[s:s + block], damp[s:s + block]
        out += np.sin(np.multiply.outer(y, kk) * (math.pi / gap)) @ dd
    return out


def couette_startup(y, t: float, u_plate: float, nu: float, gap: float = 1.0) -> np.ndarray:
    """Couette start-up velocity u(y, t) (thesis eq. 3.20); top plate at y = gap moving at u_plate."""
    t = float(t)
    _check(nu, gap, t)
    y = np.asarray(y, float)
    if t == 0.0:
        return np.where(y >= gap, u_plate, 0.0) + 0.0 * y
    n = np.arange(1, _n_terms(nu, gap, t) + 1, dtype=float)
    coef = 2.0 * u_plate * (-1.0) ** n / (n * math.pi)
    return u_plate * y / gap + _sine_sum(y, n, coef, nu, gap, t)


def poiseuille_startup(y, t: float, f_x: float, nu: float, gap: float = 1.0) -> np.ndarray:
    """Poiseuille start-up velocity u(y, t) for a body force f_x (thesis eq. 3.21, sign corrected)."""
    t = float(t)
    _check(nu, gap, t)
    y = np.asarray(y, float)
    steady = f_x / (2.0 * nu) * y * (gap - y)
    if t == 0.0:
        return 0.0 * y
    k = 2.0 * np.arange(0, (_n_terms(nu, gap, t) + 1) // 2 + 1, dtype=float) + 1.0
    coef = 4.0 * f_x * gap**2 / (nu * math.pi**3 * k**3)
    return steady - _sine_sum(y, k, coef, nu, gap, t)


def channel_startup(y, t: float, *, u_plate: float = 0.0, f_x: float = 0.0, nu: float,
                    gap: float = 1.0) -> np.ndarray:
    """Superposition of the Couette (plate speed ``u_plate``) and Poiseuille (force ``f_x``) start-ups."""
    out = np.zeros_like(np.asarray(y, float))
    if u_plate != 0.0:
        out = out + couette_startup(y, t, u_plate, nu, gap)
    if f_x != 0.0:
        out = out + poiseuille_startup(y, t, f_x, nu, gap)
    return out


def channel_steady(y, *, u_plate: float = 0.0, f_x: float = 0.0, nu: float, gap: float = 1.0) -> np.ndarray:
    """Steady profile u_plate y / L + f_x y (L - y) / (2 nu) (the t -> infinity limit)."""
    y = np.asarray(y, float)
    return u_plate * y / gap + f_x / (2.0 * nu) * y * (gap - y)


def channel_u_max(*, u_plate: float = 0.0, f_x: float = 0.0, nu: float, gap: float = 1.0) -> float:
    """max over 0 <= y <= L of |steady profile| (u_plate for Couette, f_x L^2 / (8 nu) for
    Poiseuille): the velocity scale of Re = u_max L / nu and of the normalised errors."""
    cand = [0.0, gap]
    if f_x != 0.0:
        cand.append(min(max(0.5 * gap + u_plate * nu / (f_x * gap), 0.0), gap))
    return float(np.max(np.abs(channel_steady(np.asarray(cand), u_plate=u_plate, f_x=f_x, nu=nu, gap=gap))))
