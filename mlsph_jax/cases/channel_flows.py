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

Open channel (``case.inlet`` = U != 0; issue 17 item 3).  Instead of periodicity along x, an
inlet at x = 0 and an outlet at x = nx dx: ``ceil(kappa beta) + 1`` columns of FROZEN particles
beyond each end hold the ``inflow_outflow`` far field of :mod:`mlsph_jax.far_field` (set every
stage): at the inlet the parabolic profile u = 4 U y (L - y) / L^2 with the interior's density,
at the outlet the interior's velocity with rho0 (pressure p0).  The fluid starts at rest and
the inflow drives it; no body force.  The steady state is plane Poiseuille flow with peak U,
i.e. the body-force solution with the equivalent f_x = 8 nu U / L^2, now carried by the pressure
gradient dp/dx = -rho0 f_x; the errors below compare with that steady profile at every time, and
``pressure_gradient_error`` = |slope of p(x) over the fluid - (-rho0 f_x)| / (rho0 f_x) (least
squares over the particles of the middle half of the channel).

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

from ..boundaries import Wall
from ..config import effective_beta
from ..eos import get_eos, to_conservative, to_primitive
from ..errors import ConfigError
from ..far_field import FAR_FIELDS, with_far_field
from ..kernels import get_kernel
from ..plotting import colormap, subplots
from ..reference.viscous import channel_startup, channel_steady, channel_u_max
from ..schema import Key, join_problems, show
from ..simulation import Problem
from ..state import Domain, Kind, Params, Particles, make_particles
from .base import register_case
from .common import params_from_config, scheme_from_config, setup_walls, support_layers, walls_key, walls_problems

# --- config schema: the [case] keys and cross-checks (mlsph_jax.config validates with them) ---------

def check_channel(cfg: dict) -> None:
    """`eos.kind` must be tait and physics.mu > 0 (the exact start-up solution has nu =
    physics.mu / eos.rho0). `physics.body_force` must be empty or [f_x, 0.0] (a force along the
    plates; a wall-normal force would need a hydrostatic wall treatment). The flow must be
    driven: `u_plate` != 0 or f_x != 0. Boundary-integral walls (`walls`) need `scheme.method`
    = mlsph_ale. The period `nx` dx must exceed the kernel support
    diameter 2 kappa beta dx (minimum-image neighbour search), i.e. `nx` > 2 kappa beta (6 for
    mlsph_ale with the cubic spline, 8 for sph_ale)."""
    c, eos, phys = cfg["case"], cfg["eos"], cfg["physics"]
    name = c["name"]
    problems = []
    if eos["kind"] != "tait":
        problems.append(f"invalid eos.kind={show(eos['kind'])}: case {name} compares with the "
                        "incompressible start-up solution for the weakly compressible Tait fluid; "
                        "allowed: \"tait\"")
    if not phys["mu"] > 0.0:
        problems.append(f"invalid physics.mu={show(phys['mu'])}: case {name} is a viscous flow; "
                        "allowed: a float > 0 (nu = mu / eos.rho0; thesis: 0.1)")
    bf = phys["body_force"]
    fx = bf[0] if bf else 0.0
    if bf and bf[1] != 0.0:
        problems.append(f"invalid physics.body_force={show(bf)}: case {name} takes a force along "
                        "the plates only; allowed: [] or [f_x, 0.0]")
    if c["inlet"] != 0.0:
        if fx != 0.0 or c["u_plate"] != 0.0:
            problems.append(f"invalid case.inlet={show(c['inlet'])} with physics.body_force={show(bf)} and "
                            f"case.u_plate={show(c['u_plate'])}: the open channel is driven by its inflow alone; "
                            "allowed: physics.body_force = [] (or [0.0, 0.0]) and case.u_plate = 0 with an inlet")
        if cfg["scheme"]["frame"] != "eulerian":
            problems.append(f"invalid scheme.frame={show(cfg['scheme']['frame'])} with case.inlet={show(c['inlet'])}: "
                            "the inlet and outlet columns are paired with fixed fluid particles at set-up; "
                            "allowed: \"eulerian\" (or case.inlet = 0, periodic)")
        if c["walls"] != "mirror_ghosts":
            problems.append(f"invalid case.walls={show(c['walls'])} with case.inlet={show(c['inlet'])}: the open "
                            "channel's far-field columns are built for mirror-ghost plates; allowed: "
                            "\"mirror_ghosts\" (or case.inlet = 0, periodic)")
    elif c["u_plate"] == 0.0 and fx == 0.0:
        problems.append(f"invalid case.u_plate={show(c['u_plate'])} with physics.body_force="
                        f"{show(bf)}: nothing drives the flow; allowed: u_plate != 0 (Couette) "
                        "or physics.body_force = [f_x, 0.0] with f_x != 0 (Poiseuille), or case.inlet != 0 "
                        "(an open channel)")
    problems += walls_problems(cfg)
    reach = 2.0 * get_kernel(cfg["scheme"]["kernel"]).support * effective_beta(cfg["scheme"])
    if not c["nx"] > reach:
        problems.append(f"invalid case.nx={c['nx']}: the period nx dx must exceed the kernel "
                        f"support diameter {reach:g} dx; allowed: an int > {reach:g}")
    if problems:
        raise ConfigError(join_problems(problems))


def _channel_keys(u_plate: float) -> dict[str, Key]:
    return {
        "gap": Key(float, 1.0, minimum=0.0, exclusive_minimum=True, unit="m",
                   doc="distance L between the plates (walls at y = 0 and y = L); thesis: 1"),
        "ny": Key(int, 40, minimum=4,
                  doc="fluid particles across the gap (square lattice, spacing dx = gap/ny); "
                      "thesis: 40"),
        "nx": Key(int, 20, minimum=1,
                  doc="fluid particles along the plates (periodic length nx dx); thesis: 20 "
                      "(period L/2)"),
        "u_plate": Key(float, u_plate, unit="m/s",
                       doc="velocity of the top plate (y = L) along x, switched on at t = 0 "
                           "(the bottom plate is fixed); thesis Couette: 1"),
        "walls": walls_key("both plates"),
        "inlet": Key(float, 0.0, minimum=0.0, unit="m/s",
                     doc="0: periodic along the plates; U != 0: an open channel, parabolic inflow of peak U at "
                         "x = 0 and a pressure outlet at x = nx dx (case.far_field \"inflow_outflow\" columns; "
                         "no body force); the steady state is Poiseuille flow with peak U"),
    }


def drives(cfg: Mapping) -> dict[str, float]:
    """``{"u_plate", "f_x", "nu", "gap"}`` of a resolved channel config (the exact solution's
    parameters; nu = physics.mu / eos.rho0)."""
    c, phys = cfg["case"], cfg["physics"]
    bf = phys["body_force"]
    nu = float(phys["mu"]) / float(cfg["eos"]["rho0"])
    gap = float(c["gap"])
    if c["inlet"] != 0.0:   # the open channel: the pressure gradient of the inflow's steady state
        return {"u_plate": 0.0, "f_x": 8.0 * nu * float(c["inlet"]) / gap ** 2, "nu": nu, "gap": gap}
    return {"u_plate": float(c["u_plate"]), "f_x": float(bf[0]) if bf else 0.0, "nu": nu, "gap": gap}


def exact(cfg: Mapping, y, t: float) -> np.ndarray:
    """Exact u(y, t) of a resolved channel config (the open channel: its steady profile)."""
    if cfg["case"]["inlet"] != 0.0:
        return channel_steady(y, **drives(cfg))
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
    band = scheme.support * scheme.beta * dx   # support radius: every fluid stencil is complete
    open_ = c["inlet"] != 0.0
    n_end = int(np.ceil(scheme.support * scheme.beta)) + 1 if open_ else 0   # frozen columns per end
    x = lattice(nx + 2 * n_end, ny, dx) - np.asarray([n_end * dx, 0.0])
    kind = np.where((x[:, 0] < 0.0) | (x[:, 0] > nx * dx), int(Kind.FROZEN), int(Kind.FLUID))
    n = len(x)
    U = to_conservative(jnp.full(n, cfg["eos"]["rho0"]), jnp.zeros((n, 2)), None, eos, params)
    pf = make_particles(x, np.full(n, dx * dx), U, kind=kind, ppd=np.full(n, scheme.reconstruction_degree))
    plates = [Wall(1, 0.0, 1), Wall(1, gap, -1)]
    pad = (n_end + 2) * dx if open_ else 0.0
    domain = Domain((-pad, -band - dx), (nx * dx + pad, gap + band + dx), (not open_, False))
    particles, walls = setup_walls(cfg, pf, plates, band, params, scheme, domain)
    d = drives(cfg)
    if open_:
        rho0, u_in = float(cfg["eos"]["rho0"]), float(c["inlet"])

        def stream(xf, P):
            """The inflow profile and the outlet's rest density (far_field reference)."""
            y = xf[:, 1]
            u = 4.0 * u_in * y * (gap - y) / gap ** 2
            return jnp.full(len(xf), rho0), jnp.stack([u, jnp.zeros_like(u)], axis=1), None

        far = FAR_FIELDS.get("inflow_outflow", "case.inlet").setup(particles, scheme.eos, stream)
        walls = with_far_field(walls, far)
    u_max = channel_u_max(**d)

    def errors(p: Particles, t: float, P) -> dict[str, float]:
        y, u, v = _fluid_velocity(p, P, scheme.eos)
        e = u - exact(cfg, y, t)
        return {"linf_u_error": float(np.abs(e).max() / u_max),
                "l2_u_error": float(np.sqrt(np.mean(e * e)) / u_max),
                "max_abs_v": float(np.abs(v).max() / u_max),
                "steady_linf_u_error": float(np.abs(u - channel_steady(y, **d)).max() / u_max),
                **({"pressure_gradient_error": _pressure_gradient_error(p, P, scheme.eos, nx * dx, d)} if open_
                   else {})}

    def plot(out: Path, p: Particles, t: float, P) -> None:
        plot_profiles(out, cfg, title=_title(cfg))

    return Problem(c["name"], particles, params, scheme, domain, cfg["time"]["t_end"], errors, plot,
                   config=cfg, description=_title(cfg), boundary=walls, diagnostics=errors)


def _pressure_gradient_error(p: Particles, P, eos_kind: str, length: float, d: Mapping) -> float:
    """|dp/dx - (-rho0 f_x)| / (rho0 f_x), dp/dx the least-squares slope of p(x) over the fluid
    particles of the middle half of the open channel (away from the inlet and outlet rows)."""
    pr = to_primitive(p.U, get_eos(eos_kind), P)
    x = np.asarray(p.x[:, 0])
    sel = (np.asarray(p.kind) == int(Kind.FLUID)) & (x > 0.25 * length) & (x < 0.75 * length)
    slope = np.polyfit(x[sel], np.asarray(pr.p)[sel], 1)[0]
    want = float(P["eos.rho0"]) * d["f_x"]
    return float(abs(slope + want) / abs(want))


def build_couette(cfg: Mapping) -> Problem:
    return _build(cfg)


def build_poiseuille(cfg: Mapping) -> Problem:
    return _build(cfg)


def particle_count(cfg: Mapping) -> tuple[int, tuple[str, ...]]:
    """(nx + the frozen end columns) x ny, and with mirror ghosts ceil(kappa beta) layers on each
    plate (an upper bound)."""
    c, m = cfg["case"], support_layers(cfg)
    cols = c["nx"] + (2 * (m + 1) if c["inlet"] != 0.0 else 0)
    rows = c["ny"] + (2 * m if c["walls"] == "mirror_ghosts" else 0)
    return cols * rows, ("case.nx", "case.ny", "case.walls")


COUETTE = register_case(
    "couette", _channel_keys(1.0), build_couette, check=check_channel, dim=2, particle_count=particle_count,
    defaults_override={"eos.kind": "tait", "eos.rho0": 1.0, "eos.c0": 10.0, "physics.mu": 0.1,
                       "time.t_end": 10.0, "output.snapshots": 20},
    doc="Start-up Couette flow (thesis §3.7.4): fluid at rest between two plates `gap` apart, "
        "the top plate impulsively set to `u_plate`; mirror-ghost walls, periodic along the "
        "plates, compared with the exact series solution (thesis eq. 3.20).")

POISEUILLE = register_case(
    "poiseuille", _channel_keys(0.0), build_poiseuille, check=check_channel, dim=2, particle_count=particle_count,
    defaults_override={"eos.kind": "tait", "eos.rho0": 1.0, "eos.c0": 10.0, "physics.mu": 0.1,
                       "physics.body_force": [0.8, 0.0], "time.t_end": 10.0, "output.snapshots": 20},
    doc="Start-up Poiseuille flow (thesis §3.7.4): fluid at rest between two fixed plates "
        "`gap` apart driven by the body force `physics.body_force` = [f_x, 0] (peak velocity "
        "f_x L^2 / (8 nu)); mirror-ghost walls, periodic along the plates, compared with the "
        "exact series solution (thesis eq. 3.21 with its sign corrected).")


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


    from ..io import read_snapshots

    snaps = read_snapshots(out)
    d = drives(cfg)
    u_max = channel_u_max(**d)
    yf = np.linspace(0.0, d["gap"], 401)
    fig, (ax, ax2) = subplots(1, 2, figsize=(10.5, 4.2))
    colors = colormap("viridis")(np.linspace(0.0, 0.9, 7))
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
