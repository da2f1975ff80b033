"""1-D radial finite-volume reference for barotropic (Tait) Euler flows (host side, numpy).

Thesis §3.7.2 ("2D Blast Explosion", SPEC §12.1 V3) compares the particle solution with "a one
dimensional finite volume code with a very fine mesh as explained in [Toro, 2009]" (Toro 2009,
§1.6.3 and ch. 17: multidimensional problems with radial symmetry reduce to 1-D equations with
geometric source terms).  This module is that code, written for the barotropic Tait model of the
thesis (mass and momentum only, no energy equation).

Equations, ``alpha = 0`` (planar), ``1`` (cylindrical) or ``2`` (spherical)::

    d/dt(rho)   + d/dr(rho u)       = -alpha rho u   / r
    d/dt(rho u) + d/dr(rho u^2 + p) = -alpha rho u^2 / r
    p = p0 + rho0 c0^2 / gamma ((rho / rho0)^gamma - 1)

Discretisation.  The equations are integrated in their geometric conservation form
``d/dt(r^a U) + d/dr(r^a F(U)) = (0, a r^(a-1) p)`` over cells ``[r_{i-1/2}, r_{i+1/2}]`` of
``[0, R]`` with measure ``V_i = (r_{i+1/2}^(a+1) - r_{i-1/2}^(a+1)) / (a+1)`` and face areas
``A = r^a``::

    V_i dU_i/dt = -(A F)_{i+1/2} + (A F)_{i-1/2} + (0, p_i (A_{i+1/2} - A_{i-1/2}))

Mass is therefore conserved to rounding (the face fluxes telescope; ``A = 0`` at ``r = 0``), and
a fluid at rest with uniform pressure stays exactly at rest (well balanced): the pressure flux
difference and the geometric source cancel.  Numerical flux: HLL with Davis wave-speed bounds
(or Rusanov); second-order MUSCL reconstruction of the primitive variables ``(rho, u)`` with the
monotonised-central (default) or minmod limiter; third-order SSP Runge-Kutta (Shu-Osher) with
``dt = cfl dr / max(|u| + c)``.  Boundaries: reflective wall at ``r = 0`` (mirror ghost cells,
``u -> -u``), transmissive at ``r = R`` (copied ghost cells).

API::

    ref = radial_tait_reference(1100.0, 1000.0, 0.05, 0.1, 1e-5, 1000.0, 1466.0, 7.0, alpha=1)
    ref.r, ref.rho, ref.u, ref.p     # cell centres and cell values at t_end
    ref(r_query)                     # dict of rho, u, p, c interpolated at r_query

Results are cached (:func:`functools.lru_cache`) on the arguments; their arrays are read-only.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from ..errors import SimulationError, invalid

__all__ = ["FLUXES", "LIMITERS", "RadialSolution", "radial_tait_reference"]

#: Accepted ``limiter`` and ``flux`` names.
LIMITERS = ("mc", "minmod")
FLUXES = ("hll", "rusanov")

_N_GHOST = 2
_MAX_STEPS = 10_000_000


@dataclass(frozen=True, eq=False)
class RadialSolution:
    """Radial solution at time ``t``: cell centres ``r``, faces ``faces`` (``n + 1``), cell values
    ``rho``, ``u``, ``p``, ``c``; ``measure`` is the physical measure of each cell (``2 pi r dr``
    cylindrical, ``4 pi`` ``(r_+^3 - r_-^3)/3`` spherical, ``dr`` planar) so that
    ``mass = sum(rho * measure)``; ``initial_mass`` is that sum for the initial cell averages."""

    r: np.ndarray
    faces: np.ndarray
    rho: np.ndarray
    u: np.ndarray
    p: np.ndarray
    c: np.ndarray
    measure: np.ndarray
    t: float
    alpha: int
    n_steps: int
    initial_mass: float

    @property
    def mass(self) -> float:
        """Total mass ``sum(rho * measure)`` at ``t``."""
        return float(np.sum(self.rho * self.measure))

    def __call__(self, r_query) -> dict[str, np.ndarray]:
        """``rho``, ``u``, ``p``, ``c`` linearly interpolated at ``r_query`` (any shape; values
        outside ``[r[0], r[-1]]`` are those of the end cells)."""
        q = np.asarray(r_query, dtype=np.float64)
        return {k: np.interp(q, self.r, getattr(self, k)) for k in ("rho", "u", "p", "c")}


def _positive(name: str, value, allowed: str = "a finite number > 0") -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise invalid(name, value, allowed) from None
    if not (math.isfinite(v) and v > 0.0):
        raise invalid(name, value, allowed)
    return v


def _limit(a: np.ndarray, b: np.ndarray, limiter: str) -> np.ndarray:
    """Limited slope from the backward (``a``) and forward (``b``) differences."""
    same = a * b > 0.0
    if limiter == "minmod":
        s = np.where(np.abs(a) < np.abs(b), a, b)
    else:  # monotonised central
        s = np.sign(a) * np.minimum(np.minimum(2.0 * np.abs(a), 2.0 * np.abs(b)),
                                    0.5 * np.abs(a + b))
    return np.where(same, s, 0.0)


def radial_tait_reference(rho_in: float, rho_out: float, r_interface: float, radius: float,
                          t_end: float, rho0: float, c0: float, gamma: float, p0: float = 0.0,
                          alpha: int = 1, n: int = 4000, cfl: float = 0.4, *,
                          limiter: str = "mc", flux: str = "hll") -> RadialSolution:
    """Fine 1-D finite-volume solution of the radially symmetric Tait Euler equations.

    Initial state at rest: ``rho = rho_in`` for ``r < r_interface``, ``rho_out`` outside (the
    cell straddling the interface gets the exact volume average), on ``n`` equal cells of
    ``[0, radius]``; integrated to ``t_end``.  ``alpha`` = 0 planar, 1 cylindrical, 2 spherical
    (for ``alpha = 0``, ``r = 0`` is a reflecting wall).  See the module docstring for the scheme
    (thesis §3.7.2 reference solution).  Returns a (cached, read-only) :class:`RadialSolution`.
    """
    rho_in = _positive("rho_in", rho_in)
    rho_out = _positive("rho_out", rho_out)
    radius = _positive("radius", radius)
    allowed = f"a number with 0 < r_interface < radius={radius!r}"
    r_interface = _positive("r_interface", r_interface, allowed)
    if r_interface >= radius:
        raise invalid("r_interface", r_interface, allowed)
    try:
        t_end = float(t_end)
    except (TypeError, ValueError):
        raise invalid("t_end", t_end, "a finite time >= 0") from None
    if not (math.isfinite(t_end) and t_end >= 0.0):
        raise invalid("t_end", t_end, "a finite time >= 0")
    rho0 = _positive("rho0", rho0)
    c0 = _positive("c0", c0)
    gamma = _positive("gamma", gamma)
    try:
        p0 = float(p0)
    except (TypeError, ValueError):
        raise invalid("p0", p0, "a finite pressure") from None
    if not math.isfinite(p0):
        raise invalid("p0", p0, "a finite pressure")
    if isinstance(alpha, bool) or alpha not in (0, 1, 2):
        raise invalid("alpha", alpha, "0 (planar), 1 (cylindrical), 2 (spherical)")
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 8:
        raise invalid("n", n, "an integer number of cells >= 8")
    cfl = _positive("cfl", cfl, "a number with 0 < cfl <= 1")
    if cfl > 1.0:
        raise invalid("cfl", cfl, "a number with 0 < cfl <= 1")
    if limiter not in LIMITERS:
        raise invalid("limiter", limiter, ", ".join(LIMITERS))
    if flux not in FLUXES:
        raise invalid("flux", flux, ", ".join(FLUXES))
    return _solve(rho_in, rho_out, r_interface, radius, t_end, rho0, c0, gamma, p0, int(alpha),
                  int(n), cfl, limiter, flux)


@functools.lru_cache(maxsize=16)
def _solve(rho_in, rho_out, r_interface, radius, t_end, rho0, c0, gamma, p0, alpha, n, cfl,
           limiter, flux) -> RadialSolution:
    k = rho0 * c0 * c0 / gamma
    g1 = 0.5 * (gamma - 1.0)

    def pressure(rho):
        return p0 + k * ((rho / rho0) ** gamma - 1.0)

    def sound(rho):
        return c0 * (rho / rho0) ** g1

    dr = radius / n
    faces = dr * np.arange(n + 1)
    r = 0.5 * (faces[1:] + faces[:-1])
    area = faces**alpha  # r^alpha at the faces (0^0 = 1 for the planar case)
    vol = (faces[1:] ** (alpha + 1) - faces[:-1] ** (alpha + 1)) / (alpha + 1)
    d_area = np.diff(area)
    omega = (1.0, 2.0 * np.pi, 4.0 * np.pi)[alpha]

    # exact cell averages of the step: fraction of each cell's measure inside r_interface
    inner = np.clip(faces, 0.0, r_interface) ** (alpha + 1) / (alpha + 1)
    frac = np.diff(inner) / vol
    rho = rho_out + (rho_in - rho_out) * frac
    mom = np.zeros(n)
    initial_mass = float(omega * np.sum(rho * vol))

    g = _N_GHOST
    sign = np.ones(g)
    left_idx = np.arange(g - 1, -1, -1)  # mirror: ghost j <-> cell g-1-j
    right_idx = np.full(g, n - 1)

    def rhs(rho, mom):
        u = mom / rho
        # ghost cells: mirror (u -> -u) at r = 0, copy at r = R
        rg = np.concatenate([rho[left_idx], rho, rho[right_idx]])
        ug = np.concatenate([-sign * u[left_idx], u, u[right_idx]])
        # MUSCL on primitive variables, cells 1..n+2 of the padded arrays (need n+1 faces)
        dr_rho = np.diff(rg)
        dr_u = np.diff(ug)
        s_rho = _limit(dr_rho[:-1], dr_rho[1:], limiter)  # slopes of padded cells 1..n+2
        s_u = _limit(dr_u[:-1], dr_u[1:], limiter)
        # face i-1/2 (i = 0..n) lies between padded cells g-1+i and g+i, i.e. slope index
        # (padded - 1): left cell -> s[g-2+i], right cell -> s[g-1+i]
        sl = slice(g - 2, g - 2 + n + 1)
        sr = slice(g - 1, g - 1 + n + 1)
        rho_l = rg[g - 1:g + n] + 0.5 * s_rho[sl]
        u_l = ug[g - 1:g + n] + 0.5 * s_u[sl]
        rho_r = rg[g:g + n + 1] - 0.5 * s_rho[sr]
        u_r = ug[g:g + n + 1] - 0.5 * s_u[sr]
        p_l, p_r = pressure(rho_l), pressure(rho_r)
        c_l, c_r = sound(rho_l), sound(rho_r)
        m_l, m_r = rho_l * u_l, rho_r * u_r
        f1_l, f1_r = m_l, m_r
        f2_l, f2_r = m_l * u_l + p_l, m_r * u_r + p_r
        if flux == "hll":
            s_lo = np.minimum(np.minimum(u_l - c_l, u_r - c_r), 0.0)
            s_hi = np.maximum(np.maximum(u_l + c_l, u_r + c_r), 0.0)
            w = 1.0 / (s_hi - s_lo)
            f1 = (s_hi * f1_l - s_lo * f1_r + s_hi * s_lo * (rho_r - rho_l)) * w
            f2 = (s_hi * f2_l - s_lo * f2_r + s_hi * s_lo * (m_r - m_l)) * w
        else:
            s_max = np.maximum(np.abs(u_l) + c_l, np.abs(u_r) + c_r)
            f1 = 0.5 * (f1_l + f1_r - s_max * (rho_r - rho_l))
            f2 = 0.5 * (f2_l + f2_r - s_max * (m_r - m_l))
        af1 = area * f1
        af2 = area * f2
        d_rho = -np.diff(af1) / vol
        d_mom = (-np.diff(af2) + pressure(rho) * d_area) / vol
        return d_rho, d_mom

    t = 0.0
    steps = 0
    while t < t_end:
        if steps >= _MAX_STEPS:
            raise SimulationError(f"radial reference: more than {_MAX_STEPS} steps before "
                                  f"t_end={t_end}", step=steps, time=t)
        smax = float(np.max(np.abs(mom / rho) + sound(rho)))
        dt = min(cfl * dr / smax, t_end - t)
        a1, b1 = rhs(rho, mom)
        rho1, mom1 = rho + dt * a1, mom + dt * b1
        a2, b2 = rhs(rho1, mom1)
        rho2 = 0.75 * rho + 0.25 * (rho1 + dt * a2)
        mom2 = 0.75 * mom + 0.25 * (mom1 + dt * b2)
        a3, b3 = rhs(rho2, mom2)
        rho = rho / 3.0 + 2.0 / 3.0 * (rho2 + dt * a3)
        mom = mom / 3.0 + 2.0 / 3.0 * (mom2 + dt * b3)
        t = t + dt if t + dt < t_end else t_end
        steps += 1
        if not np.all(rho > 0.0):
            raise SimulationError(f"radial reference: non-positive density at t={t:.6g}",
                                      step=steps, time=t)

    u = mom / rho
    arrays = {"r": r, "faces": faces, "rho": rho, "u": u, "p": pressure(rho), "c": sound(rho),
              "measure": omega * vol}
    for a in arrays.values():
        a.flags.writeable = False
    return RadialSolution(**arrays, t=t, alpha=alpha, n_steps=steps, initial_mass=initial_mass)
