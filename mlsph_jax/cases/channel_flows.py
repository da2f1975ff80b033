"""``couette`` and ``poiseuille``: start-up of plane channel flows against their exact series
solutions (thesis §3.7.4, eq. 3.20-3.22, Figs. 3.15-3.19; SPEC §12.1 V5/V6).

Geometry (thesis Fig. 3.16).  Plates at y = 0 and y = L (``case.gap``), periodic along x.
``ny`` x ``nx`` fluid particles on a square lattice, dx = L / ny, x_i = (i + 1/2) dx, y_j =
(j + 1/2) dx, V = dx^2 (thesis: 40 across the gap, 20 along the period L/2, i.e. dx = L/40).
Both plates are mirror-ghost walls (:mod:`mlsph_jax.boundaries`, thesis eq. 3.22: u_G = 2 u_W -
u_F, density and volume copied): every fluid particle closer than ``kappa beta dx`` (the
support radius) to a wall is mirrored, i.e. 3 ghost layers for mlsph_ale (beta = 1.5), 4 for
sph_ale (beta = 2).  The wall velocities are the differentiable parameter
``boundary.wall_velocity`` = [[0, 0], [u_plate, 0]] (bottom, top).

Fluid.  Tait, rho0 = 1, c0 = 10 m/s, gamma = 7, p0 = 0 (thesis values; c0 = 10 u_max, Mach
0.1), nu = physics.mu / rho0 = 0.1 (Re = u_max L / nu = 10).  The fluid starts at rest with
rho = rho0.  Couette: the top plate moves at ``u_plate`` = 1 from t = 0.  Poiseuille: both
plates fixed, body force ``physics.body_force`` = [f_x, 0] = [0.8, 0] (peak velocity f_x L^2 /
(8 nu) = 1).  The two drives may be combined (Couette-Poiseuille); the exact solution is then
the superposition (:func:`mlsph_jax.reference.viscous.channel_startup`).  The flow is a
parallel shear flow, div u = 0, so the weakly compressible solution has uniform density and
the incompressible solution is its exact reference.

Diagnostics (every output time, ``timeseries`` of the summary) and metrics (final time), over
the fluid particles, with u_max = :func:`~mlsph_jax.reference.viscous.channel_u_max` (the
steady peak speed: u_plate, or f_x L^2 / (8 nu)):

* ``linf_u_error`` = max_i |u_i - u_exact(y_i, t)| / u_max;
* ``l2_u_error`` = sqrt(mean_i (u_i - u_exact(y_i, t))^2) / u_max (all particles have the same
  volume, so this is the volume-weighted L2 norm over the channel);
* ``max_abs_v`` = max_i |v_i| / u_max (zero for the exact solution);
* ``steady_linf_u_error`` = max_i |u_i - u_steady(y_i)| / u_max (distance to the final state).

Plots: ``profiles.png`` (u(y) of all fluid particles at up to seven output times read back
from ``fields.h5``, against the exact profiles) and the error history.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from ..boundaries import Wall, with_ghosts
from ..eos import get_eos, to_conservative, to_primitive
from ..reference.viscous import channel_startup, channel_steady, channel_u_max
from ..simulation import Problem
from ..state import Domain, Kind, Params, Particles, make_particles
from . import CASES
from .common import params_from_config, scheme_from_config


def drives(cfg: Mapping) -> dict[str, float]:
    """``{"u_plate", "f_x", "nu", "gap"}`` of a resolved channel config (the exact solution's
    parameters; nu = physics.mu / eos.rho0)."""
    c, phys = cfg["case"], cfg["physics"]
    bf = phys["body_force"]
    return {"u_plate": float(c["u_plate"]), "f_x": float(bf[0]) if bf else 0.0,
            "nu": float(phys["mu"]) / float(cfg["eos"]["rho0"]), "gap": float(c["gap"])}


def exact(cfg: Mapping, y, t: float) -> np.ndarray:
    """Exact u(y, t) of a resolved channel config."""
    return channel_startup(y, t, **drives(cfg))


def lattice(nx: int, ny: int, dx: float) -> np.ndarray:
    """Square lattice ``x = ((i + 1/2) dx, (j + 1/2) dx)``, i < nx, j < ny, shape [nx ny, 2]."""
    X, Y = np.meshgrid((np.arange(nx) + 0.5) * dx, (np.arange(ny) + 0.5) * dx, indexing="ij")
    return np.stack([X.ravel(), Y.ravel()], axis=1)


def _build(cfg: Mapping) -> Problem:
    c = cfg["case"]
    scheme = scheme_from_config(cfg)
    base = params_from_config(cfg)
    params = Params({**{k: base[k] for k in base},
                     "boundary.wall_velocity": jnp.asarray([[0.0, 0.0], [c["u_plate"], 0.0]], jnp.float64)})
    eos = get_eos(scheme.eos)
    gap, ny, nx = c["gap"], c["ny"], c["nx"]
    dx = gap / ny
    x = lattice(nx, ny, dx)
    n = len(x)
    U = to_conservative(jnp.full(n, cfg["eos"]["rho0"]), jnp.zeros((n, 2)), None, eos, params)
    pf = make_particles(x, np.full(n, dx * dx), U, ppd=np.full(n, scheme.reconstruction_degree))
    band = scheme.support * scheme.beta * dx   # support radius: every fluid stencil is complete
    particles, walls = with_ghosts(pf, [Wall(1, 0.0, 1), Wall(1, gap, -1)], band, params, scheme.eos)
    domain = Domain((0.0, -band - dx), (nx * dx, gap + band + dx), (True, False))
    d = drives(cfg)
    u_max = channel_u_max(**d)

    def errors(p: Particles, t: float, P) -> dict[str, float]:
        y, u, v = _fluid_velocity(p, P, scheme.eos)
        e = u - exact(cfg, y, t)
        return {"linf_u_error": float(np.abs(e).max() / u_max),
                "l2_u_error": float(np.sqrt(np.mean(e * e)) / u_max),
                "max_abs_v": float(np.abs(v).max() / u_max),
                "steady_linf_u_error": float(np.abs(u - channel_steady(y, **d)).max() / u_max)}

    def plot(out: Path, p: Particles, t: float, P) -> None:
        plot_profiles(out, cfg, title=_title(cfg))

    return Problem(c["name"], particles, params, scheme, domain, cfg["time"]["t_end"], errors, plot,
                   config=cfg, description=_title(cfg), boundary=walls, diagnostics=errors)


@CASES.register("couette")
def build_couette(cfg: Mapping) -> Problem:
    return _build(cfg)


@CASES.register("poiseuille")
def build_poiseuille(cfg: Mapping) -> Problem:
    return _build(cfg)


def _title(cfg) -> str:
    s, c = cfg["scheme"], cfg["case"]
    d = drives(cfg)
    re = channel_u_max(**d) * d["gap"] / d["nu"]
    return (f"{c['name']} (Re={re:.4g}, {c['ny']}x{c['nx']} particles): {s['method']}, "
            f"reconstruction degree {s['reconstruction_degree']}, {s['frame']}")


def _fluid_velocity(p: Particles, P, eos_kind: str):
    fluid = np.asarray(p.kind) == int(Kind.FLUID)
    vel = np.asarray(to_primitive(p.U, get_eos(eos_kind), P).vel)[fluid]
    return np.asarray(p.x)[fluid, 1], vel[:, 0], vel[:, 1]


def pick_times(times, k: int = 7) -> list[int]:
    """Indices of up to ``k`` snapshot times spread roughly logarithmically over (0, t_end]
    (the start-up is fast, the approach to the steady state slow); the last one always."""
    times = np.asarray(times, float)
    pos = np.flatnonzero(times > 0)
    if pos.size <= k:
        return pos.tolist()
    targets = np.geomspace(times[pos[0]], times[pos[-1]], k)
    idx = sorted({int(pos[np.argmin(np.abs(np.log(times[pos] / tt)))]) for tt in targets})
    return idx


def plot_profiles(out: Path, cfg: Mapping, title: str = "", fname: str = "profiles.png") -> None:
    """``profiles.png``: u(y) of every fluid particle at up to seven output times (read back
    from ``fields.h5``) with the exact profiles, and the normalised L-infinity error history."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..io import read_snapshots

    snaps = read_snapshots(out)
    d = drives(cfg)
    u_max = channel_u_max(**d)
    yf = np.linspace(0.0, d["gap"], 401)
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(10.5, 4.2))
    colors = plt.cm.viridis(np.linspace(0.0, 0.9, 7))
    for ci, i in enumerate(pick_times([t for t, _ in snaps])):
        t, f = snaps[i]
        fl = f["kind"] == int(Kind.FLUID)
        y, u = f["x"][fl, 1], f["vel"][fl, 0]
        col = colors[ci % len(colors)]
        ax.plot(exact(cfg, yf, t), yf, "-", color=col, lw=1.1)
        ax.plot(u, y, "o", ms=2.5, mfc="none", color=col, label=f"t = {t:.3g}")
    ax.plot([], [], "k-", lw=1.1, label="exact")
    ax.set_xlabel("u [m/s]")
    ax.set_ylabel("y [m]")
    ax.legend(fontsize=7, loc="best")
    ts, errs = [], []
    for t, f in snaps:
        if t > 0:
            fl = f["kind"] == int(Kind.FLUID)
            ts.append(t)
            errs.append(np.abs(f["vel"][fl, 0] - exact(cfg, f["x"][fl, 1], t)).max() / u_max)
    ax2.semilogy(ts, errs, "o-", ms=3)
    ax2.set_xlabel("t [s]")
    ax2.set_ylabel("max |u - u_exact| / u_max")
    ax2.grid(True, which="both", alpha=0.3)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(Path(out) / fname, dpi=120)
    plt.close(fig)
