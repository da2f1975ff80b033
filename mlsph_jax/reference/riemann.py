"""Exact solutions of the 1-D Riemann problem (host side: numpy/scipy, not JAX).

Used as the reference for case metrics, plots and tests (SPEC §12.1, V1 and V2).

Equations of state (SPEC §2.1), selected by ``eos["kind"]``:

* ``"ideal_gas"`` (``gamma``): :math:`p=(\\gamma-1)\\rho e`, :math:`c=\\sqrt{\\gamma p/\\rho}`.
* ``"stiffened_gas"`` (alias ``"tammann"``; ``gamma``, ``pc``):
  :math:`p=(\\gamma-1)\\rho e-\\gamma p_c`, :math:`c=\\sqrt{\\gamma(p+p_c)/\\rho}`.
* ``"tait"`` (``rho0``, ``c0``, ``gamma``, optional ``p0`` = 0):
  :math:`p=\\rho_0c_0^2/\\gamma\\,[(\\rho/\\rho_0)^\\gamma-1]+p_0`,
  :math:`c=c_0(\\rho/\\rho_0)^{(\\gamma-1)/2}`; barotropic, no energy equation.

Method.  Ideal gas: Toro (2009), *Riemann Solvers and Numerical Methods for Fluid Dynamics*,
3rd ed., ch. 4 — the star pressure is the root of the pressure function
:math:`f_L(p)+f_R(p)+u_R-u_L=0` (shock branch from the Rankine–Hugoniot conditions,
rarefaction branch from the isentropic relations), and the solution is sampled on
:math:`\\xi=(x-x_0)/t` (Toro §4.5).  Stiffened gas: Ivings, Causon & Toro (1998), Int. J. Numer.
Meth. Fluids 28:395–418 — the ideal-gas solver written for :math:`\\bar p=p+p_c` (the energy
equation is exactly the ideal-gas one in :math:`\\bar p`).  Tait: the barotropic system (mass
and momentum) has two nonlinear waves and no contact; the unknown is the common star density
:math:`\\rho^*`; across a rarefaction :math:`u\\pm 2c/(\\gamma-1)` is invariant and across a shock
:math:`u^*-u_K=\\mp\\sqrt{(p^*-p_K)(\\rho^*-\\rho_K)/(\\rho^*\\rho_K)}` (Rankine–Hugoniot for mass
and momentum).  The (monotone) pressure/density function is solved with a bracketed root
finder (:func:`scipy.optimize.brentq`) rather than bare Newton, to near machine precision.

API::

    star = star_state(left, right, eos)          # StarState
    sol = sample(left, right, eos, x, t, x0=0.0)  # dict of arrays: rho, u, p, c (+ e for gases)
    exact = ExactRiemann(left, right, eos, x0=0.05); exact(x, t)

``left``/``right`` are ``(rho, u, p)`` tuples or ``{"rho":, "u":, "p":}`` dicts; for Tait
``p`` may be omitted (``(rho, u)``) since it follows from ``rho``; if given it must agree
with the Tait pressure of ``rho`` (relative tolerance 1e-6).

For Tait the sampled dict has **no** ``"e"`` key: the barotropic model carries no energy
equation, so there is no exact internal energy to report (check ``"e" in sol``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from ..errors import InputError, invalid

__all__ = ["EOS_KINDS", "ExactRiemann", "StarState", "sample", "star_state"]

#: Accepted ``eos["kind"]`` values (``"tammann"`` is an alias of ``"stiffened_gas"``).
EOS_KINDS = ("ideal_gas", "stiffened_gas", "tammann", "tait")

_REQUIRED = {"ideal_gas": ("gamma",), "stiffened_gas": ("gamma", "pc"),
             "tait": ("rho0", "c0", "gamma")}
_OPTIONAL = {"ideal_gas": (), "stiffened_gas": (), "tait": ("p0",)}
# Auxiliary caloric constants that may sit in an EOS config section; they do not enter the
# Riemann solution and are accepted and ignored.
_IGNORED = ("kind", "cv", "cp", "R", "T0")

_TAIT_P_RTOL = 1e-6
_EPS = np.finfo(float).eps


@dataclass(frozen=True)
class _EOS:
    kind: str  # "ideal_gas" | "stiffened_gas" | "tait"
    gamma: float
    pc: float = 0.0
    rho0: float = 1.0
    c0: float = 1.0
    p0: float = 0.0

    # --- Tait helpers -------------------------------------------------------------------------
    def tait_p(self, rho):
        k = self.rho0 * self.c0**2 / self.gamma
        return k * ((rho / self.rho0) ** self.gamma - 1.0) + self.p0

    def tait_c(self, rho):
        return self.c0 * (rho / self.rho0) ** (0.5 * (self.gamma - 1.0))

    def tait_rho_from_c(self, c):
        return self.rho0 * (c / self.c0) ** (2.0 / (self.gamma - 1.0))

    def tait_secant(self, rho, rho_k):
        """(p(rho) - p(rho_k)) / (rho - rho_k) without cancellation (-> c(rho_k)^2 at rho_k)."""
        g = self.gamma
        lr = math.log1p((rho - rho_k) / rho_k)  # log(rho / rho_k)
        ratio = g if lr == 0.0 else math.expm1(g * lr) / math.expm1(lr)
        return self.c0**2 / g * (rho_k / self.rho0) ** (g - 1.0) * ratio


@dataclass(frozen=True)
class StarState:
    """Exact star-region state and wave structure of a Riemann problem.

    ``p``, ``u``: star pressure and velocity; ``rho_l``/``rho_r``: star densities left/right of
    the contact (equal for Tait, which has no contact); ``c_l``/``c_r``: star sound speeds;
    ``e_l``/``e_r``: star specific internal energies (``None`` for Tait);
    ``wave_l``/``wave_r``: ``"shock"`` or ``"rarefaction"`` (a zero-strength wave is reported
    as a rarefaction of zero width).  Wave speeds: ``head``/``tail`` of each wave, the head
    being the edge facing the undisturbed state; for a shock ``head == tail`` = shock speed.
    ``contact`` is the contact speed (= ``u``; Tait has no contact but ``u`` is still the
    particle-path speed).
    """

    p: float
    u: float
    rho_l: float
    rho_r: float
    wave_l: str
    wave_r: str
    c_l: float
    c_r: float
    speed_l_head: float
    speed_l_tail: float
    speed_r_tail: float
    speed_r_head: float
    e_l: float | None = None
    e_r: float | None = None
    kind: str = "ideal_gas"

    @property
    def contact(self) -> float:
        return self.u

    @property
    def shock_speed_l(self) -> float | None:
        """Left shock speed, or ``None`` if the left wave is a rarefaction."""
        return self.speed_l_head if self.wave_l == "shock" else None

    @property
    def shock_speed_r(self) -> float | None:
        """Right shock speed, or ``None`` if the right wave is a rarefaction."""
        return self.speed_r_head if self.wave_r == "shock" else None


# ------------------------------------------------------------------------------------------------
# Input validation
# ------------------------------------------------------------------------------------------------

def _finite_float(argument: str, value, allowed: str = "a finite real number") -> float:
    try:
        if isinstance(value, bool | str | bytes):
            raise TypeError
        arr = np.asarray(value, dtype=float)
        if arr.shape != ():
            raise TypeError
        v = float(arr)
    except (TypeError, ValueError):
        raise invalid(argument, value, allowed) from None
    if not math.isfinite(v):
        raise invalid(argument, value, allowed)
    return v


def _parse_eos(eos) -> _EOS:
    if not isinstance(eos, Mapping):
        raise invalid("eos", eos, "a dict with 'kind' in " + ", ".join(EOS_KINDS)
                      + " and its constants")
    kind = eos.get("kind")
    if kind not in EOS_KINDS:
        raise invalid("eos['kind']", kind, ", ".join(EOS_KINDS))
    kind = "stiffened_gas" if kind == "tammann" else kind
    req, opt = _REQUIRED[kind], _OPTIONAL[kind]
    missing = [k for k in req if k not in eos]
    if missing:
        optional = f"; optional: {', '.join(opt)}" if opt else ""
        raise InputError(f"eos of kind {kind!r} is missing constant(s) {', '.join(missing)}; "
                         f"required: {', '.join(req)}{optional}")
    unknown = [k for k in eos if k not in req + opt + _IGNORED]
    if unknown:
        raise InputError(f"eos of kind {kind!r} has unknown key(s) "
                         f"{', '.join(map(repr, unknown))}; "
                         f"allowed: {', '.join(req + opt + _IGNORED)}")
    gamma = _finite_float("eos['gamma']", eos["gamma"], "a finite number > 1")
    if not gamma > 1.0:
        raise invalid("eos['gamma']", eos["gamma"], "a finite number > 1")
    if kind == "ideal_gas":
        return _EOS(kind, gamma)
    if kind == "stiffened_gas":
        pc = _finite_float("eos['pc']", eos["pc"], "a finite number >= 0")
        if pc < 0.0:
            raise invalid("eos['pc']", eos["pc"], "a finite number >= 0")
        return _EOS(kind, gamma, pc=pc)
    rho0 = _finite_float("eos['rho0']", eos["rho0"], "a finite number > 0")
    c0 = _finite_float("eos['c0']", eos["c0"], "a finite number > 0")
    for name, v in (("rho0", rho0), ("c0", c0)):
        if not v > 0.0:
            raise invalid(f"eos[{name!r}]", eos[name], "a finite number > 0")
    p0 = _finite_float("eos['p0']", eos.get("p0", 0.0))
    return _EOS(kind, gamma, rho0=rho0, c0=c0, p0=p0)


def _parse_state(argument: str, state, eos: _EOS) -> tuple[float, float, float]:
    """Return (rho, u, p) as floats; for gases p is the physical pressure."""
    tait = eos.kind == "tait"
    form = "(rho, u, p)" + (" or (rho, u)" if tait else "")
    if isinstance(state, Mapping):
        keys = ("rho", "u", "p")
        unknown = [k for k in state if k not in keys]
        need = ("rho", "u") if tait else keys
        missing = [k for k in need if k not in state]
        if unknown or missing:
            raise invalid(argument, dict(state), f"a dict with keys {', '.join(need)}"
                          + (" and optionally p" if tait else ""))
        rho, u, p = state["rho"], state["u"], state.get("p")
    else:
        try:
            vals = list(state)
        except TypeError:
            raise invalid(argument, state, f"a tuple {form} or a dict with those keys") from None
        if len(vals) == 3:
            rho, u, p = vals
        elif len(vals) == 2 and tait:
            (rho, u), p = vals, None
        else:
            raise invalid(argument, state, f"a tuple {form} or a dict with those keys")
    rho = _finite_float(f"{argument} density rho", rho, "a finite number > 0")
    if not rho > 0.0:
        raise invalid(f"{argument} density rho", rho, "a finite number > 0")
    u = _finite_float(f"{argument} velocity u", u)
    if tait:
        p_eos = float(eos.tait_p(rho))
        if p is not None:
            p = _finite_float(f"{argument} pressure p", p)
            scale = abs(p_eos) + eos.rho0 * eos.c0**2 / eos.gamma
            if abs(p - p_eos) > _TAIT_P_RTOL * scale:
                raise invalid(f"{argument} pressure p", p,
                              f"the Tait pressure of rho={rho!r}, p={p_eos!r} (or omit p)")
        return rho, u, p_eos
    p = _finite_float(f"{argument} pressure p", p)
    if not p + eos.pc > 0.0:
        bound = "p > 0" if eos.kind == "ideal_gas" else f"p > -pc = {-eos.pc!r}"
        raise invalid(f"{argument} pressure p", p, f"a finite number with {bound}")
    return rho, u, p


# ------------------------------------------------------------------------------------------------
# Star state
# ------------------------------------------------------------------------------------------------

def _bracketed_root(g, scale: float, what: str) -> float:
    """Root of an increasing function g on (0, inf) with g(0) < 0, to ~machine precision."""
    hi = scale
    g_hi = g(hi)
    for _ in range(2100):
        if g_hi > 0.0:
            break
        hi *= 2.0
        g_hi = g(hi)
        if not math.isfinite(hi) or not math.isfinite(g_hi):
            break
    if not (math.isfinite(g_hi) and g_hi > 0.0):
        raise InputError(f"left, right: no finite star {what} found (waves too strong for float64)")
    if g_hi == 0.0:
        return hi
    return brentq(g, 0.0, hi, xtol=1e-300, rtol=4 * _EPS, maxiter=500)


def _gas_star(left, right, eos: _EOS) -> StarState:
    g, pc = eos.gamma, eos.pc
    (rl, ul, pl), (rr, ur, pr) = left, right
    bl, br = pl + pc, pr + pc  # shifted pressures pbar = p + pc (> 0)
    cl, cr = math.sqrt(g * bl / rl), math.sqrt(g * br / rr)
    du = ur - ul
    gm, gp = g - 1.0, g + 1.0

    crit = 2.0 / gm * (cl + cr)
    if not crit > du:
        raise InputError(
            f"left, right generate vacuum: the pressure positivity condition "
            f"2/(gamma-1)*(c_L + c_R) = {crit!r} > u_R - u_L = {du!r} is violated "
            f"(left={left!r}, right={right!r})")

    def f(b, rho_k, b_k, c_k):
        if b > b_k:  # shock
            a, bb = 2.0 / (gp * rho_k), gm / gp * b_k
            return (b - b_k) * math.sqrt(a / (b + bb))
        return 2.0 * c_k / gm * ((b / b_k) ** (gm / (2.0 * g)) - 1.0)

    def fun(b):
        return f(b, rl, bl, cl) + f(b, rr, br, cr) + du

    bs = _bracketed_root(fun, max(bl, br), "pressure")
    us = 0.5 * (ul + ur) + 0.5 * (f(bs, rr, br, cr) - f(bs, rl, bl, cl))
    q = gm / gp

    def side(rho_k, b_k, c_k):
        ratio = bs / b_k
        if ratio > 1.0:
            rho_s = rho_k * (ratio + q) / (q * ratio + 1.0)
            wave = "shock"
        else:
            rho_s = rho_k * ratio ** (1.0 / g)
            wave = "rarefaction"
        return wave, rho_s, math.sqrt(g * bs / rho_s)

    wl, rsl, csl = side(rl, bl, cl)
    wr, rsr, csr = side(rr, br, cr)
    if wl == "shock":
        sl = ul - cl * math.sqrt(gp / (2 * g) * bs / bl + gm / (2 * g))
        l_head = l_tail = sl
    else:
        l_head, l_tail = ul - cl, us - csl
    if wr == "shock":
        sr = ur + cr * math.sqrt(gp / (2 * g) * bs / br + gm / (2 * g))
        r_head = r_tail = sr
    else:
        r_head, r_tail = ur + cr, us + csr
    ps = bs - pc
    return StarState(p=ps, u=us, rho_l=rsl, rho_r=rsr, wave_l=wl, wave_r=wr, c_l=csl, c_r=csr,
                     speed_l_head=l_head, speed_l_tail=l_tail, speed_r_tail=r_tail,
                     speed_r_head=r_head, e_l=(ps + g * pc) / (gm * rsl),
                     e_r=(ps + g * pc) / (gm * rsr), kind=eos.kind)


def _tait_star(left, right, eos: _EOS) -> StarState:
    g = eos.gamma
    (rl, ul, _), (rr, ur, _) = left, right
    cl, cr = float(eos.tait_c(rl)), float(eos.tait_c(rr))
    du = ur - ul
    crit = 2.0 / (g - 1.0) * (cl + cr)
    if not crit > du:
        raise InputError(
            f"left, right generate vacuum (cavitation to zero density): the condition "
            f"2/(gamma-1)*(c_L + c_R) = {crit!r} > u_R - u_L = {du!r} is violated "
            f"(left={left!r}, right={right!r})")

    def f(rho, rho_k, c_k):
        if rho > rho_k:  # shock: sqrt((p-pK)(rho-rhoK)/(rho rhoK))
            return (rho - rho_k) * math.sqrt(eos.tait_secant(rho, rho_k) / (rho * rho_k))
        return 2.0 / (g - 1.0) * (float(eos.tait_c(rho)) - c_k)

    def fun(rho):
        return f(rho, rl, cl) + f(rho, rr, cr) + du

    rs = _bracketed_root(fun, max(rl, rr), "density")
    us = 0.5 * (ul + ur) + 0.5 * (f(rs, rr, cr) - f(rs, rl, cl))
    cs = float(eos.tait_c(rs))
    if rs > rl:
        wl = "shock"
        l_head = l_tail = ul - math.sqrt(eos.tait_secant(rs, rl) * rs / rl)
    else:
        wl, l_head, l_tail = "rarefaction", ul - cl, us - cs
    if rs > rr:
        wr = "shock"
        r_head = r_tail = ur + math.sqrt(eos.tait_secant(rs, rr) * rs / rr)
    else:
        wr, r_head, r_tail = "rarefaction", ur + cr, us + cs
    return StarState(p=float(eos.tait_p(rs)), u=us, rho_l=rs, rho_r=rs, wave_l=wl, wave_r=wr,
                     c_l=cs, c_r=cs, speed_l_head=l_head, speed_l_tail=l_tail,
                     speed_r_tail=r_tail, speed_r_head=r_head, kind="tait")


def _solve(left, right, eos):
    e = _parse_eos(eos)
    lt = _parse_state("left", left, e)
    rt = _parse_state("right", right, e)
    star = _tait_star(lt, rt, e) if e.kind == "tait" else _gas_star(lt, rt, e)
    return e, lt, rt, star


def star_state(left, right, eos) -> StarState:
    """Exact star state of the Riemann problem ``left | right`` for the EOS ``eos``.

    ``left``/``right``: ``(rho, u, p)`` or ``{"rho", "u", "p"}`` (Tait: ``p`` optional).
    ``eos``: e.g. ``{"kind": "ideal_gas", "gamma": 1.4}``,
    ``{"kind": "stiffened_gas", "gamma": 7.15, "pc": 3e8}``,
    ``{"kind": "tait", "rho0": 1000, "c0": 1466, "gamma": 7, "p0": 0}``.
    Raises :class:`~mlsph_jax.errors.InputError` for invalid input or if the data generate
    vacuum (pressure positivity condition violated).
    """
    return _solve(left, right, eos)[3]


# ------------------------------------------------------------------------------------------------
# Sampling
# ------------------------------------------------------------------------------------------------

def _sample(e: _EOS, lt, rt, s: StarState, x, t, x0) -> dict[str, np.ndarray]:
    try:
        xa = np.asarray(x, dtype=float)
    except (TypeError, ValueError):
        raise invalid("x", x, "a real array of positions") from None
    if not np.all(np.isfinite(xa)):
        raise invalid("x", x, "finite positions (no NaN/inf)")
    t = _finite_float("t", t, "a finite time >= 0")
    if t < 0.0:
        raise invalid("t", t, "a finite time >= 0")
    x0 = _finite_float("x0", x0)

    (rl, ul, pl), (rr, ur, pr) = lt, rt
    rho, u, p = np.empty_like(xa), np.empty_like(xa), np.empty_like(xa)

    def put(mask, r_, u_, p_):
        rho[mask], u[mask], p[mask] = r_, u_, p_

    if t == 0.0:
        left_mask = xa <= x0
        put(left_mask, rl, ul, pl)
        put(~left_mask, rr, ur, pr)
    else:
        xi = (xa - x0) / t
        tait = e.kind == "tait"
        g, pc = e.gamma, e.pc
        # Regions, left to right: L | left fan | star-L | star-R | right fan | R.
        m_l = xi < s.speed_l_head
        m_fl = ~m_l & (xi < s.speed_l_tail)
        m_sl = ~m_l & ~m_fl & (xi <= s.u)
        m_r = xi > s.speed_r_head
        m_fr = ~m_r & (xi > s.speed_r_tail)
        m_sr = ~m_r & ~m_fr & (xi > s.u)
        put(m_l, rl, ul, pl)
        put(m_r, rr, ur, pr)
        put(m_sl, s.rho_l, s.u, s.p)
        put(m_sr, s.rho_r, s.u, s.p)
        if tait:
            cl, cr = float(e.tait_c(rl)), float(e.tait_c(rr))
        else:
            bl, br = pl + pc, pr + pc
            cl, cr = math.sqrt(g * bl / rl), math.sqrt(g * br / rr)
        k = (g - 1.0) / (g + 1.0)
        if np.any(m_fl):  # left fan: u + 2c/(g-1) invariant, xi = u - c
            c = k * (ul + 2.0 * cl / (g - 1.0) - xi[m_fl])
            if tait:
                r_ = e.tait_rho_from_c(c)
                put(m_fl, r_, xi[m_fl] + c, e.tait_p(r_))
            else:
                r_ = rl * (c / cl) ** (2.0 / (g - 1.0))
                put(m_fl, r_, xi[m_fl] + c, bl * (c / cl) ** (2.0 * g / (g - 1.0)) - pc)
        if np.any(m_fr):  # right fan: u - 2c/(g-1) invariant, xi = u + c
            c = k * (xi[m_fr] - ur + 2.0 * cr / (g - 1.0))
            if tait:
                r_ = e.tait_rho_from_c(c)
                put(m_fr, r_, xi[m_fr] - c, e.tait_p(r_))
            else:
                r_ = rr * (c / cr) ** (2.0 / (g - 1.0))
                put(m_fr, r_, xi[m_fr] - c, br * (c / cr) ** (2.0 * g / (g - 1.0)) - pc)

    out = {"rho": rho, "u": u, "p": p}
    if e.kind == "tait":
        out["c"] = e.tait_c(rho)
    else:
        out["c"] = np.sqrt(e.gamma * (p + e.pc) / rho)
        out["e"] = (p + e.gamma * e.pc) / ((e.gamma - 1.0) * rho)
    return out


def sample(left, right, eos, x, t, x0: float = 0.0) -> dict[str, np.ndarray]:
    """Exact solution at positions ``x`` (any shape) and time ``t >= 0``; interface at ``x0``.

    Returns a dict of float64 arrays shaped like ``x``: ``rho``, ``u``, ``p``, ``c`` and, for
    the ideal and stiffened gas, ``e`` (specific internal energy).  Tait has no ``e`` key
    (barotropic: no energy equation).  At ``t == 0`` the initial data are returned, with
    ``x <= x0`` taking the left state.
    """
    e, lt, rt, star = _solve(left, right, eos)
    return _sample(e, lt, rt, star, x, t, x0)


class ExactRiemann:
    """Exact Riemann solution, solved once at construction and callable as ``exact(x, t)``.

    Attributes: ``star`` (:class:`StarState`), ``left``/``right`` (validated ``(rho, u, p)``
    tuples; Tait ``p`` computed from ``rho``), ``x0``, ``kind``.
    """

    def __init__(self, left, right, eos, x0: float = 0.0):
        self._eos, self.left, self.right, self.star = _solve(left, right, eos)
        self.x0 = _finite_float("x0", x0)
        self.kind = self._eos.kind

    def __call__(self, x, t) -> dict[str, np.ndarray]:
        return _sample(self._eos, self.left, self.right, self.star, x, t, self.x0)

    def wave_positions(self, t) -> dict[str, float]:
        """Positions at time ``t`` of the wave edges: ``left_head``, ``left_tail``, ``contact``,
        ``right_tail``, ``right_head`` (a shock has ``head == tail``; for Tait ``contact`` is
        the position of the material initially at ``x0``)."""
        t = _finite_float("t", t, "a finite time >= 0")
        if t < 0.0:
            raise invalid("t", t, "a finite time >= 0")
        s = self.star
        speeds = {"left_head": s.speed_l_head, "left_tail": s.speed_l_tail, "contact": s.u,
                  "right_tail": s.speed_r_tail, "right_head": s.speed_r_head}
        return {k: self.x0 + v * t for k, v in speeds.items()}

    def __repr__(self) -> str:
        return (f"ExactRiemann(kind={self.kind!r}, left={self.left!r}, right={self.right!r}, "
                f"x0={self.x0!r}, p*={self.star.p:.6g}, u*={self.star.u:.6g})")
