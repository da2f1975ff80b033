"""``blast_2d``: two-dimensional blast explosion, the cylindrical Tait shock tube (thesis §3.7.2,
Figs. 3.5-3.7; SPEC §12.1 V3).

Water (Tait EOS, thesis rho0 = 1000, c0 = 1466, gamma = 7, p0 = 0) at rest fills the disc
``r <= radius`` (R = 0.1 m) with ``rho = rho_in`` (1100) for ``r <= r_interface`` (0.05 m) and
``rho_out`` (1000) outside; an outgoing shock and an ingoing rarefaction develop (t_end = 1e-5 s).

Particles.  The fluid particles come from :func:`mlsph_jax.cases.layouts.disc_layout`
(``case.layout`` = rings, delaunay or perturbed, spacing ``case.dx``; N ~ pi R^2 / dx^2).
Far field (SPEC §13.7 item 40): concentric rings of FROZEN particles at rest with
``rho = rho_out`` fill the band ``R < r < R + n_frozen dr``, ring spacing ``dr = R / round(R /
dx)`` (the continuation of the ``rings`` layout), ``n_frozen = ceil(kappa beta sqrt(max_i V_i)
/ dr) + 1`` with the largest fluid volume (the Delaunay boundary triangles reach ~2 dx^2), so
every fluid particle near ``r = R`` has a complete stencil (radius ``kappa h_i``, ``h_i = beta
sqrt(V_i)``).  They act as neighbours but are never updated.  The physical waves do not reach
them before ``t_end`` (the config check bounds the signal speed: ``r_interface + c_max (1 +
ln(rho_max / rho_min)) t_end < R``, here 0.071 m < 0.1 m); the numerical precursor of the shock
does, faintly (|rho - rho_out| ~ 1e-4 near r = R at t_end for dx = 2e-3), so the total mass
(fluid + far field) drifts by ~1e-10 relative; away from the far field the fluxes conserve it to
round-off.

Metrics (fluid particles only, ``rho_i`` from :func:`~mlsph_jax.eos.to_primitive`, ``r_i =
|x_i|`` at the final time), against the cylindrical (``alpha = 1``) 1-D radial finite-volume
reference ``rho_ref`` of :func:`mlsph_jax.reference.radial.radial_tait_reference` at the same
time on ``case.reference_cells`` cells:

* ``l1_rho_radial`` = sum_i V_i |rho_i - rho_ref(r_i)| / (sum_i V_i (max rho_ref - min rho_ref));
* ``radial_spread`` — scatter of the density among particles at (nearly) equal radius, relative
  to the shock jump: particles are binned in radius with bin width ``dx`` (bin ``floor(r_i /
  dx)``); ``d_i = rho_i - mean_{bin(i)} rho``;
  ``radial_spread = sqrt(mean_i d_i^2) / J`` over all fluid particles, with the shock jump
  ``J = max_{r > r_interface} rho_ref - rho_out``;
* ``radial_spread_max`` = max over bins of the (population) standard deviation of rho in the
  bin, divided by ``J``;
* ``radial_spread_linear`` — as ``radial_spread`` with ``d_i`` the residual of the per-bin
  least-squares line ``rho ~ a + b r`` instead of the bin mean (``b = 0`` if the bin's particles
  share one radius, as on the rings layout).
* ``overshoot`` — the 1-D tubes' measure (:func:`mlsph_jax.cases.riemann_1d.new_extremum`)
  applied to the radial profile: the density averaged over the same bins of width ``dx``,
  placed at the bins' mean radius; its largest new extremum beyond the reference's extremum
  within ``+-5 dx`` (``OVERSHOOT_WINDOW``), relative to the reference's density range.  It picks
  up the start-up bump the scheme leaves at the initial interface (docs/validation.md).

A radially symmetric solution has zero ``radial_spread`` up to the radial variation inside one
bin (about ``|d rho/dr| dx / sqrt(12)`` where the profile is steep: at the shock and across the
rarefaction), so it is an upper bound on the asymmetry of the solution;
``radial_spread_linear`` removes that gradient term to first order and is the sharper measure
of asymmetry on the irregular layouts.  The metrics also report ``rho_max``/``rho_ref_shock``
(largest particle density and the reference's post-shock peak, outer half) and
``n_fluid``/``n_frozen``.  The reference uses the EOS constants of the config, not the run's
:class:`~mlsph_jax.state.Params`.
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
from ..reference.radial import RadialSolution, radial_tait_reference
from ..schema import Key, join_problems, show
from ..simulation import Problem
from ..state import Domain, Kind, Particles, make_particles
from .base import register_case
from .common import params_from_config, scheme_from_config
from .layouts import LAYOUTS, disc_layout, ring_sizes, rings
from .riemann_1d import OVERSHOOT_WINDOW, new_extremum

# --- config schema: the [case] keys and cross-checks (mlsph_jax.config validates with them) ---------

def check_blast_2d(cfg: dict) -> None:
    """`eos.kind` must be tait (the radial reference solves the barotropic Tait equations).
    0 < `r_interface` < `radius`; `dx` <= `r_interface`/5 (at least five spacings across the
    high-density region); `perturbation` is used by the perturbed layout only. The far field
    beyond `radius` is frozen, so the waves must stay inside the disc: `r_interface` +
    s_max `time.t_end` < `radius`, with the signal-speed bound s_max = c_max (1 + ln(rho_max /
    rho_min)) (largest sound speed times one plus the largest possible |u*|/c_max of a Tait
    Riemann problem from rest)."""
    c, eos = cfg["case"], cfg["eos"]
    problems = []
    if eos["kind"] != "tait":
        problems.append(f"invalid eos.kind={show(eos['kind'])}: case blast_2d compares with a "
                        "radial reference for the barotropic Tait EOS; allowed: \"tait\"")
    radius, r_if, dx = c["radius"], c["r_interface"], c["dx"]
    if not r_if < radius:
        problems.append(f"invalid case.r_interface={show(r_if)}: outside the disc; allowed: a "
                        f"float in (0.0, case.radius={show(radius)})")
    elif not dx <= r_if / 5.0:
        problems.append(f"invalid case.dx={show(dx)}: too coarse; allowed: a float in "
                        f"(0.0, case.r_interface/5 = {show(r_if / 5.0)}]")
    elif eos["kind"] == "tait":
        rho_max, rho_min = max(c["rho_in"], c["rho_out"]), min(c["rho_in"], c["rho_out"])
        c_max = eos["c0"] * (rho_max / eos["rho0"]) ** (0.5 * (eos["gamma"] - 1.0))
        s_max = c_max * (1.0 + math.log(rho_max / rho_min))
        t_end = cfg["time"]["t_end"]
        if r_if + s_max * t_end >= radius:
            problems.append(f"invalid time.t_end={show(t_end)}: the waves may reach the frozen far "
                            f"field at case.radius={show(radius)} (signal-speed bound "
                            f"{s_max:.6g} m/s); allowed: t_end < "
                            f"{show((radius - r_if) / s_max)} s")
    if problems:
        raise ConfigError(join_problems(problems))


BLAST_2D_KEYS: dict[str, Key] = {
    "radius": Key(float, 0.1, minimum=0.0, exclusive_minimum=True, unit="m",
                  doc="radius R of the fluid disc (centred at the origin; frozen far field beyond)"),
    "r_interface": Key(float, 0.05, minimum=0.0, exclusive_minimum=True, unit="m",
                       doc="radius of the initial discontinuity"),
    "rho_in": Key(float, 1100.0, minimum=0.0, exclusive_minimum=True, unit="kg/m^3",
                  doc="density for r <= r_interface (fluid at rest)"),
    "rho_out": Key(float, 1000.0, minimum=0.0, exclusive_minimum=True, unit="kg/m^3",
                   doc="density for r > r_interface (fluid at rest)"),
    "layout": Key(str, "delaunay", choices=tuple(LAYOUTS),
                  doc="initial particles: concentric rings, Delaunay triangle barycentres, or "
                      "randomly perturbed Delaunay barycentres (thesis Fig. 3.5)"),
    "dx": Key(float, 2e-3, minimum=0.0, exclusive_minimum=True, unit="m",
              doc="particle spacing, N ~ pi R^2 / dx^2 (2e-3: ~7,800 particles, minutes on 2 "
                  "CPU cores); thesis resolution: 5.9e-4 (rings, ~90,000) and 6.5e-4 "
                  "(delaunay/perturbed, ~75,000)"),
    "perturbation": Key(float, 0.2, minimum=0.0, maximum=0.5,
                        doc="perturbed layout: random displacement of each particle within a "
                            "disc of radius perturbation * sqrt(V_i)"),
    "seed": Key(int, 0, minimum=0, doc="random seed of the delaunay and perturbed layouts"),
    "reference_cells": Key(int, 4000, minimum=100,
                           doc="cells of the 1-D radial finite-volume reference on [0, radius]"),
}


def far_field_rings(radius: float, dx: float, n_rings: int) -> tuple[np.ndarray, np.ndarray]:
    """``n_rings`` concentric rings just outside the disc: rings ``k = n_r .. n_r + n_rings - 1``
    of the :func:`~mlsph_jax.cases.layouts.rings` layout of the larger disc of radius
    ``radius + n_rings dr`` (``n_r = round(radius/dx)``, ``dr = radius/n_r``), i.e. radii
    ``(k + 1/2) dr`` in ``(radius, radius + n_rings dr)``.  Returns ``(x[M, 2], vol[M])``."""
    n_r = max(1, round(radius / dx))
    dr = radius / n_r
    x, vol = rings((n_r + n_rings) * dr, dr)
    keep = np.hypot(x[:, 0], x[:, 1]) > radius
    return x[keep], vol[keep]


def reference(cfg: Mapping, t: float) -> RadialSolution:
    """Cylindrical radial Tait reference at time ``t`` (cached by the reference module)."""
    c, eos = cfg["case"], cfg["eos"]
    return radial_tait_reference(c["rho_in"], c["rho_out"], c["r_interface"], c["radius"], float(t),
                                 eos["rho0"], eos["c0"], eos["gamma"], eos["p0"], alpha=1,
                                 n=c["reference_cells"])


def build(cfg: Mapping) -> Problem:
    c = cfg["case"]
    scheme = scheme_from_config(cfg)
    params = params_from_config(cfg)
    eos = get_eos(scheme.eos)
    radius, dx = c["radius"], c["dx"]
    xf, vf = disc_layout(c["layout"], radius, dx, seed=c["seed"], amplitude=c["perturbation"])
    dr = radius / max(1, round(radius / dx))
    reach = scheme.support * scheme.beta * math.sqrt(float(vf.max()))  # largest fluid support radius
    n_frozen_rings = math.ceil(reach / dr) + 1
    xo, vo = far_field_rings(radius, dx, n_frozen_rings)
    x = np.concatenate([xf, xo])
    vol = np.concatenate([vf, vo])
    kind = np.concatenate([np.full(len(xf), int(Kind.FLUID)), np.full(len(xo), int(Kind.FROZEN))])
    r = np.hypot(x[:, 0], x[:, 1])
    rho = np.where((r <= c["r_interface"]) & (kind == int(Kind.FLUID)), c["rho_in"], c["rho_out"])
    U = to_conservative(jnp.asarray(rho), jnp.zeros((len(x), 2)), None, eos, params)
    particles = make_particles(x, vol, U, kind=kind,
                               ppd=np.full(len(x), scheme.reconstruction_degree))
    half = float(r.max()) + 3.0 * dx
    domain = Domain((-half, -half), (half, half), (False, False))

    def metrics(p: Particles, t: float, P) -> dict[str, float]:
        return radial_metrics(p, t, P, reference(cfg, t), scheme.eos, dx, c["r_interface"],
                              c["rho_out"])

    def plot(out: Path, p: Particles, t: float, P) -> None:
        plot_radial(out, p, t, P, reference(cfg, t), scheme.eos, title=_title(cfg, len(xf)))

    return Problem("blast_2d", particles, params, scheme, domain, cfg["time"]["t_end"], metrics, plot,
                   config=cfg, description=_title(cfg, len(xf)))


#: Upper bound of sqrt(max_i V_i) / dr on the ``rings`` layout: annulus k holds
#: rint(pi (2k + 1)) particles of area pi (2k + 1) dr^2 / rint(pi (2k + 1)), largest at k = 0, 1
#: (pi / 3 dr^2).  On the Delaunay layouts (``delaunay``, ``perturbed``, same volumes) the bound
#: used is 2 dx: the largest triangle sits in the boundary band; measured at most 1.63 dx
#: (dx = 4e-4 .. 8e-3, seeds 0-2; 1.63 at dx = 6.5e-4, 1.41-1.49 at dx >= 1e-3).
RINGS_SQRT_VMAX = math.sqrt(math.pi / 3.0)
DELAUNAY_SQRT_VMAX = 2.0


def particle_count(cfg: Mapping) -> tuple[int, tuple[str, ...]]:
    """An upper bound of :func:`build`'s particle count without building a layout: the fluid
    disc (``rings``: sum_k rint(2 pi (k + 1/2)) over its n_r = round(R / dx) annuli, exact; the
    Delaunay layouts: pi R^2 / dx^2, measured 0.2-5.5 % above the triangle count) plus the frozen
    rings counted exactly as :func:`far_field_rings` lays them, ceil(kappa beta sqrt(V_max) / dr) + 1
    of them with sqrt(V_max) bounded by :data:`RINGS_SQRT_VMAX` dr or :data:`DELAUNAY_SQRT_VMAX`
    dx (tests/test_particle_limit.py)."""
    c, s = cfg["case"], scheme_from_config(cfg)
    radius, dx = c["radius"], c["dx"]
    n_r = max(1, round(radius / dx))
    dr = radius / n_r

    def count(k0, k1):   # particles of the rings layout's annuli k0 .. k1 - 1
        return int(ring_sizes(np.arange(k0, k1)).sum())

    if c["layout"] == "rings":
        fluid, sqrt_vmax = count(0, n_r), RINGS_SQRT_VMAX * dr
    else:
        fluid, sqrt_vmax = math.ceil(math.pi * radius ** 2 / dx ** 2), DELAUNAY_SQRT_VMAX * dx
    n_frozen = math.ceil(s.support * s.beta * sqrt_vmax * (1 + 1e-12) / dr) + 1
    return fluid + count(n_r, n_r + n_frozen), ("case.radius", "case.dx", "case.layout")


BLAST_2D = register_case(
    "blast_2d", BLAST_2D_KEYS, build, check=check_blast_2d, dim=2, particle_count=particle_count,
    defaults_override={"scheme.frame": "lagrangian", "eos.kind": "tait", "eos.rho0": 1000.0,
                       "eos.c0": 1466.0, "time.t_end": 1e-5},
    doc="Two-dimensional blast explosion (cylindrical Tait shock tube, thesis §3.7.2): a disc "
        "of radius `radius` at rest, density `rho_in` inside `r_interface` and `rho_out` "
        "outside, compared with a 1-D radial finite-volume reference.")


def _title(cfg, n_fluid: int) -> str:
    s, c = cfg["scheme"], cfg["case"]
    return (f"blast_2d ({c['layout']}, dx={c['dx']:g}, {n_fluid} particles): {s['method']}, "
            f"reconstruction degree {s['reconstruction_degree']}, limiter {s['limiter']}, {s['frame']}")


def radial_fields(p: Particles, P, eos_kind: str):
    """Radius, volume and density of the fluid particles."""
    fluid = np.asarray(p.kind) == int(Kind.FLUID)
    pr = to_primitive(p.U, get_eos(eos_kind), P)
    x = np.asarray(p.x)[fluid]
    return np.hypot(x[:, 0], x[:, 1]), np.asarray(p.vol)[fluid], np.asarray(pr.rho)[fluid], x


def radial_bins(r: np.ndarray, width: float) -> tuple[np.ndarray, np.ndarray]:
    """``(inv, cnt)``: the radial bin ``floor(r / width)`` of each particle as an index into the
    occupied bins, and each occupied bin's particle count (the bins of the spread and overshoot)."""
    _, inv, cnt = np.unique(np.floor(r / width).astype(np.int64), return_inverse=True, return_counts=True)
    return inv, cnt


def radial_spread(r: np.ndarray, rho: np.ndarray, width: float) -> tuple[float, float, float]:
    """``(rms, max, rms_linear)`` of the within-bin density scatter (module docstring), not
    normalised: bins ``floor(r / width)``; rms over all particles of ``rho_i - mean_bin(rho)``;
    the largest bin standard deviation; rms of the residuals of the per-bin least-squares line
    ``rho ~ a + b r`` (``b = 0`` in a bin whose particles share one radius)."""
    inv, cnt = radial_bins(r, width)

    def bin_mean(v):
        return (np.bincount(inv, weights=v) / cnt)[inv]

    d = rho - bin_mean(rho)
    var_bin = np.bincount(inv, weights=d * d) / cnt
    dr = r - bin_mean(r)
    srr = bin_mean(dr * dr)
    slope = np.where(srr > (1e-9 * width) ** 2, bin_mean(dr * d) / np.maximum(srr, 1e-300), 0.0)
    lin = d - slope * dr
    return (float(np.sqrt(np.mean(d * d))), float(np.sqrt(var_bin.max())),
            float(np.sqrt(np.mean(lin * lin))))


def radial_overshoot(r: np.ndarray, rho: np.ndarray, ref: RadialSolution, dx: float) -> float:
    """``overshoot`` (module docstring): new extrema of the bin-averaged radial density profile
    beyond the reference's extremum within ``OVERSHOOT_WINDOW * dx``, relative to its range."""
    inv, cnt = radial_bins(r, dx)
    rb, rhob = np.bincount(inv, weights=r) / cnt, np.bincount(inv, weights=rho) / cnt
    rng = float(ref.rho.max() - ref.rho.min())
    return new_extremum(rb, rhob, lambda xs: ref(np.abs(xs))["rho"], OVERSHOOT_WINDOW * dx) / max(rng, 1e-300)


def radial_metrics(p: Particles, t: float, P, ref: RadialSolution, eos_kind: str, dx: float,
                   r_interface: float, rho_out: float) -> dict[str, float]:
    """``l1_rho_radial``, ``radial_spread``, ``radial_spread_max``, ``radial_spread_linear``,
    ``overshoot`` (module docstring)."""
    r, vol, rho, _ = radial_fields(p, P, eos_kind)
    rng = float(ref.rho.max() - ref.rho.min())
    ref_rho = ref(r)["rho"]
    l1 = float(np.sum(vol * np.abs(rho - ref_rho)) / (np.sum(vol) * max(rng, 1e-300)))
    shock = float(ref.rho[ref.r > r_interface].max())
    jump = max(shock - rho_out, 1e-300)
    rms, worst, rms_lin = radial_spread(r, rho, dx)
    return {"l1_rho_radial": l1, "radial_spread": rms / jump, "radial_spread_max": worst / jump,
            "radial_spread_linear": rms_lin / jump, "overshoot": radial_overshoot(r, rho, ref, dx),
            "rho_max": float(rho.max()), "rho_ref_shock": shock,
            "n_fluid": int(rho.size), "n_frozen": int(np.sum(np.asarray(p.kind) == int(Kind.FROZEN)))}


def plot_radial(out: Path, p: Particles, t: float, P, ref: RadialSolution, eos_kind: str,
                title: str = "") -> None:
    """``density_vs_radius.png`` (all fluid particles vs the reference) and ``density_field.png``
    (particles coloured by density)."""


    r, _, rho, x = radial_fields(p, P, eos_kind)
    head = title.replace(": ", "\n", 1) + f", t={t:.4g} s"
    fig, ax = subplots(figsize=(6.4, 4.2))
    ax.plot(r, rho, ".", ms=1.5, color="tab:blue", alpha=0.6, label=f"particles ({r.size})")
    ax.plot(ref.r, ref.rho, "k-", lw=1.2, label="radial reference")
    ax.set_xlabel("r [m]")
    ax.set_ylabel("density [kg/m^3]")
    ax.set_xlim(0.0, float(ref.r[-1]))
    ax.legend(fontsize=8, markerscale=4)
    ax.set_title(head, fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "density_vs_radius.png", dpi=130)

    fig, ax = subplots(figsize=(5.6, 4.8))
    ms = max(0.3, min(6.0, 2.0e4 / max(r.size, 1)))
    sc = ax.scatter(x[:, 0], x[:, 1], c=rho, s=ms, cmap="viridis", linewidths=0)
    fig.colorbar(sc, ax=ax, label="density [kg/m^3]")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(head, fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "density_field.png", dpi=130)
