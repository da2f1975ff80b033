"""``taylor_green_2d``: the two-dimensional viscous Taylor-Green vortex, weakly compressible
(thesis §3.7.3, Figs. 3.8-3.14, SPEC §12.1 V4; and the [0, 2 pi]^2 variant of §4.5.1, V8).

Four counter-rotating vortices decay in the periodic square [0, L]^2.  Exact solution of the
incompressible Navier-Stokes equations (thesis eq. 3.15-3.17 written for a general L; with
k = 2 pi / L, nu = mu / rho0 and F(t) = exp(-8 pi^2 nu t / L^2) = exp(-2 k^2 nu t)):

    u = U0 sin(k x) cos(k y) F,   v = -U0 cos(k x) sin(k y) F,
    p = rho0 U0^2 / 4 [cos(2 k x) + cos(2 k y)] F^2        (gauge pressure, relative to eos.p0).

The kinetic energy E_k = integral of 1/2 rho0 |u|^2 = rho0 U0^2 L^2 F^2 / 4 decays as
F^2 = exp(-16 pi^2 nu t / L^2), which for L = U0 = rho0 = 1 is exp(-16 pi^2 t / Re) (thesis
eq. 3.19).  For L = 2 pi, U0 = 1 it is the thesis eq. 4.41 with F = exp(-2 nu t).

Reynolds number and viscosity.  ``case.re`` is the Reynolds number Re = rho0 U0 L / mu based on
the box side L (thesis §3.7.3); the builder sets physics.mu = rho0 U0 L / Re (a config may
leave physics.mu = 0 or give exactly that value; anything else is a ConfigError).  Thesis
§4.5.1 quotes Re = 100 with the decay e^{-2t/Re}, i.e. a Reynolds number based on the length
1/k = L/(2 pi) = 1: in this case's convention that is re = 200 pi (mu = 0.01).

Set-up.  ``n`` x ``n`` particles of volume dx^2 (dx = L/n): a Cartesian lattice x = (i + 1/2) dx
or (``layout = "perturbed"``) the lattice with each coordinate displaced by a uniform random
amount in [-a dx, a dx], a = ``perturbation`` (wrapped into the box; volumes stay dx^2).
Velocities from the exact solution at t = 0, density from the Tait law inverted at the exact
pressure, rho = rho0 (1 + gamma p_exact / (rho0 c0^2))^(1/gamma) (thesis §3.7.3).  All
particles are fluid; periodicity is the neighbour search's minimum image (no ghost particles).

Metrics at the final time t (fluid particles i, volumes V_i, densities rho_i, velocities u_i,
gauge pressures p_i - eos.p0, exact fields evaluated at the particle positions x_i):

* ``ke_rel_error`` = |E_k / E_k,exact - 1| with E_k = sum_i 1/2 V_i rho_i |u_i|^2 (kinetic
  energy of the particles) and E_k,exact = rho0 U0^2 L^2 F^2 / 4;
* ``ke_ratio_rel_error`` = |(E_k / E_k(0)) / F^2 - 1|: the decay factor r(t) of thesis eq. 3.18
  against eq. 3.19 (removes the quadrature error of E_k(0) on perturbed layouts);
* ``umax_rel_error`` = |max_i |u_i| / max_i |u_exact(x_i, t)| - 1| (the exact maximum sampled
  at the same points: on the lattice the particles miss the points where |u| = U0 F by dx/2,
  an O(dx^2) sampling offset that is not a solver error);
* ``l2_velocity_error`` = sqrt(sum_i V_i |u_i - u_exact(x_i)|^2 / sum_i V_i |u_exact(x_i)|^2);
* ``l2_pressure_error`` = sqrt(sum_i V_i (p'_i - p'_exact,i)^2 / sum_i V_i) / (rho0 U0^2 F^2 / 2),
  with p' the pressure minus its volume-weighted mean: in a weakly compressible run the mean
  pressure is not fixed by the incompressible solution (it follows the mean density, which
  drifts with the O(Ma^2) compressibility), so only the fluctuation is compared, relative to
  the exact pressure amplitude rho0 U0^2 F^2 / 2.

Diagnostics at every output time (``summary["timeseries"]``, ``timeseries.csv``): ``ke``,
``ke_exact``, ``umax``, ``umax_exact`` (U0 F, the continuous maximum), ``p_centre`` (gauge
pressure of the particle nearest the centre (L/2, L/2), minimum image), ``p_centre_exact``
(exact pressure at that particle) and ``p_mean`` (volume-weighted mean gauge pressure).

Plots: ``fields.png`` (u, v, p at the final time and their errors against the exact solution)
and ``decay.png`` (E_k/E_k(0) against F^2, max |u| / U0 against F, and the centre pressure,
from ``timeseries.csv``).
"""

from __future__ import annotations

import copy
import dataclasses
import math
from collections.abc import Mapping
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from ..eos import get_eos, to_conservative, to_primitive
from ..errors import ConfigError
from ..kernels import safe_norm
from ..plotting import subplots
from ..schema import Key, join_problems, show
from ..simulation import Problem
from ..state import Domain, Kind, Particles, make_particles
from .base import register_case
from .common import params_from_config, scheme_from_config


@dataclasses.dataclass(frozen=True)
class TaylorGreen:
    """Exact incompressible Taylor-Green solution on [0, L]^2 (module docstring)."""

    length: float = 1.0
    u0: float = 1.0
    rho0: float = 1.0
    nu: float = 0.01

    @classmethod
    def from_config(cls, cfg: Mapping) -> TaylorGreen:
        c = cfg["case"]
        rho0 = float(cfg["eos"]["rho0"])
        return cls(float(c["length"]), float(c["u0"]), rho0, viscosity(cfg) / rho0)

    @property
    def k(self) -> float:
        return 2.0 * math.pi / self.length

    # jnp throughout, so that the same formulas serve the host metrics and the differentiable
    # ones (nu may then be a traced parameter: dataclasses.replace(exact, nu=...))
    def decay(self, t):
        """F(t) = exp(-2 k^2 nu t) = exp(-8 pi^2 nu t / L^2) (velocity decay factor)."""
        return jnp.exp(-2.0 * self.k ** 2 * self.nu * jnp.asarray(t, dtype=float))

    def velocity(self, x, t):
        x = jnp.asarray(x, dtype=float)
        kx, ky = self.k * x[..., 0], self.k * x[..., 1]
        f = self.u0 * self.decay(t)
        return jnp.stack([f * jnp.sin(kx) * jnp.cos(ky), -f * jnp.cos(kx) * jnp.sin(ky)], axis=-1)

    def pressure(self, x, t):
        """Gauge pressure (relative to eos.p0)."""
        x = jnp.asarray(x, dtype=float)
        kx, ky = self.k * x[..., 0], self.k * x[..., 1]
        return 0.25 * self.rho0 * self.u0 ** 2 * (jnp.cos(2 * kx) + jnp.cos(2 * ky)) * self.decay(t) ** 2

    def kinetic_energy(self, t):
        """Integral of 1/2 rho0 |u|^2 over the box: rho0 U0^2 L^2 F^2 / 4."""
        return 0.25 * self.rho0 * self.u0 ** 2 * self.length ** 2 * self.decay(t) ** 2

    def umax(self, t):
        return self.u0 * self.decay(t)

    def pressure_amplitude(self, t):
        """max |p_exact| = rho0 U0^2 F^2 / 2."""
        return 0.5 * self.rho0 * self.u0 ** 2 * self.decay(t) ** 2


def viscosity(cfg: Mapping) -> float:
    """mu = rho0 U0 L / Re of a resolved config (``case.re`` defines the viscosity)."""
    c = cfg["case"]
    return float(cfg["eos"]["rho0"]) * float(c["u0"]) * float(c["length"]) / float(c["re"])


def resolved(cfg: Mapping) -> dict:
    """A copy of ``cfg`` with physics.mu set to the viscosity derived from ``case.re``."""
    out = copy.deepcopy(dict(cfg))
    out["physics"] = {**out.get("physics", {}), "mu": viscosity(cfg)}
    return out


def lattice(n: int, length: float, layout: str = "cartesian", perturbation: float = 0.15,
            seed: int = 0) -> np.ndarray:
    """``n^2`` positions in [0, L)^2: the lattice (i + 1/2) dx, optionally perturbed (module
    docstring).  Returns ``x[n^2, 2]``."""
    if layout not in ("cartesian", "perturbed"):
        raise ConfigError(f"invalid case.layout={layout!r}; allowed: one of \"cartesian\", \"perturbed\"")
    dx = length / n
    X, Y = np.meshgrid((np.arange(n) + 0.5) * dx, (np.arange(n) + 0.5) * dx, indexing="ij")
    x = np.stack([X.ravel(), Y.ravel()], axis=1)
    if layout == "perturbed" and perturbation > 0:
        x = x + np.random.default_rng(seed).uniform(-perturbation, perturbation, x.shape) * dx
        x = np.mod(x, length)
    return x


# --- config schema: the [case] keys and cross-checks (mlsph_jax.config validates with them) ---------

TAYLOR_GREEN_2D_LAYOUTS = ("cartesian", "perturbed")


def check_taylor_green_2d(cfg: dict) -> None:
    """`eos.kind` must be tait (the initial density inverts the Tait law at the exact pressure).
    The viscosity follows from `re`: mu = eos.rho0 `u0` `length` / `re`; physics.mu must be left
    at 0 (it is then set to that value) or equal it (relative difference <= 1e-9).
    `physics.body_force` must be empty. The Tait law must be invertible at the lowest exact
    pressure -rho0 u0^2/2: eos.gamma u0^2 / (2 eos.c0^2) < 1 (Mach number u0/c0 below
    sqrt(2/gamma), 0.53 for gamma = 7)."""
    c, eos, phys = cfg["case"], cfg["eos"], cfg["physics"]
    problems = []
    if eos["kind"] != "tait":
        problems.append(f"invalid eos.kind={show(eos['kind'])}: case taylor_green_2d sets the "
                        "initial density from the Tait law at the exact pressure; allowed: \"tait\"")
    else:
        mu = eos["rho0"] * c["u0"] * c["length"] / c["re"]
        if phys["mu"] != 0.0 and abs(phys["mu"] - mu) > 1e-9 * mu:
            problems.append(f"invalid physics.mu={show(phys['mu'])}: case taylor_green_2d derives "
                            f"the viscosity from case.re={show(c['re'])} (mu = eos.rho0 case.u0 "
                            f"case.length / case.re = {mu:.10g}); allowed: 0 (derived) or "
                            f"{mu:.10g} (set case.re instead)")
        if eos["gamma"] * c["u0"] ** 2 / (2.0 * eos["c0"] ** 2) >= 1.0:
            problems.append(f"invalid case.u0={show(c['u0'])}: the Tait law cannot be inverted at "
                            f"the lowest exact pressure -rho0 u0^2/2 with eos.c0={show(eos['c0'])}; "
                            f"allowed: u0 < c0 sqrt(2/gamma) = "
                            f"{eos['c0'] * math.sqrt(2.0 / eos['gamma']):.6g}")
    if phys["body_force"]:
        problems.append(f"invalid physics.body_force={show(phys['body_force'])}: the Taylor-Green "
                        "vortex has no body force; allowed: []")
    if problems:
        raise ConfigError(join_problems(problems))


TAYLOR_GREEN_2D_KEYS: dict[str, Key] = {
    "n": Key(int, 50, minimum=8,
             doc="particles per side (n^2 in total, spacing length/n); thesis §3.7.3: 100, "
                 "§4.5.1: 50"),
    "length": Key(float, 1.0, minimum=0.0, exclusive_minimum=True, unit="m",
                  doc="side L of the periodic square [0, L]^2 (one period of the vortex pattern; "
                      "thesis §3.7.3: 1, §4.5.1: 2 pi)"),
    "u0": Key(float, 1.0, minimum=0.0, exclusive_minimum=True, unit="m/s",
              doc="velocity amplitude U0 of the exact solution"),
    "re": Key(float, 100.0, minimum=0.0, exclusive_minimum=True,
              doc="Reynolds number Re = rho0 U0 L / mu (sets physics.mu = rho0 U0 L / Re); the "
                  "kinetic energy decays as exp(-16 pi^2 t U0 / (Re L))"),
    "layout": Key(str, "cartesian", choices=TAYLOR_GREEN_2D_LAYOUTS,
                  doc="initial particles: Cartesian lattice (x = (i + 1/2) dx) or the lattice "
                      "with random displacements"),
    "perturbation": Key(float, 0.15, minimum=0.0, maximum=0.5, exclusive_maximum=True,
                        doc="perturbed layout: each coordinate is displaced by a uniform random "
                            "amount in [-perturbation dx, +perturbation dx] (volumes stay dx^2)"),
    "seed": Key(int, 0, minimum=0, doc="random seed of the perturbed layout"),
}


def build(cfg: Mapping) -> Problem:
    cfg = resolved(cfg)
    c = cfg["case"]
    scheme = scheme_from_config(cfg)
    params = params_from_config(cfg)
    eos = get_eos(scheme.eos)
    n, L = c["n"], c["length"]
    dx = L / n
    reach = scheme.support * scheme.beta * dx
    if not reach < 0.5 * L:
        raise ConfigError(f"invalid case.n={n}: the support radius kappa beta dx = {reach:.6g} of "
                          f"scheme.kernel={scheme.kernel!r} with beta={scheme.beta:g} must be below "
                          f"half the periodic box (case.length/2 = {0.5 * L:.6g}); allowed: case.n > "
                          f"{math.floor(2.0 * scheme.support * scheme.beta)}")
    exact = TaylorGreen.from_config(cfg)
    x = lattice(n, L, c["layout"], c["perturbation"], c["seed"])
    N = len(x)
    e = cfg["eos"]
    p_ex = exact.pressure(x, 0.0)
    rho = e["rho0"] * (1.0 + e["gamma"] * p_ex / (e["rho0"] * e["c0"] ** 2)) ** (1.0 / e["gamma"])
    U = to_conservative(jnp.asarray(rho), jnp.asarray(exact.velocity(x, 0.0)), None, eos, params)
    particles = make_particles(x, np.full(N, dx * dx), U,
                               ppd=np.full(N, scheme.reconstruction_degree))
    domain = Domain((0.0, 0.0), (L, L), (True, True))
    ke0 = fields(particles, params, scheme.eos)["ke"]
    title = _title(cfg)

    def metrics(p: Particles, t: float, P) -> dict[str, float]:
        return error_metrics(p, t, P, exact, scheme.eos, ke0)

    def diagnostics(p: Particles, t: float, P) -> dict[str, float]:
        return time_diagnostics(p, t, P, exact, scheme.eos)

    def differentiable_metrics(p: Particles, t, P) -> dict:
        # the exact solution of the run's own viscosity, so d/d physics.mu sees both sides
        ex = dataclasses.replace(exact, nu=P["physics.mu"] / P["eos.rho0"])
        return error_terms(p, t, P, ex, scheme.eos)

    def plot(out: Path, p: Particles, t: float, P) -> None:
        plot_fields(out / "fields.png", p, t, P, exact, scheme.eos, title=title)
        plot_decay(out / "decay.png", Path(out) / "timeseries.csv", exact, title=title)

    return Problem("taylor_green_2d", particles, params, scheme, domain, cfg["time"]["t_end"], metrics,
                   plot, config=cfg, description=title, diagnostics=diagnostics,
                   differentiable_metrics=differentiable_metrics)


def particle_count(cfg: Mapping) -> tuple[int, tuple[str, ...]]:
    """n x n particles (periodic: no walls)."""
    return cfg["case"]["n"] ** 2, ("case.n",)


TAYLOR_GREEN_2D = register_case(
    "taylor_green_2d", TAYLOR_GREEN_2D_KEYS, build, check=check_taylor_green_2d, dim=2,
    particle_count=particle_count,
    defaults_override={"eos.kind": "tait", "eos.rho0": 1.0, "eos.c0": 10.0, "time.t_end": 1.0},
    doc="Two-dimensional viscous Taylor-Green vortex (weakly compressible, Tait EOS, periodic "
        "square [0, `length`]^2; thesis §3.7.3 and §4.5.1), compared with the exact incompressible "
        "solution.")


def _title(cfg) -> str:
    s, c = cfg["scheme"], cfg["case"]
    lay = c["layout"] + (f" {c['perturbation']:g} dx" if c["layout"] == "perturbed" else "")
    return (f"taylor_green_2d (L={c['length']:.4g}, {c['n']}x{c['n']} {lay}, Re={c['re']:g}): "
            f"{s['method']}, reconstruction degree {s['reconstruction_degree']}, {s['frame']}")


def fields(p: Particles, P, eos_kind: str) -> dict:
    """Host arrays of the fluid particles: x, vol, rho, vel, gauge pressure p - eos.p0, and the
    kinetic energy ``ke`` = sum_i 1/2 V_i rho_i |u_i|^2."""
    fluid = np.asarray(p.kind) == int(Kind.FLUID)
    pr = to_primitive(p.U, get_eos(eos_kind), P)
    vol = np.asarray(p.vol)[fluid]
    rho = np.asarray(pr.rho)[fluid]
    vel = np.asarray(pr.vel)[fluid]
    p0 = float(P["eos.p0"]) if "eos.p0" in P else 0.0
    return {"x": np.asarray(p.x)[fluid], "vol": vol, "rho": rho, "vel": vel,
            "p": np.asarray(pr.p)[fluid] - p0,
            "ke": float(np.sum(0.5 * vol * rho * np.sum(vel * vel, axis=1)))}


def error_terms(p: Particles, t, P, exact: TaylorGreen, eos_kind: str) -> dict:
    """``ke_rel_error``, ``umax_rel_error``, ``l2_velocity_error`` and ``l2_pressure_error`` of the
    module docstring as jnp scalars (jit-able and differentiable; non-fluid particles get zero
    weight).  The host metrics (:func:`error_metrics`) and ``mlsph sensitivity --of`` both use it."""
    pr = to_primitive(p.U, get_eos(eos_kind), P)
    fluid = p.kind == int(Kind.FLUID)
    vol = jnp.where(fluid, p.vol, 0.0)
    vel = pr.vel
    pg = pr.p - (P["eos.p0"] if "eos.p0" in P else 0.0)
    ue = exact.velocity(p.x, t)
    pe = exact.pressure(p.x, t)
    speed = jnp.where(fluid, safe_norm(vel), 0.0)          # finite derivative also where |u| = 0
    speed_e = jnp.where(fluid, safe_norm(ue), 0.0)
    err_u = jnp.sqrt(jnp.sum(vol * jnp.sum((vel - ue) ** 2, axis=1)) / jnp.sum(vol * jnp.sum(ue * ue, axis=1)))
    wsum = jnp.sum(vol)
    dp = (pg - jnp.sum(vol * pg) / wsum) - (pe - jnp.sum(vol * pe) / wsum)
    err_p = jnp.sqrt(jnp.sum(vol * dp * dp) / wsum) / exact.pressure_amplitude(t)
    ke = jnp.sum(0.5 * vol * pr.rho * jnp.sum(vel * vel, axis=1))
    return {"ke_rel_error": jnp.abs(ke / exact.kinetic_energy(t) - 1.0),
            "umax_rel_error": jnp.abs(jnp.max(speed) / jnp.max(speed_e) - 1.0),
            "l2_velocity_error": err_u, "l2_pressure_error": err_p}


def error_metrics(p: Particles, t: float, P, exact: TaylorGreen, eos_kind: str,
                  ke0: float | None = None) -> dict[str, float]:
    """The module docstring's metrics at time ``t`` (``ke0``: E_k of the initial particles)."""
    f = fields(p, P, eos_kind)
    vel = f["vel"]
    out = {k: float(v) for k, v in error_terms(p, t, P, exact, eos_kind).items()}
    if ke0 is not None:
        out["ke_ratio_rel_error"] = abs((f["ke"] / ke0) / float(exact.decay(t)) ** 2 - 1.0)
    out.update({"ke": f["ke"], "ke_exact": float(exact.kinetic_energy(t)),
                "umax": float(np.sqrt(np.sum(vel ** 2, axis=1)).max()), "umax_exact": float(exact.umax(t))})
    return out


def centre_index(x: np.ndarray, length: float) -> int:
    """Index of the particle nearest the box centre (minimum image on the periodic box)."""
    d = x - 0.5 * length
    d = d - length * np.round(d / length)
    return int(np.argmin(np.sum(d * d, axis=1)))


def time_diagnostics(p: Particles, t: float, P, exact: TaylorGreen, eos_kind: str) -> dict[str, float]:
    """The module docstring's diagnostics at time ``t``."""
    f = fields(p, P, eos_kind)
    i = centre_index(f["x"], exact.length)
    return {"ke": f["ke"], "ke_exact": float(exact.kinetic_energy(t)),
            "umax": float(np.sqrt(np.sum(f["vel"] ** 2, axis=1)).max()),
            "umax_exact": float(exact.umax(t)),
            "p_centre": float(f["p"][i]), "p_centre_exact": float(exact.pressure(f["x"][i], t)),
            "p_mean": float(np.sum(f["vol"] * f["p"]) / np.sum(f["vol"]))}


def plot_fields(path: Path, p: Particles, t: float, P, exact: TaylorGreen, eos_kind: str,
                title: str = "") -> None:
    """u, v, p (gauge) at time ``t`` (top) and their differences from the exact solution
    (bottom; the pressure difference after removing both volume-weighted means)."""


    f = fields(p, P, eos_kind)
    x = np.mod(f["x"], exact.length)
    ue, pe = exact.velocity(f["x"], t), exact.pressure(f["x"], t)
    w = f["vol"] / np.sum(f["vol"])
    dp = (f["p"] - np.sum(w * f["p"])) - (pe - np.sum(w * pe))
    top = [("u", f["vel"][:, 0]), ("v", f["vel"][:, 1]), ("p - p0", f["p"])]
    bottom = [("u - u_exact", f["vel"][:, 0] - ue[:, 0]), ("v - v_exact", f["vel"][:, 1] - ue[:, 1]),
              ("p' - p'_exact (means removed)", dp)]
    fig, axes = subplots(2, 3, figsize=(13.0, 8.0))
    ms = max(0.5, min(30.0, 6.0e4 / max(len(x), 1)))
    for row, panels in zip(axes, (top, bottom), strict=True):
        for ax, (name, val) in zip(row, panels, strict=True):
            lim = float(np.max(np.abs(val))) or 1.0
            sc = ax.scatter(x[:, 0], x[:, 1], c=val, s=ms, cmap="RdBu_r", vmin=-lim, vmax=lim,
                            linewidths=0, marker="s")
            fig.colorbar(sc, ax=ax, shrink=0.85)
            ax.set_title(name, fontsize=9)
            ax.set_aspect("equal")
            ax.set_xlim(0.0, exact.length)
            ax.set_ylim(0.0, exact.length)
    fig.suptitle(f"{title}\nt = {t:.4g}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def read_timeseries(path: Path) -> dict[str, np.ndarray] | None:
    """Columns of a ``timeseries.csv`` (None if the file is missing)."""
    path = Path(path)
    if not path.is_file():
        return None
    lines = path.read_text().strip().splitlines()
    keys = lines[0].split(",")
    data = np.array([[float(v) for v in ln.split(",")] for ln in lines[1:]], dtype=float).reshape(-1, len(keys))
    return {k: data[:, j] for j, k in enumerate(keys)}


def plot_decay(path: Path, series_path: Path, exact: TaylorGreen, title: str = "") -> None:
    """E_k / E_k(0) against F^2, max |u| / U0 against F and the centre pressure against the
    exact one, from the run's time series."""


    s = read_timeseries(series_path)
    if s is None or len(s["t"]) < 2:
        return
    t = s["t"]
    tf = np.linspace(0.0, float(t.max()), 400)
    fig, axes = subplots(1, 3, figsize=(13.0, 3.8))
    ax = axes[0]
    ax.plot(tf, exact.decay(tf) ** 2, "k-", lw=1.2, label="exact $F^2$")
    ax.plot(t, s["ke"] / s["ke"][0], "o", ms=4, mfc="none", label="particles")
    ax.set_ylabel("$E_k / E_{k0}$")
    ax = axes[1]
    ax.plot(tf, exact.decay(tf), "k-", lw=1.2, label="exact $F$")
    ax.plot(t, s["umax"] / exact.u0, "o", ms=4, mfc="none", label="particles")
    ax.set_ylabel("max |u| / U0")
    ax = axes[2]
    ax.plot(tf, exact.pressure_amplitude(tf), "k-", lw=1.2, label="exact at the centre")
    ax.plot(t, s["p_centre_exact"], "k--", lw=0.8, label="exact at the particle")
    ax.plot(t, s["p_centre"], "o", ms=4, mfc="none", label="particle nearest the centre")
    ax.plot(t, s["p_centre"] - s["p_mean"], "x", ms=4, label="same, minus mean pressure")
    ax.set_ylabel("p - p0 at the centre")
    for ax in axes:
        ax.set_xlabel("t")
        ax.legend(fontsize=7)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
