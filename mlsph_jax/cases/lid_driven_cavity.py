"""``lid_driven_cavity``: two-dimensional lid-driven cavity against Ghia et al. (1982) (thesis
§3.7.5, Figs. 3.20-3.23; SPEC §12.1 V7, §8.3).

Geometry.  The square [0, L]^2 (``case.length``) filled with ``n`` x ``n`` fluid particles on a
square lattice (dx = L/n, x = (i + 1/2) dx, V = dx^2; thesis: n = 100), Eulerian (fixed
particles).  Four mirror-ghost walls (:mod:`mlsph_jax.boundaries`, thesis eq. 3.22): the lid
y = L moves at (``u_lid``, 0), the other three are fixed (``boundary.wall_velocity`` = [[0, 0],
[u_lid, 0], [0, 0], [0, 0]] for bottom, lid, left, right).  Fluid particles within the support
radius kappa beta dx of a wall are mirrored (3 layers for mlsph_ale); particles near two walls
also get a corner ghost mirrored across both (thesis Fig. 3.21, Szewc et al. 2012) whose
velocity makes the vertex velocity the average of the four particles, with vertex velocity
(u_W1 + u_W2)/2 (half the lid speed at the two lid corners, zero at the bottom corners; SPEC
§8.3 default), i.e. u_GC = u_F.

``case.walls = "boundary_integral"`` replaces the ghosts by the boundary term of thesis eq. 4.24
(:mod:`mlsph_jax.wall_integral`, the same path as the channel flows; docs/architecture.md
decisions 54, 60, 61): four segments spanning the cavity corner to corner, n midpoint-rule
points each (lengths dx, the wall's own normal and velocity; the lid's points move at u_lid up to
dx/2 from the corners).  No quadrature point sits on a corner, so no vertex velocity is needed:
the lid-corner singularity is the jump between the lid's last point and the side wall's first.
The domain is then the cavity itself (nothing lies outside it).

Fluid.  Tait with rho0 = 1, c0 = 10 u_lid, gamma = 7, p0 = 0 (SPEC §13 item 33; the thesis
does not restate them; Mach 0.1), at rest with rho = rho0 at t = 0.  The viscosity follows from
``case.re``: mu = rho0 u_lid L / Re (physics.mu is set to it; the resolved config written to
the output records the value used).

Steady state.  The thesis runs to t = 500 s.  Here the run stops once the velocity field
changes by less than ``case.steady_tol`` per unit time relative to its maximum between two
output times (``summary["steady_state"]``), or at ``time.t_end``.

Metrics (final state) and diagnostics (every output time).  Centre-line velocities are
interpolated from the particles (fluid and ghosts) by a local quadratic moving-least-squares
fit (:func:`mls_interpolate`: cubic-spline weight of radius 2h, h = 1.5 dx, basis 1, xi, eta,
xi^2, xi eta, eta^2 in coordinates scaled by h; the value of the fit at the point) at Ghia's
interior points (the wall points, where Ghia's values are the boundary conditions, and the
flagged misprint v(Re=400, x=0.9063) are left out; :mod:`mlsph_jax.reference.ghia`):

* ``ghia_u_max_abs_dev`` = max_k |u(L/2, y_k)/u_lid - u_Ghia(y_k)| (15 points);
* ``ghia_v_max_abs_dev`` = max_k |v(x_k, L/2)/u_lid - v_Ghia(x_k)| (15 points, 14 at Re = 400);
* ``ghia_u_rms_dev``, ``ghia_v_rms_dev``: the root-mean-square deviations at the same points;
* ``u_min_centerline``: the minimum of u/u_lid along x = L/2 (primary-vortex strength; Ghia:
  -0.2109 at Re = 100), sampled at 201 points;
* ``kinetic_energy`` = sum_i V_i rho_i |u_i|^2 / 2 / (rho0 u_lid^2 L^2).

The Ghia metrics are reported only when ``re`` is 100, 400 or 1000 (the tabulated values).
With ``steady_tol`` > 0 the time series holds ``velocity_change_rate``, the steady-state residual
(max |u(t) - u(t_prev)| / max |u(t)| / (t - t_prev) between consecutive outputs) that
``steady_tol`` is compared with, recorded by :class:`~mlsph_jax.simulation.Simulation` (so a
restarted run's series is the uninterrupted one's).

Resolution.  At Re = 100 the deviations from Ghia fall with refinement (max |u| / |v| deviation
0.070 / 0.067, 0.045 / 0.032, 0.034 / 0.019 at n = 24, 40, 50).  On coarse lattices the
scheme's numerical dissipation caps the effective Reynolds number at a few hundred (at n = 24-32
the Re = 400 and 1000 runs end close to the Re = 100 flow), so Re = 400 and 1000 need the
thesis resolution (n = 100) or finer.

Plots: ``centerlines.png`` (both centre-line profiles against Ghia, thesis Fig. 3.22) and
``velocity_field.png`` (speed contours with streamlines on a 101 x 101 grid interpolated with
``scipy.interpolate.griddata``, thesis Fig. 3.23).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from ..boundaries import Wall
from ..eos import get_eos, to_conservative, to_primitive
from ..errors import ConfigError
from ..plotting import subplots
from ..reference import ghia
from ..schema import Key, join_problems, show
from ..simulation import Problem
from ..state import Domain, Kind, Params, Particles, make_particles
from .base import register_case
from .channel_flows import lattice
from .common import (
    params_from_config,
    scheme_from_config,
    setup_walls,
    steady_tol_key,
    support_layers,
    walls_key,
    walls_problems,
)

# --- config schema: the [case] keys and cross-checks (mlsph_jax.config validates with them) ---------

def lid_driven_cavity_viscosity(cfg: Mapping) -> float:
    """Dynamic viscosity of a resolved ``lid_driven_cavity`` config: mu = rho0 u_lid length / re."""
    c = cfg["case"]
    return cfg["eos"]["rho0"] * c["u_lid"] * c["length"] / c["re"]


def check_lid_driven_cavity(cfg: dict) -> None:
    """`eos.kind` must be tait. The viscosity follows from `re`: mu = eos.rho0 `u_lid`
    `length` / `re`; physics.mu must be left at 0 (it is then set to that value) or equal it
    (relative difference <= 1e-9). `physics.body_force` must be empty. `scheme.frame` must be
    eulerian (the mirror ghosts are fixed at set-up, so the particles must not move; the
    boundary-integral walls are validated on fixed particles only). Boundary-integral walls
    (`walls`) need `scheme.method` = mlsph_ale."""
    c, eos, phys = cfg["case"], cfg["eos"], cfg["physics"]
    problems = []
    if eos["kind"] != "tait":
        problems.append(f"invalid eos.kind={show(eos['kind'])}: case lid_driven_cavity is a "
                        "weakly compressible Tait flow; allowed: \"tait\"")
    else:
        mu = lid_driven_cavity_viscosity(cfg)
        if phys["mu"] != 0.0 and abs(phys["mu"] - mu) > 1e-9 * mu:
            problems.append(f"invalid physics.mu={show(phys['mu'])}: case lid_driven_cavity derives "
                            f"the viscosity from case.re={show(c['re'])} (mu = eos.rho0 case.u_lid "
                            f"case.length / case.re = {mu:.10g}); allowed: 0 (derived) or "
                            f"{mu:.10g} — set case.re instead")
    if phys["body_force"]:
        problems.append(f"invalid physics.body_force={show(phys['body_force'])}: the lid-driven "
                        "cavity has no body force; allowed: []")
    problems += walls_problems(cfg)
    if cfg["scheme"]["frame"] != "eulerian":
        why = ("the cavity's mirror ghosts are fixed at set-up, so the particles must stay in place"
               if c["walls"] == "mirror_ghosts" else
               "the cavity with boundary-integral walls is validated on fixed particles only")
        problems.append(f"invalid scheme.frame={show(cfg['scheme']['frame'])}: {why}; allowed: \"eulerian\"")
    if problems:
        raise ConfigError(join_problems(problems))


LID_DRIVEN_CAVITY_KEYS: dict[str, Key] = {
    "n": Key(int, 40, minimum=8,
             doc="fluid particles per side (n^2 in total, square lattice, spacing length/n); "
                 "thesis: 100"),
    "length": Key(float, 1.0, minimum=0.0, exclusive_minimum=True, unit="m",
                  doc="side L of the square cavity [0, L]^2"),
    "u_lid": Key(float, 1.0, minimum=0.0, exclusive_minimum=True, unit="m/s",
                 doc="velocity of the lid (top wall y = L) along +x; the other walls are fixed"),
    "re": Key(float, 100.0, minimum=0.0, exclusive_minimum=True,
              doc="Reynolds number Re = rho0 u_lid L / mu (sets physics.mu); Ghia et al. "
                  "(1982) centre-line data exist for 100, 400 and 1000"),
    "walls": walls_key("the four walls (boundary integral: decision 61 for the corners)"),
    "steady_tol": steady_tol_key(2e-3),
}


def run_config(cfg: Mapping) -> dict:
    """The resolved config with ``physics.mu`` set to rho0 u_lid L / Re (what the run uses)."""
    mu = lid_driven_cavity_viscosity(cfg)
    return {**cfg, "physics": {**cfg["physics"], "mu": mu}}


def build(cfg: Mapping) -> Problem:
    cfg = run_config(cfg)
    c = cfg["case"]
    scheme = scheme_from_config(cfg)
    base = params_from_config(cfg)
    L, n, u_lid = c["length"], c["n"], c["u_lid"]
    wall_velocity = jnp.asarray([[0.0, 0.0], [u_lid, 0.0], [0.0, 0.0], [0.0, 0.0]], jnp.float64)
    params = Params({**{k: base[k] for k in base}, "boundary.wall_velocity": wall_velocity})
    eos = get_eos(scheme.eos)
    dx = L / n
    x = lattice(n, n, dx)
    U = to_conservative(jnp.full(len(x), cfg["eos"]["rho0"]), jnp.zeros((len(x), 2)), None, eos, params)
    pf = make_particles(x, np.full(len(x), dx * dx), U, ppd=np.full(len(x), scheme.reconstruction_degree))
    band = scheme.support * scheme.beta * dx
    walls = [Wall(1, 0.0, 1), Wall(1, L, -1), Wall(0, 0.0, 1), Wall(0, L, -1)]
    # the box holds the ghosts; without them it is the cavity itself, which the boundary-integral
    # walls span corner to corner (decision 61)
    pad = band + dx if c["walls"] == "mirror_ghosts" else 0.0
    domain = Domain((-pad, -pad), (L + pad, L + pad), (False, False))
    particles, boundary = setup_walls(cfg, pf, walls, band, params, scheme, domain)
    re_table = ghia.table_reynolds(c["re"])

    def metrics(p: Particles, t: float, P) -> dict[str, float]:
        return cavity_metrics(p, P, cfg, scheme, re_table)

    def diagnostics(p: Particles, t: float, P) -> dict[str, float]:
        """The metrics at every output (the run adds ``velocity_change_rate``, its steady-state
        residual, when ``steady_tol`` > 0)."""
        return metrics(p, t, P)

    def plot(out: Path, p: Particles, t: float, P) -> None:
        plot_centerlines(Path(out) / "centerlines.png", p, P, cfg, scheme, title=_title(cfg, t))
        plot_field(Path(out) / "velocity_field.png", p, P, cfg, scheme, title=_title(cfg, t))

    return Problem("lid_driven_cavity", particles, params, scheme, domain, cfg["time"]["t_end"], metrics, plot,
                   config=cfg, description=_title(cfg), boundary=boundary, diagnostics=diagnostics,
                   steady_tol=c["steady_tol"])


def particle_count(cfg: Mapping) -> tuple[int, tuple[str, ...]]:
    """n x n fluid particles, and with mirror ghosts the frame of ceil(kappa beta) layers around
    them (an upper bound: the ghosts are the fluid particles within the support of a wall)."""
    n, m = cfg["case"]["n"], support_layers(cfg)
    return (n + 2 * m) ** 2 if cfg["case"]["walls"] == "mirror_ghosts" else n * n, ("case.n", "case.walls")


LID_DRIVEN_CAVITY = register_case(
    "lid_driven_cavity", LID_DRIVEN_CAVITY_KEYS, build, check=check_lid_driven_cavity, dim=2,
    particle_count=particle_count,
    defaults_override={"eos.kind": "tait", "eos.rho0": 1.0, "eos.c0": 10.0, "time.t_end": 15.0,
                       "output.snapshots": 15},
    doc="Two-dimensional lid-driven cavity (thesis §3.7.5): fluid at rest in the square [0, "
        "`length`]^2, the lid moves at `u_lid`; mirror-ghost walls with corner ghosts (or the "
        "boundary integral of thesis eq. 4.24, `walls`), run to a steady state and compared with "
        "Ghia et al. (1982) along the centre lines.")


def _title(cfg, t: float | None = None) -> str:
    s, c = cfg["scheme"], cfg["case"]
    when = f", t={t:.4g} s" if t is not None else ""
    return (f"lid_driven_cavity (Re={c['re']:g}, {c['n']}x{c['n']} particles{when}): {s['method']}, "
            f"reconstruction degree {s['reconstruction_degree']}, {s['frame']}")


# --- interpolation ------------------------------------------------------------------------------

def _cubic_spline(q: np.ndarray) -> np.ndarray:
    return np.where(q < 1.0, 1.0 - 1.5 * q**2 + 0.75 * q**3, np.where(q < 2.0, 0.25 * (2.0 - q) ** 3, 0.0))


def mls_interpolate(xs: np.ndarray, fs: np.ndarray, xe: np.ndarray, h: float) -> np.ndarray:
    """Quadratic moving-least-squares value at the points ``xe[M, 2]`` of the data ``fs[N, ...]``
    at ``xs[N, 2]``: for each point the weighted least-squares fit of 1, xi, eta, xi^2, xi eta,
    eta^2 (xi = (x_j - x_e)/h) with cubic-spline weights of radius 2h, evaluated at xi = 0.
    Reproduces quadratic fields exactly.  Returns ``[M, ...]``."""
    from scipy.spatial import cKDTree

    xs = np.asarray(xs, float)
    fs = np.asarray(fs, float)
    xe = np.atleast_2d(np.asarray(xe, float))
    tree = cKDTree(xs)
    out = np.empty((len(xe),) + fs.shape[1:])
    for m, idx in enumerate(tree.query_ball_point(xe, 2.0 * h)):
        idx = np.asarray(idx, int)
        r = (xs[idx] - xe[m]) / h
        w = _cubic_spline(np.hypot(r[:, 0], r[:, 1]))
        P = np.stack([np.ones(len(idx)), r[:, 0], r[:, 1], r[:, 0] ** 2, r[:, 0] * r[:, 1], r[:, 1] ** 2], 1)
        M = P.T @ (w[:, None] * P)
        a = np.linalg.solve(M, P.T @ (w.reshape((-1,) + (1,) * (fs.ndim - 1)) * fs[idx]))
        out[m] = a[0]
    return out


def _velocity(p: Particles, P, scheme):
    pr = to_primitive(p.U, get_eos(scheme.eos), P)
    return np.asarray(p.x), np.asarray(pr.vel), np.asarray(pr.rho)


def centerlines(p: Particles, P, cfg: Mapping, scheme, y_pts, x_pts):
    """u/u_lid at (L/2, y_k L) and v/u_lid at (x_k L, L/2) by :func:`mls_interpolate` over all
    particles (fluid and ghosts); ``y_pts``/``x_pts`` in units of L."""
    c = cfg["case"]
    L, u_lid = c["length"], c["u_lid"]
    x, vel, _ = _velocity(p, P, scheme)
    h = scheme.beta * L / c["n"]
    y_pts, x_pts = np.asarray(y_pts, float), np.asarray(x_pts, float)
    pu = np.stack([np.full_like(y_pts, 0.5 * L), y_pts * L], 1)
    pv = np.stack([x_pts * L, np.full_like(x_pts, 0.5 * L)], 1)
    return mls_interpolate(x, vel[:, 0], pu, h) / u_lid, mls_interpolate(x, vel[:, 1], pv, h) / u_lid


def ghia_deviations(p: Particles, P, cfg: Mapping, scheme, re_table: int):
    """The signed centre-line deviations from Ghia's table ``re_table`` at its interior points
    (the points of the ``ghia_*`` metrics): ``((y_k, u(L/2, y_k)/u_lid - u_Ghia), (x_k,
    v(x_k, L/2)/u_lid - v_Ghia))``, positions in units of L."""
    yg, ug = ghia.centerline("u", re_table, include_walls=False)
    xg, vg = ghia.centerline("v", re_table, include_walls=False)
    un, vn = centerlines(p, P, cfg, scheme, yg, xg)
    return (yg, un - ug), (xg, vn - vg)


def worst_points(dev) -> dict[str, list[float]]:
    """Where the largest deviations sit: for :func:`ghia_deviations`' ``((y_k, du_k), (x_k,
    dv_k))``, ``{"u": [y, du], "v": [x, dv]}`` at the point of the largest |du| / |dv| (signed:
    > 0 means the run's velocity is above Ghia's)."""
    out = {}
    for name, (pts, d) in zip(("u", "v"), dev, strict=True):
        k = int(np.argmax(np.abs(d)))
        out[name] = [float(pts[k]), float(d[k])]
    return out


def cavity_metrics(p: Particles, P, cfg: Mapping, scheme, re_table: int | None) -> dict[str, float]:
    """Metrics of the module docstring."""
    c = cfg["case"]
    L, u_lid = c["length"], c["u_lid"]
    x, vel, rho = _velocity(p, P, scheme)
    fluid = np.asarray(p.kind) == int(Kind.FLUID)
    vol = np.asarray(p.vol)
    ke = float(np.sum((0.5 * vol * rho * np.sum(vel**2, axis=1))[fluid])
               / (cfg["eos"]["rho0"] * u_lid**2 * L**2))
    line = np.linspace(0.0, 1.0, 201)
    u_line, _ = centerlines(p, P, cfg, scheme, line, [])
    out = {"kinetic_energy": ke, "u_min_centerline": float(u_line.min())}
    if re_table is not None:
        (_, du), (_, dv) = ghia_deviations(p, P, cfg, scheme, re_table)
        out.update({"ghia_u_max_abs_dev": float(np.abs(du).max()), "ghia_v_max_abs_dev": float(np.abs(dv).max()),
                    "ghia_u_rms_dev": float(np.sqrt(np.mean(du**2))), "ghia_v_rms_dev": float(np.sqrt(np.mean(dv**2)))})
    return out


# --- plots ---------------------------------------------------------------------------------------

def plot_centerlines(path: Path, p: Particles, P, cfg: Mapping, scheme, title: str = "") -> None:
    """u(x = L/2, y) and v(x, y = L/2) against Ghia et al. (1982) (thesis Fig. 3.22)."""


    line = np.linspace(0.0, 1.0, 201)
    u_line, v_line = centerlines(p, P, cfg, scheme, line, line)
    re_table = ghia.table_reynolds(cfg["case"]["re"])
    fig, (a1, a2) = subplots(1, 2, figsize=(10, 4.4))
    a1.plot(u_line, line, "-", color="tab:blue", label="MLSPH-ALE (MLS fit)")
    a2.plot(line, v_line, "-", color="tab:blue", label="MLSPH-ALE (MLS fit)")
    if re_table is not None:
        yg, ug = ghia.centerline("u", re_table)
        xg, vg = ghia.centerline("v", re_table)
        a1.plot(ug, yg, "ks", ms=4, mfc="none", label=f"Ghia et al. 1982, Re={re_table}")
        a2.plot(xg, vg, "ks", ms=4, mfc="none", label=f"Ghia et al. 1982, Re={re_table}")
        for comp, rr, cc in ghia.MISPRINTS:
            if rr == re_table and comp == "v":
                xa, va = ghia.centerline("v", re_table, include_misprint=True)
                k = np.flatnonzero(np.isclose(xa, cc))
                a2.plot(xa[k], va[k], "rx", ms=6, label="misprint (excluded)")
    finish_centerline_figure(fig, a1, a2, title, path)


def finish_centerline_figure(fig, a1, a2, title: str, path: Path) -> None:
    """Labels, grid, legend and title of a centre-line figure (u along x = L/2 on ``a1``, v along
    y = L/2 on ``a2``), saved to ``path``."""
    a1.set_xlabel("u / u_lid")
    a1.set_ylabel("y / L")
    a1.set_title("u along x = L/2", fontsize=9)
    a2.set_xlabel("x / L")
    a2.set_ylabel("v / u_lid")
    a2.set_title("v along y = L/2", fontsize=9)
    for a in (a1, a2):
        a.grid(True, alpha=0.3)
        a.legend(fontsize=7)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def plot_field(path: Path, p: Particles, P, cfg: Mapping, scheme, title: str = "", grid: int = 101) -> None:
    """Speed contours with streamlines (thesis Fig. 3.23): the particle velocities (fluid and
    ghosts) interpolated linearly (``scipy.interpolate.griddata``) onto a ``grid`` x ``grid``
    mesh of the cavity."""

    from scipy.interpolate import griddata

    c = cfg["case"]
    L, u_lid = c["length"], c["u_lid"]
    x, vel, _ = _velocity(p, P, scheme)
    g = np.linspace(0.0, L, grid)
    X, Y = np.meshgrid(g, g)
    U = griddata(x, vel[:, 0], (X, Y), method="linear") / u_lid
    V = griddata(x, vel[:, 1], (X, Y), method="linear") / u_lid
    fig, ax = subplots(figsize=(6.0, 5.2))
    cs = ax.contourf(X / L, Y / L, np.hypot(U, V), levels=20, cmap="viridis")
    fig.colorbar(cs, ax=ax, label="|u| / u_lid")
    ax.streamplot(g / L, g / L, U, V, density=1.6, color="w", linewidth=0.6, arrowsize=0.6)
    ax.set_aspect("equal")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_xlabel("x / L")
    ax.set_ylabel("y / L")
    ax.set_title(title.replace(": ", "\n", 1), fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
