"""``riemann_1d``: one-dimensional Riemann problems (shock tubes) against exact solutions.

Thesis §3.7.1 (R1: Tait water, Fig. 3.3) and R2 (Tammann/stiffened gas, Fig. 3.4); Sod's tube
for the ideal gas.  ``n`` fluid particles with equal volumes dx = (b - a)/n fill [a, b].
Transmissive ends (SPEC §13.7 item 40): beyond each end, ``ceil(kappa beta) + 1`` FROZEN
particles hold the undisturbed end state, so every fluid particle has a complete stencil; they
act as neighbours but are never updated (the waves must not reach them before ``t_end``).

Metrics (against :mod:`mlsph_jax.reference.riemann`): ``l1_rho``, ``l1_u``, ``l1_p`` =
sum_i V_i |phi_i - phi_exact(x_i)| / ((b - a) * range(phi_exact)), over fluid particles, where
range is max - min of the exact profile (the jump size; for R1's velocity, whose end states are
equal, it is the star velocity).  ``overshoot_rho``, ``overshoot_u``, ``overshoot_p`` and their
maximum ``overshoot``: the largest new extremum relative to the jump, i.e. over the interior
local extrema of the particle profile, the excess beyond the exact solution's extremum within
+-5 particle spacings (:func:`new_extremum`), divided by range(phi_exact).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from ..eos import get_eos, to_conservative, to_primitive
from ..errors import ConfigError
from ..plotting import subplots
from ..reference.riemann import EOS_KINDS, ExactRiemann
from ..schema import Key, join_problems, show, suggest
from ..simulation import Problem
from ..state import Domain, Kind, Particles, make_particles
from .base import register_case
from .common import params_from_config, scheme_from_config, support_layers

# --- config schema: the [case] keys and cross-checks (mlsph_jax.config validates with them) ---------

_STATE_KEYS = ("rho", "u", "p")


def check_riemann_1d(cfg: dict) -> None:
    """`left`/`right` hold `rho` > 0 and `u`, plus `p` for an EOS with an energy equation
    (ideal_gas: p > 0, stiffened_gas: p + pc > 0); for the barotropic tait EOS (or any EOS without
    an energy equation) `p` must be absent (the pressure follows from rho). `domain` = [a, b] with
    a < b and a < `x_interface` < b."""
    c, eos = cfg["case"], cfg["eos"]
    kind = eos["kind"]
    barotropic = not get_eos(kind).has_energy
    problems = []
    for side in ("left", "right"):
        st = c[side]
        for k in st:
            if k not in _STATE_KEYS:
                s = suggest(k, _STATE_KEYS)
                problems.append(f"unknown key case.{side}.{k} (value {show(st[k])})"
                                + (f"; did you mean case.{side}.{s}?" if s else "")
                                + f"; valid keys: {', '.join(_STATE_KEYS)}")
        for k in ("rho", "u"):
            if k not in st:
                problems.append(f"missing required key case.{side}.{k}; allowed: a float")
        if "rho" in st and st["rho"] <= 0:
            problems.append(f"invalid case.{side}.rho={show(st['rho'])}: out of range; "
                            "allowed: float > 0")
        if barotropic:
            if "p" in st:
                what = "Tait EOS" if kind == "tait" else f"EOS {kind!r}"
                problems.append(f"invalid case.{side}.p={show(st['p'])}: the pressure follows "
                                f"from rho for the barotropic {what}; allowed: no p "
                                "(remove it, or choose another eos.kind)")
        elif "p" not in st:
            problems.append(f"missing required key case.{side}.p: eos.kind = {kind!r} has an "
                            "energy equation and needs the pressure; allowed: a float")
        elif kind == "ideal_gas" and st["p"] <= 0:
            problems.append(f"invalid case.{side}.p={show(st['p'])}: out of range; "
                            "allowed: float > 0 for the ideal gas")
        elif kind == "stiffened_gas" and st["p"] + eos["pc"] <= 0:
            problems.append(f"invalid case.{side}.p={show(st['p'])}: out of range; "
                            f"allowed: p > -pc = {show(-eos['pc'])} for the stiffened gas")
    a, b = c["domain"]
    if not a < b:
        problems.append(f"invalid case.domain={show(c['domain'])}: out of order; "
                        "allowed: [a, b] with a < b")
    elif not a < c["x_interface"] < b:
        problems.append(f"invalid case.x_interface={show(c['x_interface'])}: outside the domain; "
                        f"allowed: a float in ({show(a)}, {show(b)})")
    if problems:
        raise ConfigError(join_problems(problems))


_STATE_NOTE = "keys rho, u and p; no p when eos.kind = tait (no energy equation)"

RIEMANN_1D_KEYS: dict[str, Key] = {
    "left": Key(dict, item_type=float, note=_STATE_NOTE,
                doc="state left of the interface: {rho = ..., u = ..., p = ...}"),
    "right": Key(dict, item_type=float, note=_STATE_NOTE,
                 doc="state right of the interface: {rho = ..., u = ..., p = ...}"),
    "x_interface": Key(float, unit="m", doc="position of the initial discontinuity"),
    "domain": Key(list, item_type=float, length=2, unit="m", doc="tube ends [a, b]"),
    "n": Key(int, minimum=10, doc="number of fluid particles in the tube"),
}


def exact_solution(cfg: Mapping) -> ExactRiemann | None:
    """The exact solution, or ``None`` for an EOS without an exact Riemann solver (one registered
    from a user's script): the run then has no reference metrics."""
    c, eos = cfg["case"], cfg["eos"]
    if eos["kind"] not in EOS_KINDS:
        return None
    has_p = get_eos(eos["kind"]).has_energy

    def st(s):
        return (s["rho"], s["u"], s["p"]) if has_p else (s["rho"], s["u"])

    return ExactRiemann(st(c["left"]), st(c["right"]), dict(eos), x0=c["x_interface"])


def build(cfg: Mapping) -> Problem:
    c = cfg["case"]
    scheme = scheme_from_config(cfg)
    params = params_from_config(cfg)
    eos = get_eos(scheme.eos)
    a, b = c["domain"]
    n = c["n"]
    dx = (b - a) / n
    n_frozen = math.ceil(scheme.support * scheme.beta) + 1
    i = np.arange(-n_frozen, n + n_frozen)
    x = a + (i + 0.5) * dx
    kind = np.where((i < 0) | (i >= n), int(Kind.FROZEN), int(Kind.FLUID))
    left = x <= c["x_interface"]

    def state(key, default=0.0):
        lv, rv = c["left"].get(key, default), c["right"].get(key, default)
        return jnp.asarray(np.where(left, lv, rv))

    U = to_conservative(state("rho"), state("u")[:, None], state("p"), eos, params)
    particles = make_particles(x[:, None], np.full(x.shape, dx), U, kind=kind,
                               ppd=np.full(x.shape, scheme.reconstruction_degree))
    domain = Domain((a - (n_frozen + 2) * dx,), (b + (n_frozen + 2) * dx,), (False,))
    exact = exact_solution(cfg)

    def metrics(p: Particles, t: float, P) -> dict[str, float]:
        return l1_errors(p, t, P, exact, scheme.eos, (a, b)) if exact is not None else {}

    def plot(out: Path, p: Particles, t: float, P) -> None:
        if exact is not None:
            plot_profiles(out / "profiles.png", p, t, P, exact, scheme.eos, title=_title(cfg))

    rho_r = float(c["right"]["rho"])
    x0 = float(c["x_interface"])

    def shock_position(p: Particles, t, P) -> dict:
        """Differentiable front position of a right-moving shock (thesis R1): x0 + sum over fluid
        particles right of x0 of V (rho - rho_R) / (max rho there - rho_R), exact for a step
        of any height from x0 to the shock."""
        fluid = (p.kind == Kind.FLUID) & (p.x[:, 0] > x0)
        rho = p.q[:, 0] / p.vol
        excess = jnp.where(fluid, rho - rho_r, 0.0)
        return {"shock_position": x0 + jnp.sum(p.vol * excess) / jnp.max(excess)}

    return Problem("riemann_1d", particles, params, scheme, domain, cfg["time"]["t_end"], metrics, plot,
                   config=cfg, description=_title(cfg), differentiable_diagnostics=shock_position)


def particle_count(cfg: Mapping) -> tuple[int, tuple[str, ...]]:
    """n fluid particles and ceil(kappa beta) + 1 frozen ones at each end (as :func:`build`)."""
    return cfg["case"]["n"] + 2 * (support_layers(cfg) + 1), ("case.n",)


RIEMANN_1D = register_case(
    "riemann_1d", RIEMANN_1D_KEYS, build, check=check_riemann_1d, dim=1, particle_count=particle_count,
    defaults_override={"scheme.frame": "lagrangian"},
    doc="One-dimensional Riemann problem (shock tube, thesis §3.7.1): two constant states separated by an "
        "interface at `x_interface`, compared with the exact solution.")


def _title(cfg) -> str:
    s = cfg["scheme"]
    return (f"riemann_1d ({cfg['eos']['kind']}, n={cfg['case']['n']}): {s['method']}, "
            f"reconstruction degree {s['reconstruction_degree']}, {s['frame']}")


def profile_fields(p: Particles, P, eos_kind: str):
    """Positions, volumes and primitive fields (rho, u, p, and e where the EOS has it) of the fluid
    particles (host arrays)."""
    fluid = np.asarray(p.kind) == int(Kind.FLUID)
    pr = to_primitive(p.U, get_eos(eos_kind), P)
    x = np.asarray(p.x[:, 0])[fluid]
    out = {"rho": np.asarray(pr.rho)[fluid], "u": np.asarray(pr.vel[:, 0])[fluid],
           "p": np.asarray(pr.p)[fluid]}
    if get_eos(eos_kind).has_energy:
        out["e"] = np.asarray(pr.e)[fluid]
    return x, np.asarray(p.vol)[fluid], out


def l1_errors(p: Particles, t: float, P, exact: ExactRiemann, eos_kind: str, span) -> dict[str, float]:
    """Normalised L1 errors of rho, u, p against the exact solution (module docstring)."""
    x, vol, f = profile_fields(p, P, eos_kind)
    ex = exact(x, t)
    fine = exact(np.linspace(span[0], span[1], 20001), t)
    out = {}
    for k in ("rho", "u", "p"):
        rng = float(np.max(fine[k]) - np.min(fine[k]))
        out[f"l1_{k}"] = float(np.sum(vol * np.abs(f[k] - ex[k])) / ((span[1] - span[0]) * max(rng, 1e-300)))
    for k in ("rho", "u", "p"):
        rng = float(np.max(fine[k]) - np.min(fine[k]))
        out[f"overshoot_{k}"] = new_extremum(x, f[k], lambda xs, k=k: exact(xs, t)[k],
                                             OVERSHOOT_WINDOW * float(np.mean(vol))) / max(rng, 1e-300)
    out["overshoot"] = max(out[f"overshoot_{k}"] for k in ("rho", "u", "p"))
    return out


#: Half-width of the window (in particle spacings) over which a numerical extremum is compared
#: with the exact solution's extremum (module docstring).
OVERSHOOT_WINDOW = 5


def new_extremum(x, f, exact_fn, w: float) -> float:
    """Largest new extremum of the particle profile ``f(x)``: over the interior local maxima
    (minima) of the numerical profile, the largest amount by which f exceeds the maximum (falls
    below the minimum) of the exact solution within ``[x_i - w, x_i + w]``.  Smearing creates no
    interior extrema, so only spurious oscillations (overshoots, undershoots, wiggles) count."""
    o = np.argsort(x)
    x, f = x[o], f[o]
    fm, fc, fp = f[:-2], f[1:-1], f[2:]
    is_max = (fc >= fm) & (fc >= fp) & ((fc > fm) | (fc > fp))
    is_min = (fc <= fm) & (fc <= fp) & ((fc < fm) | (fc < fp))
    xs = np.linspace(-w, w, 201)
    worst = 0.0
    for sel, sign in ((is_max, 1.0), (is_min, -1.0)):
        i = np.flatnonzero(sel) + 1
        if i.size == 0:
            continue
        ex = exact_fn((x[i][:, None] + xs[None, :]).ravel()).reshape(i.size, xs.size)
        bound = ex.max(axis=1) if sign > 0 else ex.min(axis=1)
        worst = max(worst, float(np.max(sign * (f[i] - bound))))
    return max(worst, 0.0)


def plot_profiles(path: Path, p: Particles, t: float, P, exact: ExactRiemann, eos_kind: str, title: str = ""):
    """Particle profiles of rho, u, p (and e) against the exact solution."""


    x, _, f = profile_fields(p, P, eos_kind)
    xf = np.linspace(x.min(), x.max(), 2000)
    ex = exact(xf, t)
    names = [k for k in ("rho", "u", "p", "e") if k in f]
    fig, axes = subplots(1, len(names), figsize=(4.2 * len(names), 3.4))
    labels = {"rho": "density", "u": "velocity", "p": "pressure", "e": "internal energy"}
    for ax, k in zip(axes, names, strict=True):
        ax.plot(xf, ex[k], "k-", lw=1.2, label="exact")
        ax.plot(x, f[k], "o", ms=3, mfc="none", color="tab:blue", label="particles")
        ax.set_xlabel("x")
        ax.set_title(labels[k])
    axes[0].legend(fontsize=8)
    fig.suptitle(f"{title}  t={t:.4g}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
