"""``cylinder``: flow past a circular cylinder (thesis §4.5.2, Figs. 4.7-4.9, Table 4.1; SPEC §12.2
V9, §5.8, §8.4-8.5; issue 17).

Geometry and particles.  A cylinder of ``radius`` R (D = 2R) at the origin in a stream along +x.
The fluid fills the annulus R < r < ``r_far`` on the body-fitted polar layout of
:func:`mlsph_jax.cases.layouts.polar_layout`: ``n_theta`` particles per ring at the angles of the
body's quadrature points, rings growing geometrically with square cells (ring ratio q ~ 1 + 2
pi / n_theta), volumes the annular-sector areas.  The thesis' setup (120 points on the body,
10,800 particles = 120 x 90 rings) is ``--set case.n_theta=120 case.r_far=40`` (86 fluid rings
to r = 80 D and 4 far-field rings).

Other layouts (``case.layout``, :mod:`mlsph_jax.cases.body_layouts`, decision 72): ``"cartesian"``,
a uniform square lattice of spacing ``lattice_ratio`` x perimeter / ``n_theta`` over the disc of
``r_far`` with the body cut out (no particle inside it or closer than h/2 to it), and ``"blend"``,
the polar rings out to ``blend_radius`` with the lattice of the last ring's spacing beyond; their
volumes are Voronoi cells clipped to the fluid, their far field is the lattice continued as frozen
particles, and they do not follow the body's shape parameters (shape derivatives need the polar
layout).  ``"graded"`` (decision 90): the polar rings with the near wake's ring particles replaced
by a relaxed point cloud whose spacing grows linearly, by ``wake_grading``, with the distance from
the wake axis between the body and ``wake_length`` D, where it is ``wake_spacing`` D (smooth
grading keeps the neighbour rows near the polar layout's).  ``"offset"`` (decision 105):
``offset_rows`` rows along the body's offset curves at distances (m + 1/2) h, the cartesian
lattice beyond, so that the first row lies h/2 from the wall of any body.  The body's quadrature keeps
``n_theta`` points on every layout.

Body.  No-slip wall by the boundary integral of thesis eq. 4.24, adiabatic (thesis) or isothermal
(``wall_temperature`` T_w / T_inf > 0: wall energy e_w = (T_w / T_inf) e_inf, Params key
``geometry.body.wall_e``; decision 102)
(:mod:`mlsph_jax.wall_integral`, ``boundary_integral``; SPEC §5.8): a
:class:`~mlsph_jax.geometry.Circle` named ``body`` with ``n_theta`` quadrature points, no ghosts.
The body's centre and radius are the parameters ``geometry.body.centre`` / ``geometry.body.radius``
of the problem's Params; the layout follows them (below), so ``mlsph sensitivity --wrt
geometry.body.radius`` moves the particles with the body.

Elliptic body (``case.body = "ellipse"``; decision 65).  A
:class:`~mlsph_jax.geometry.StreamEllipse` of the same area pi R^2: aspect ratio A = a/b
(``case.aspect``, parameter ``geometry.body.aspect``), a = R sqrt(A) along x, b = R / sqrt(A),
and angle of attack alpha (``case.alpha`` in degrees, parameter ``geometry.body.alpha`` in
radians, nose up).  The angle of attack turns the free stream to U_inf (cos alpha, sin alpha)
(initial state, far field and the force projection: C_D along the stream, C_L across it), not
the body: the same flow seen in a frame turned by alpha, in which the body, its layout, the
neighbour lists and the set-up geometry of the in-run wall-crossing check do not depend on
alpha.  The layout is the circle's polar layout carried by the Joukowski map z = zeta + c^2 /
zeta (:func:`~mlsph_jax.cases.layouts.elliptic_polar_layout`): body-fitted, cells kept square,
volumes the exact areas of the mapped cells.  ``problem.particles_at(params)`` gives the initial
particles as a jnp function of the Params (positions and volumes of the shape, state of the
stream direction), which :mod:`mlsph_jax.sensitivity` starts every differentiated run from.  The
coefficients' length is D = 2R (the equal-area diameter; the chord is 2a).  The recirculation
length of an ellipse is reported at alpha = 0 only (behind the rear point x = a).

Bodies given by points (``case.body = "polygon"`` or ``"spline"``; decision 103).  The closed
polygon through ``case.body_points`` (a :class:`~mlsph_jax.geometry.Polygon`, edges cut into pieces
no longer than its perimeter / ``n_theta``, midpoint rule) or the periodic cubic spline through them
(:class:`~mlsph_jax.geometry.Spline`, ``n_theta`` points); the points are in units of the reference
length D = 2 ``radius`` about the body's centre, the origin, so ``radius`` scales the shape and D
stays the length of Re, C_D, C_L and Nu (a square of side D: corners at +-0.5).  Only the
``cartesian`` and ``offset`` layouts fit an arbitrary curve (``offset`` keeps the first row h/2
from every face); ``alpha`` turns the stream as for the ellipse, the
aspect ratio must stay 1.  C_p(theta) and the front / base values use the angle about the origin
(a star-shaped body about its centre reads naturally); the recirculation length starts at the
body's rearmost crossing of the wake axis y = 0 (none at incidence or for a body off the axis).
At a sharp corner the wall state is a one-sided MLS extrapolation across the corner, so C_p and
C_f at the quadrature points next to a corner are not converged values (docs/validation.md).

Far field (SPEC §5.8 [REC], §8.5).  Beyond ``r_far`` the geometric rings continue as FROZEN
particles (:class:`~mlsph_jax.state.Kind`) holding the free-stream state: the integrator never
updates a frozen particle (its state is the free stream bit for bit at every stage, which is the
"reset to the free stream each stage" of SPEC §5.8), while it acts as a neighbour of the fluid.
Their number is the smallest that covers the support radius kappa beta sqrt(V) of the outermost
fluid ring, plus one ring (as for the blast's far field), so every fluid stencil is complete.
``far_field`` chooses their state (:mod:`mlsph_jax.far_field`): ``frozen`` (the above, default),
``characteristic`` (Riemann invariants, set every stage) or ``inflow_outflow`` (velocity inlet,
pressure outlet); measured against each other in docs/validation.md ("Far-field options").

Fluid.  Ideal gas (SPEC V9 [REC]: gamma = 1.4), rho_inf = U_inf = 1, free-stream Mach number
``mach`` (c_inf = U_inf / M, p_inf = rho_inf c_inf^2 / gamma), mu = rho_inf U_inf D / ``re``
(physics.mu is derived as in the cavity; ``inviscid``: mu = 0, Euler flow past a body that is then a
no-penetration wall only, whatever ``re``), by default no heat conduction (physics.kappa = 0: at M =
0.1 the temperature varies by O(M^2); the thesis' wall is adiabatic).  ``prandtl`` Pr > 0 derives
physics.kappa = gamma mu / Pr (held fixed when physics.mu is differentiated, so a derivative with
respect to mu is one at fixed kappa, not at fixed Pr); an isothermal body needs conduction.  The
steady stop (``steady_tol``) tests the velocity only: with a heated body check that ``nusselt`` in
``timeseries.csv`` has settled too.  Eulerian frame (thesis).  The
run starts impulsively: every particle at the free stream.  With a body force
``physics.body_force`` = f the initial and far-field states are the isothermal hydrostatic
atmosphere p = p_inf exp(rho_inf f.x / p_inf), rho = rho_inf p / p_inf (grad p = rho f).

Steady state.  The run stops once the velocity field changes by less than ``steady_tol`` per unit
time relative to its maximum between two output times (the cavity's residual,
:class:`~mlsph_jax.simulation.Problem` ``steady_tol``), or at ``time.t_end``.

Vortex shedding (Re >~ 47; thesis §4.5.3, Table 4.2; configs ``cylinder_re100``, ``cylinder_re185``). The layout (rings
at the body's quadrature angles, symmetric about y = 0), the impulsive start and the scheme are
mirror-symmetric to round-off, so without a trigger the wake stays symmetric for as long as
round-off needs to grow into the shedding mode (measured: |C_L| < 1.5e-13 to t = 84 at Re = 100).
Numerical studies of the unsteady cylinder break the symmetry on purpose, either by an asymmetric
start (an initial perturbation of the flow field) or by a short rotation or displacement of the
body (Braza, Chassaing & Ha Minh 1986, J. Fluid Mech. 165, rotated the cylinder for a short time);
a limit cycle that is reached does not depend on the trigger. Here the trigger is an initial
perturbation, ``case.perturbation`` > 0 (default 0: off): a shielded Gaussian vortex (stream
function psi = A exp(-|x - x_v|^2 / sigma^2), divergence-free, zero circulation in the unbounded
plane, its velocity negligible beyond 4 sigma; kept two cores clear of the body, whose cut of the
shield would leave net circulation; the pressure and density are the free stream's, not in
cyclostrophic balance with the swirl, so the start carries a small acoustic transient; the vortex
is fixed in space, not moved with the body's parameters) centred on the wake axis at x_v =
(``perturbation_x`` D, 0), core sigma = ``perturbation_core`` D, peak swirl speed ``perturbation``
U_inf, added to the free stream of the fluid particles at t = 0 (:func:`trigger_velocity`). It is a
plain function of the configuration (in :func:`initial_state`, which ``problem.particles_at`` also
uses, so it is as differentiable as the rest of the initial state), needs no time-dependent
boundary data, and is carried out of the domain by the stream: after the transient nothing of it
remains (statistics are taken after ``case.transient``). A rotation of the body over a time window
would need the time inside the right-hand side, which the integrator does not pass. Statistics of the shedding
(:func:`shedding_statistics`, :mod:`mlsph_jax.periodic`; summary.json ``series_statistics`` and
metrics ``st``, ``st_spectral``, ``cd_mean``, ``cl_mean``, ``cl_amplitude``, ``cl_rms``,
``n_periods``): the Strouhal number f D / U_inf from the upward zero crossings of C_L, means,
amplitude and rms (of the fluctuation) over the whole lift periods after ``case.transient``; a
note instead of numbers when the run is too short, does not shed, is not saturated, is irregular,
has non-finite values, failed, or runs local time steps, or the sampling of the time series does
not resolve the period.  The statistics are host-side numbers (numpy) over whole periods; their
differentiable counterparts are the objectives ``cd_mean``, ``cl_mean``, ``cl_rms`` (and the parts'
``*_mean`` / ``*_rms``) of ``mlsph sensitivity --window T_START T_END``: time averages over a fixed
window accumulated at every step of the differentiated run (:mod:`mlsph_jax.sensitivity`,
decision 73). C_L
and C_D are recorded at the samples of the time series: every ``output.series_interval`` (a whole
fraction of the output interval, recorded without writing the fields) or, without it, at the output
times; the sampling must resolve the period (~6 D / U_inf at Re = 100: >= 8 samples per period are
required; ``cylinder_re100`` samples every 0.25, ~28 per period, and writes 30 snapshots).

Diagnostics (every output time, ``timeseries.csv``) and metrics (final state), forces from the
body's quadrature points (:meth:`~mlsph_jax.wall_integral.BoundaryIntegralWalls.coefficients`):

* ``cd``, ``cl``: drag and lift coefficients F / (1/2 rho_inf U_inf^2 D); ``cd_pressure``,
  ``cl_pressure`` their pressure parts and ``cd_viscous``, ``cl_viscous`` the viscous parts;
* ``cp_front``, ``cp_base``: C_p = (p_b - p_inf) / (1/2 rho_inf U_inf^2) at theta = pi (front
  stagnation point) and theta = 0 (base), p_b the wall pressure of the boundary integral,
  interpolated in angle from the four nearest quadrature points (cubic Lagrange);
* ``separation_angle``, ``separation_angle_lower``: where the flow separates on the upper
  (left of the stream) and lower surface, in degrees from the base (the downstream end of the
  body seen from its centre), 0 when it does not separate: the first sign change of the skin
  friction C_f met when walking from the surface's largest C_f (just behind the front stagnation
  point) towards the base, linear in angle between the two quadrature points around it
  (:func:`separation_angles`).  C_f = tau_w / (1/2 rho_inf U_inf^2) with tau_w the viscous
  traction on the body along the surface tangent pointing from the front towards the base
  (positive in attached flow; :func:`body_cf`; plotted in ``cf.png``);
* ``nusselt`` (an isothermal body, ``case.wall_temperature`` > 0 and not 1): the mean Nusselt
  number Nu = Q D / (P kappa (e_w - e_inf)) = h D / k, Q = sum_b dGamma_b kappa grad(e)_b . n_b the
  heat passed from the body into the fluid per unit span (the isothermal wall's conductive flux,
  decision 101), P the body's perimeter, e = c_v T (so kappa grad e = k grad T); positive when heat
  flows from the hotter to the colder side (a cooled body too); ``nusselt_front`` the local Nu at
  the front stagnation point (interpolated like C_p; plotted against theta in ``nu.png``).  Heat
  conduction: ``case.prandtl`` Pr sets physics.kappa = gamma mu / Pr (k = mu c_p / Pr over c_v);
* ``recirculation_length`` (metrics only): L_w / D, the distance from the base to where u_x on
  the wake axis y = 0 turns positive again behind the first ring that flows back; u_x on the
  axis is the mean of the two particle rays at theta = +-dtheta/2, linear in r between rings
  (0 when nothing flows back; the first ring next to the wall may be slightly positive, since
  no-slip is imposed weakly through the boundary term).

Plots: ``cp.png`` (C_p(theta) with thesis Table 4.1's points), ``cf.png`` (C_f(theta) and the
separation points), ``nu.png`` (local Nu(theta) of an isothermal body) and ``velocity_field.png``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from ..boundaries import BOUNDARIES
from ..config import effective_beta
from ..eos import get_eos, to_conservative, to_primitive
from ..errors import ConfigError, InputError
from ..far_field import FAR_FIELDS, with_far_field
from ..geometry import Circle, StreamEllipse
from ..geometry.checks import detour_around_polygon, inside_polygon
from ..kernels import get_kernel
from ..periodic import whole_period_statistics
from ..plotting import subplots
from ..reference import cylinder as ref
from ..schema import Key, join_problems, show
from ..simulation import Problem
from ..state import Domain, Kind, Params, Particles, make_particles
from .base import register_case
from .body_layouts import (
    BODY_LAYOUTS,
    POINT_BODIES,
    POINT_LAYOUTS,
    body_extent,
    body_polygon,
    check_outside,
    distance_to_polygon,
    far_rings,
    points_text,
    shape_curve,
    shape_outline,
    shape_problems,
)
from .common import params_from_config, scheme_from_config, steady_tol_key
from .layouts import polar_ring_edges

#: Free-stream density and speed (the scales of the coefficients).
RHO_INF = 1.0
U_INF = 1.0
#: Name of the body's curve (``geometry.body.*`` parameters).
BODY = "body"
_NAMES = ("case.radius", "case.n_theta", "case.r_far")
#: The trigger vortex must fit in the fluid out to this many core radii (its velocity there is
#: ~1e-6 of the peak).
TRIGGER_REACH = 4.0
#: Neighbours through the body (:func:`_check_line_of_sight`): refused when the way around the
#: body is longer than the straight line by this fraction of their support radius or more.  Near
#: a corner of half-angle theta the worst pair's excess is ~(1 / sin theta - 1) of the support at
#: every resolution: 1 refuses corners sharper than 60 degrees (a square's 90 degrees give 0.41).
DETOUR_LIMIT = 1.0
#: ``case.body`` choices: the curve of each (:func:`body_curve`).
BODIES = ("circle", "ellipse", *POINT_BODIES)


def cylinder_viscosity(cfg: Mapping) -> float:
    """mu = rho_inf U_inf D / re of a resolved ``cylinder`` config (0 for ``case.inviscid``)."""
    if cfg["case"]["inviscid"]:
        return 0.0
    return RHO_INF * U_INF * 2.0 * cfg["case"]["radius"] / cfg["case"]["re"]


def _support_radius(cfg: Mapping, dx: float) -> float:
    return get_kernel(cfg["scheme"]["kernel"]).support * effective_beta(cfg["scheme"]) * dx


def n_far_field_rings(cfg: Mapping) -> int:
    """Frozen rings beyond ``r_far`` of the polar layout: the fewest whose widths (the geometric
    sequence continued) cover the support radius of the outermost fluid ring's particles, plus one."""
    return far_rings(cfg["case"], lambda dx: _support_radius(cfg, dx), _NAMES)


def particle_count(cfg: Mapping) -> tuple[int, tuple[str, ...]] | None:
    """The layout's particle count (fluid and frozen far field) and the keys that set it, from the
    config (:data:`~mlsph_jax.cases.body_layouts.BODY_LAYOUTS` ``count``; the ``run.max_particles``
    guard); None for a user's layout without ``count``."""
    c = cfg["case"]
    count = getattr(BODY_LAYOUTS.get(c["layout"], "case.layout"), "count", None)
    return None if count is None else count(c, lambda dx: _support_radius(cfg, dx))


def check_cylinder(cfg: dict) -> None:
    """`eos.kind` must be ideal_gas (SPEC V9) and `scheme.method` mlsph_ale (the boundary term of
    thesis eq. 4.24 is derived for MLS shape functions), `scheme.frame` eulerian (thesis; the
    body-fitted layout is not kept by moving particles). The viscosity follows from `re`:
    physics.mu must be 0 (derived) or equal rho_inf U_inf 2 `radius` / `re`; with `inviscid` it
    must be 0, and no heat conduction or isothermal body may be set. The far field must
    stay out of the body's wall stencils: `r_far` must exceed `radius` plus the wall points'
    support radius kappa beta sqrt(V_0) (V_0 the volume of a first-ring particle); otherwise the
    body is too big for the layout and overlaps the far-field rings (the set-up also checks
    every wall stencil for frozen particles). A `physics.body_force` f must keep the hydrostatic
    pressure ratio across the domain moderate: rho_inf |f| 2 `r_far` / p_inf <= 50. Lattice layouts
    (`layout`, decision 72): `cartesian` needs n_theta / `lattice_ratio` >= 20 lattice spacings around
    the body and `blend` a `blend_radius` beyond the body's first two rings and two lattice spacings
    inside `r_far`; both need `r_far` beyond the body's extent plus h/2 plus the support radius of the
    lattice spacing h plus h; `lattice_ratio` / `blend_radius` may only be set for the layout that uses
    them. The set-up refuses a lattice whose particles next to the body are smaller than the body's
    quadrature pieces (naming `lattice_ratio` or `n_theta`) and any layout leaving a fluid particle
    inside the body."""
    c, phys = cfg["case"], cfg["physics"]
    problems = _body_problems(c)
    if problems and c["body"] in POINT_BODIES:      # the layout checks below need a valid shape
        raise ConfigError(join_problems(problems))
    if cfg["eos"]["kind"] != "ideal_gas":
        problems.append(f"invalid eos.kind={show(cfg['eos']['kind'])}: case cylinder is a compressible "
                        "ideal-gas flow at free-stream Mach number case.mach (thesis §4.5.2); allowed: \"ideal_gas\"")
    if cfg["scheme"]["method"] != "mlsph_ale":
        problems.append(f"invalid scheme.method={show(cfg['scheme']['method'])}: the body is a boundary-integral "
                        "wall (thesis eq. 4.24), derived for MLS shape functions; allowed: \"mlsph_ale\"")
    if cfg["scheme"]["frame"] != "eulerian":
        problems.append(f"invalid scheme.frame={show(cfg['scheme']['frame'])}: the body-fitted layout and "
                        "the frozen far field need fixed particles; allowed: \"eulerian\"")
    mu = cylinder_viscosity(cfg)
    if c["inviscid"] and phys["mu"] != 0.0:
        problems.append(f"invalid physics.mu={show(phys['mu'])} with case.inviscid=true: an inviscid flow has "
                        "mu = 0; allowed: physics.mu = 0, or case.inviscid = false with case.re")
    elif phys["mu"] != 0.0 and abs(phys["mu"] - mu) > 1e-9 * mu:
        problems.append(f"invalid physics.mu={show(phys['mu'])}: case cylinder derives the viscosity from "
                        f"case.re={show(c['re'])} (mu = rho_inf U_inf 2 case.radius / case.re = {mu:.10g}); "
                        f"allowed: 0 (derived) or {mu:.10g} — set case.re instead")
    problems += _heat_problems(cfg)
    try:
        edges, _ = polar_ring_edges(c["radius"], c["n_theta"], c["r_far"], names=_NAMES)
    except InputError as e:
        problems.append(str(e))
    else:
        dtheta = 2.0 * math.pi / c["n_theta"]
        # the support radius kappa beta sqrt(V_0) of the body's wall points (V_0: the first ring)
        need = c["radius"] + _support_radius(cfg, math.sqrt(0.5 * (edges[1] ** 2 - edges[0] ** 2) * dtheta))
        if c["r_far"] <= need:
            problems.append(f"invalid case.r_far={show(c['r_far'])} with case.radius={show(c['radius'])} and "
                            f"case.n_theta={c['n_theta']}: the far-field rings start inside the support of the "
                            f"body's wall points (out to r = {need:.4g}), the body is too big for the layout; "
                            f"allowed: case.r_far > {need:.4g} (or a smaller case.radius)")
    problems += layout_problems(cfg)
    if c["body"] == "circle" and (c["aspect"] != 1.0 or c["alpha"] != 0.0):
        problems.append(f"invalid case.aspect={show(c['aspect'])} / case.alpha={show(c['alpha'])} with "
                        "case.body=\"circle\": a circle has aspect 1 and no angle of attack; allowed: "
                        "case.body = \"ellipse\" (or aspect 1 and alpha 0)")
    if c["perturbation"] > 0.0:
        D, core, xv = 2.0 * c["radius"], c["perturbation_core"], c["perturbation_x"]
        room = None
        if c["body"] in POINT_BODIES:     # the room between the vortex centre and the outline, in D
            poly = shape_outline(c)
            centre = np.asarray([[xv * D, 0.0]])
            room = 0.0 if inside_polygon(centre, poly)[0] else float(distance_to_polygon(centre, poly)[0]) / D
            if 2.0 * core > room:
                problems.append(f"invalid case.perturbation_x={show(xv)} with case.perturbation_core={show(core)}: "
                                f"the trigger vortex (core and shield, two core radii) reaches into the body (its "
                                f"centre is {room:.4g} D from the outline{', inside it' if room == 0.0 else ''}); "
                                f"allowed: 2 case.perturbation_core <= the distance from (case.perturbation_x D, 0) "
                                "to the outline, the centre outside the body")
        half = body_extent(c) / D        # the largest half-extent in D (an ellipse: its semi-major axis)
        if room is None and xv - 2.0 * core < half:   # its shield too: cut by the body it would leave circulation
            problems.append(f"invalid case.perturbation_x={show(xv)} with case.perturbation_core={show(core)}: the "
                            f"trigger vortex (core and shield, two core radii) reaches into the body (x / D < "
                            f"{half:.4g}); allowed: case.perturbation_x - 2 case.perturbation_core >= {half:.4g}")
        elif (xv + TRIGGER_REACH * core) * D >= c["r_far"]:
            problems.append(f"invalid case.perturbation_x={show(xv)} with case.perturbation_core={show(core)} and "
                            f"case.r_far={show(c['r_far'])}: the trigger vortex reaches the far field; allowed: "
                            f"(case.perturbation_x + {TRIGGER_REACH:g} case.perturbation_core) D < case.r_far")
    if c["perturbation"] > 0.0 and cfg["time"]["local_time_stepping"]:
        problems.append(f"invalid case.perturbation={show(c['perturbation'])} with time.local_time_stepping=true: "
                        "the trigger starts an unsteady flow, and local time steps advance a pseudo-time (no "
                        "shedding period); allowed: time.local_time_stepping=false with a trigger")
    bf = phys["body_force"]
    if bf and any(f != 0.0 for f in bf):
        p_inf = RHO_INF * (U_INF / c["mach"]) ** 2 / cfg["eos"]["gamma"]
        r_out = 2.0 * c["r_far"]
        drop = RHO_INF * math.hypot(*bf) * r_out / p_inf
        if drop > 50.0:
            problems.append(f"invalid physics.body_force={show(bf)} with case.mach={show(c['mach'])}: the "
                            f"hydrostatic pressure would vary by a factor exp({drop:.3g}) across the domain; "
                            "allowed: rho_inf |f| 2 r_far / p_inf <= 50")
    if problems:
        raise ConfigError(join_problems(problems))


def _body_problems(c: Mapping) -> list[str]:
    """A body given by points (decision 103) needs ``body_points`` (a simple closed curve), the
    ``cartesian`` or ``offset`` layout (decision 105) and aspect 1; the points are refused for a
    circle or an ellipse."""
    if c["body"] not in POINT_BODIES:
        if c["body_points"]:
            return [f"invalid case.body_points={show(c['body_points'])} with case.body={show(c['body'])}: points "
                    f"give the body's shape for case.body = {' / '.join(map(show, POINT_BODIES))} only; allowed: "
                    f"case.body_points = [] or case.body = {show(POINT_BODIES[0])}"]
        return []
    problems = []
    if c["layout"] not in POINT_LAYOUTS:
        problems.append(f"invalid case.layout={show(c['layout'])} with case.body={show(c['body'])}: the polar "
                        "rings (and the blend and graded layouts built on them) are fitted to a circle or an "
                        "ellipse; allowed: case.layout = \"cartesian\" (a lattice with the body cut out) or "
                        "\"offset\" (rows along the body's offset curves, the lattice beyond)")
    if c["aspect"] != 1.0:
        problems.append(f"invalid case.aspect={show(c['aspect'])} with case.body={show(c['body'])}: the points give "
                        "the shape; allowed: case.aspect = 1 (scale the points instead)")
    return problems + shape_problems(c)


def _heat_problems(cfg: Mapping) -> list[str]:
    """Heat conduction and the isothermal body: physics.kappa must be 0 (derived) or gamma mu / Pr
    when `prandtl` is set, and a `wall_temperature` needs conduction (nothing silently ignored)."""
    c, phys, problems = cfg["case"], cfg["physics"], []
    kappa = cylinder_conductivity(cfg)
    if c["inviscid"]:
        for key, val in (("case.prandtl", c["prandtl"]), ("physics.kappa", phys["kappa"]),
                         ("case.wall_temperature", c["wall_temperature"])):
            if val != 0.0:
                problems.append(f"invalid {key}={show(val)} with case.inviscid=true: an inviscid flow has no heat "
                                f"conduction (and an isothermal body needs it); allowed: {key} = 0, or "
                                "case.inviscid = false")
        return problems
    if c["prandtl"] > 0.0 and phys["kappa"] != 0.0 and abs(phys["kappa"] - kappa) > 1e-9 * kappa:
        problems.append(f"invalid physics.kappa={show(phys['kappa'])}: case cylinder derives the conduction "
                        f"coefficient from case.prandtl={show(c['prandtl'])} (kappa = gamma mu / Pr = {kappa:.10g}); "
                        f"allowed: 0 (derived) or {kappa:.10g} — or case.prandtl = 0 to set physics.kappa directly")
    if c["wall_temperature"] > 0.0 and kappa == 0.0:
        problems.append(f"invalid case.wall_temperature={show(c['wall_temperature'])} without heat conduction "
                        f"(case.prandtl={show(c['prandtl'])}, physics.kappa={show(phys['kappa'])}): an isothermal "
                        "body passes heat by conduction only; allowed: case.wall_temperature = 0 (adiabatic), or "
                        "case.prandtl > 0 (e.g. 0.72) or physics.kappa > 0")
    return problems


def layout_problems(cfg: Mapping) -> list[str]:
    """The layout's own checks (:data:`~mlsph_jax.cases.body_layouts.BODY_LAYOUTS`), and no
    lattice key set for a layout that does not use it (nothing silently ignored)."""
    c = cfg["case"]
    used = {"lattice_ratio": ("cartesian", "offset"), "offset_rows": ("offset",), "blend_radius": ("blend",),
            "wake_spacing": ("graded",),
            "wake_length": ("graded",), "wake_grading": ("graded",)}
    problems = [f"invalid case.{k}={show(c[k])} with case.layout={show(c['layout'])}: it is used by case.layout="
                f"{' / '.join(map(show, lays))} only; allowed: the default {show(CYLINDER_KEYS[k].default)} or "
                f"case.layout={' / '.join(map(show, lays))}"
                for k, lays in used.items() if c["layout"] not in lays and c[k] != CYLINDER_KEYS[k].default]
    if problems:
        return problems
    return BODY_LAYOUTS.get(c["layout"], "case.layout").check(c, lambda dx: _support_radius(cfg, dx))


CYLINDER_KEYS: dict[str, Key] = {
    "radius": Key(float, 0.5, minimum=0.0, exclusive_minimum=True, unit="m",
                  doc="cylinder radius R (D = 2R; thesis: 0.5)"),
    "re": Key(float, 40.0, minimum=0.0, exclusive_minimum=True,
              doc="Reynolds number rho_inf U_inf D / mu (sets physics.mu; rho_inf = U_inf = 1; unused with "
                  "case.inviscid)"),
    "inviscid": Key(bool, False,
                    doc="Euler flow: mu = 0 (case.re unused), the body a no-penetration wall without friction "
                        "(docs/validation.md \"Euler flow past the circle\": the exact stagnation C_p is "
                        "1 + M^2/4 + ...)"),
    "mach": Key(float, 0.1, minimum=0.0, exclusive_minimum=True, maximum=0.5,
                doc="free-stream Mach number U_inf / c_inf (sets p_inf = rho_inf c_inf^2 / gamma; thesis: 0.1)"),
    "n_theta": Key(int, 48, minimum=32,
                   doc="particles per ring = quadrature points on the body (thesis: 120); the rings "
                       "grow geometrically with square cells, ratio ~1 + 2 pi / n_theta; below 32 the "
                       "wall rows blow up (16: NaN in the first step, 24: at t = 1.6, CFL 0.3 and 0.6)"),
    "r_far": Key(float, 40.0, minimum=0.0, exclusive_minimum=True, unit="m",
                 doc="outer radius of the fluid region (frozen free-stream rings beyond it); "
                     "thesis setup: 40 with n_theta = 120 (10,800 particles)"),
    "layout": Key(str, "polar", choices=BODY_LAYOUTS.names,
                  doc="particles around the body (docs/architecture.md decision 72): \"polar\" body-fitted rings "
                      "with geometric growth (decisions 58, 65); \"cartesian\" a uniform square lattice of spacing "
                      "case.lattice_ratio x perimeter / case.n_theta with the body cut out; \"blend\" the polar "
                      "rings out to case.blend_radius and the lattice of the last ring's spacing beyond; \"graded\" "
                      "the polar rings with a wake cloud graded from case.wake_spacing on the wake axis (decision 90); "
                      "\"offset\" case.offset_rows rows along the body's offset curves at (m + 1/2) h, the cartesian "
                      "lattice beyond (decision 105; the first row h/2 from any body); lattice and cloud "
                      "volumes are Voronoi cells clipped to the fluid; shape derivatives need \"polar\""),
    "lattice_ratio": Key(float, 1.0, minimum=0.0, exclusive_minimum=True,
                         doc="case.layout = \"cartesian\" / \"offset\" only: lattice spacing h over the body's "
                             "quadrature spacing (perimeter / case.n_theta); n_theta / lattice_ratio >= 20 spacings "
                             "around the body, and the quadrature may not be sparser than the particles next to the "
                             "body"),
    "offset_rows": Key(int, 3, minimum=1,
                       doc="case.layout = \"offset\" only: rows of particles along the body's offset curves at "
                           "distances (m + 1/2) h, m = 0 .. offset_rows - 1, spaced h along each (decision 105); the "
                           "lattice of spacing h starts offset_rows h from the body"),
    "blend_radius": Key(float, 2.0, minimum=0.0, exclusive_minimum=True, unit="m",
                        doc="case.layout = \"blend\" only: outer radius of the polar rings (the lattice beyond has "
                            "the last ring's spacing sqrt(V)); between the body's second ring and case.r_far less "
                            "two lattice spacings"),
    "wake_spacing": Key(float, 0.1, minimum=0.0, exclusive_minimum=True,
                        doc="case.layout = \"graded\" only: particle spacing sqrt(V) / D on the wake axis from the "
                            "body's rear to case.wake_length (decision 90); at least the first ring's spacing"),
    "wake_length": Key(float, 6.0, minimum=1.0,
                       doc="case.layout = \"graded\" only: x / D (from the body's centre) where the wake axis' "
                           "refinement ends; beyond it the spacing grows by case.wake_grading with the distance"),
    "wake_grading": Key(float, 0.16, minimum=0.0, exclusive_minimum=True, maximum=0.3,
                        doc="case.layout = \"graded\" only: growth of the wake spacing with the distance from the "
                            "refined axis segment (neighbouring spacings differ by ~1 + wake_grading); above the "
                            "rings' own growth sqrt(V) / r (0.126 at n_theta 48), so the refined region ends"),
    "body": Key(str, "circle", choices=BODIES,
                doc="the body: a circle of case.radius, or an ellipse of the same area (equal-area radius "
                    "case.radius, aspect ratio case.aspect, angle of attack case.alpha) on the conformally "
                    "mapped polar layout (docs/architecture.md decision 65), or a polygon through / a periodic "
                    "cubic spline through case.body_points on the cartesian or offset layout (decisions 103, 105)"),
    "body_points": Key(list, [], item_type=float, item_length=2,
                       doc="case.body = \"polygon\" / \"spline\" only: the vertices / knots [[x, y], ...] in "
                           "units of D = 2 case.radius about the body's centre (the origin), in order around the "
                           "body (either sense, the first point not repeated); D is the reference length of "
                           "case.re, C_D, C_L and Nu (a square cylinder of side D: [[-0.5, -0.5], [0.5, -0.5], "
                           "[0.5, 0.5], [-0.5, 0.5]]); the polygon's edges are cut into pieces no longer than "
                           "its perimeter / case.n_theta; on case.layout = \"cartesian\" choose case.lattice_ratio so "
                           "that flat faces lie half a lattice spacing from a lattice row (the square: lattice_ratio = "
                           "n_theta / (8 k)), a gap near 1.5 spacings spoils the wall pressure (docs/validation.md); "
                           "case.layout = \"offset\" keeps the first row half a spacing from every face"),
    "aspect": Key(float, 1.0, minimum=0.0, exclusive_minimum=True,
                  doc="ellipse only: aspect ratio a/b of the semi-axes along/across its chord, a = R sqrt(aspect), "
                      "b = R / sqrt(aspect) (R = case.radius; parameter geometry.body.aspect)"),
    "alpha": Key(float, 0.0, minimum=-90.0, maximum=90.0, unit="deg",
                 doc="ellipse, polygon and spline bodies: angle of attack, nose up, in degrees (realised by "
                     "turning the free stream to (cos alpha, sin alpha); parameter geometry.body.alpha in radians)"),
    "perturbation": Key(float, 0.0, minimum=0.0, maximum=0.5,
                        doc="symmetry-breaking trigger for vortex shedding: peak swirl speed / U_inf of a "
                            "divergence-free, shielded (zero-circulation) Gaussian vortex added to the initial "
                            "state, centred at (case.perturbation_x, 0) in units of D behind the body's centre "
                            "(0: off, the flow stays mirror-symmetric to round-off; docs/validation.md)"),
    "perturbation_x": Key(float, 1.5, minimum=0.0, exclusive_minimum=True,
                          doc="x / D of the trigger vortex's centre on the wake axis (its core, of radius "
                              "case.perturbation_core D, must lie in the fluid)"),
    "perturbation_core": Key(float, 0.5, minimum=0.0, exclusive_minimum=True,
                             doc="core radius sigma / D of the trigger vortex (stream function "
                                 "psi ~ exp(-r^2 / sigma^2))"),
    "transient": Key(float, 50.0, minimum=0.0, unit="s",
                     doc="unsteady statistics (Strouhal number, mean C_D, C_L amplitude and rms; summary.json "
                         "series_statistics) use the whole lift periods recorded after this time (in D / U_inf); "
                         "the time series' sampling (output.series_interval, or the output interval) must "
                         "resolve a period (>= 8 samples)"),
    "far_field": Key(str, "frozen", choices=FAR_FIELDS.names,
                     doc="state of the far-field rings beyond r_far: \"frozen\" keeps the free stream (SPEC "
                         "§5.8); \"characteristic\" sets the Riemann-invariant state of the nearest fluid "
                         "particle and the free stream each stage (non-reflecting for outgoing acoustic waves, "
                         "but at low Mach the pressure level floats with the wake); \"inflow_outflow\" is a "
                         "velocity inlet and pressure outlet (docs/validation.md, far-field options)"),
    "prandtl": Key(float, 0.0, minimum=0.0,
                   doc="Prandtl number mu c_p / k of the gas: sets physics.kappa = gamma mu / Pr (heat conduction, "
                       "thesis eq. 4.40; SPEC V9 recommends 0.72); 0: physics.kappa as given (default 0, no "
                       "conduction; the thesis' adiabatic body)"),
    "wall_temperature": Key(float, 0.0, minimum=0.0,
                            doc="T_w / T_inf of an isothermal body (wall energy e_w = ratio e_inf, parameter "
                                "geometry.body.wall_e; decisions 101, 102), reporting the Nusselt number (not at 1: "
                                "no temperature difference; near 1 it carries the O(M^2) recovery temperature, "
                                "docs/validation.md); 0: adiabatic (the default, thesis); needs heat conduction "
                                "(case.prandtl or physics.kappa > 0)"),
    "steady_tol": steady_tol_key(1e-3),
}


def cylinder_conductivity(cfg: Mapping) -> float:
    """physics.kappa of a resolved ``cylinder`` config: gamma mu / ``case.prandtl`` (kappa = k / c_v,
    k = mu c_p / Pr) when the Prandtl number is set, else physics.kappa as given."""
    pr = cfg["case"]["prandtl"]
    return cfg["eos"]["gamma"] * cylinder_viscosity(cfg) / pr if pr > 0.0 else cfg["physics"]["kappa"]


def run_config(cfg: Mapping) -> dict:
    """The resolved config with ``physics.mu`` set to rho_inf U_inf D / Re and ``physics.kappa``
    to gamma mu / Pr when ``case.prandtl`` is set (what the run uses)."""
    return {**cfg, "physics": {**cfg["physics"], "mu": cylinder_viscosity(cfg), "kappa": cylinder_conductivity(cfg)}}


def free_stream(cfg: Mapping, x: np.ndarray, params: Params, xp=np):
    """``(rho, vel, p)`` of the free stream at ``x[N, 2]`` (the isothermal hydrostatic atmosphere
    when there is a body force; module docstring); ``xp``: numpy or jax.numpy (traceable in x)."""
    c = cfg["case"]
    p_inf = RHO_INF * (U_INF / c["mach"]) ** 2 / cfg["eos"]["gamma"]
    bf = cfg["physics"]["body_force"]
    f = np.asarray(bf if bf else [0.0, 0.0], float)
    p = p_inf * xp.exp(RHO_INF * (x @ f) / p_inf)
    vel = xp.tile(stream_velocity(params, xp), (len(x), 1))
    return RHO_INF * p / p_inf, vel, p


def trigger_velocity(cfg: Mapping, x, xp=np):
    """The symmetry-breaking trigger's velocity at ``x[N, 2]`` (zeros when ``case.perturbation`` is
    0): the shielded Gaussian vortex of stream function psi = A exp(-|x - x_v|^2 / sigma^2), u =
    (d psi / dy, -d psi / dx), centred at x_v = (``perturbation_x`` D, 0), sigma =
    ``perturbation_core`` D, A set so that the peak swirl speed (at |x - x_v| = sigma / sqrt 2)
    is ``perturbation`` U_inf.  It is divergence-free, its circulation is zero (the velocity decays
    as exp(-r^2 / sigma^2), nothing reaches the far field) and it turns anticlockwise about x_v: a
    state that is not its own mirror image in y = 0 (module docstring, "Vortex shedding")."""
    c = cfg["case"]
    D = 2.0 * c["radius"]
    sigma = c["perturbation_core"] * D
    amp = c["perturbation"] * U_INF * sigma * math.exp(0.5) / math.sqrt(2.0)
    dx, dy = x[:, 0] - c["perturbation_x"] * D, x[:, 1]
    psi = amp * xp.exp(-(dx * dx + dy * dy) / sigma ** 2)
    return xp.stack([-2.0 * dy / sigma ** 2 * psi, 2.0 * dx / sigma ** 2 * psi], axis=-1)


def initial_state(cfg: Mapping, x, params: Params, xp=np):
    """``(rho, vel, p)`` of the initial state: the free stream plus the trigger's velocity
    (:func:`trigger_velocity`; density and pressure unchanged)."""
    rho, vel, p = free_stream(cfg, x, params, xp)
    if cfg["case"]["perturbation"] > 0.0:
        vel = vel + trigger_velocity(cfg, x, xp)
    return rho, vel, p


def free_stream_energy(cfg: Mapping) -> float:
    """The free stream's specific internal energy e_inf = p_inf / ((gamma - 1) rho_inf) (uniform,
    also in the isothermal atmosphere of a body force)."""
    gamma = cfg["eos"]["gamma"]
    return (U_INF / cfg["case"]["mach"]) ** 2 / (gamma * (gamma - 1.0))


def stream_velocity(params: Params, xp=np):
    """The free-stream velocity U_inf (cos alpha, sin alpha): an elliptic body's angle of attack
    ``geometry.body.alpha`` turns the stream, not the body (decision 65); (U_inf, 0) without it."""
    key = f"geometry.{BODY}.alpha"
    if key not in params:
        return xp.asarray([U_INF, 0.0])
    a = params[key]
    return U_INF * xp.stack([xp.cos(a), xp.sin(a)])


def body_curve(cfg: Mapping):
    """The body's curve: a :class:`~mlsph_jax.geometry.Circle` of ``case.radius``, or for
    ``case.body = "ellipse"`` the :class:`~mlsph_jax.geometry.StreamEllipse` of equal-area radius
    ``case.radius``, aspect ``case.aspect`` and angle of attack ``case.alpha`` (degrees in the
    config, radians in ``geometry.body.alpha``); ``case.n_theta`` quadrature points; a polygon or
    spline through ``case.body_points`` (:func:`~mlsph_jax.cases.body_layouts.shape_curve`)."""
    c = cfg["case"]
    if c["body"] in POINT_BODIES:
        return shape_curve(c, BODY)
    if c["body"] == "ellipse":
        return StreamEllipse(BODY, radius=float(c["radius"]), aspect=float(c["aspect"]),
                             alpha=math.radians(c["alpha"]), incidence="stream", n_points=c["n_theta"])
    return Circle(BODY, centre=(0.0, 0.0), radius=float(c["radius"]), n_points=c["n_theta"])


def build(cfg: Mapping) -> Problem:
    cfg = run_config(cfg)
    c = cfg["case"]
    scheme = scheme_from_config(cfg)
    params = params_from_config(cfg)
    eos = get_eos(scheme.eos)
    R, n_theta = c["radius"], c["n_theta"]
    body = body_curve(cfg)
    # the body's geometry parameters live in the Params (differentiable, `mlsph sensitivity --wrt`)
    params = params.updated({k: jnp.asarray(v, jnp.float64) for k, v in body.defaults().items()})
    if c["body"] in POINT_BODIES:    # the angle of attack turns the stream, as for the ellipse
        params = params.updated({f"geometry.{BODY}.alpha": jnp.asarray(math.radians(c["alpha"]), jnp.float64)})
    lay = BODY_LAYOUTS.get(c["layout"], "case.layout").build(c, body, params, lambda dx: _support_radius(cfg, dx),
                                                             _NAMES)
    x, vol, kind = lay.x, lay.vol, lay.kind
    check_outside(x, kind, body, params, c["layout"])
    rho, vel, p = initial_state(cfg, x, params)
    vel = np.where((kind == int(Kind.FLUID))[:, None], vel, free_stream(cfg, x, params)[1])
    U = to_conservative(jnp.asarray(rho), jnp.asarray(vel), jnp.asarray(p), eos, params)
    pf = make_particles(x, vol, U, kind=kind, ppd=np.full(len(x), scheme.reconstruction_degree))
    polar_circle = c["layout"] == "polar" and c["body"] == "circle"
    half = (lay.bound if polar_circle else float(np.max(np.abs(x)))) * 1.01
    domain = Domain((-half, -half), (half, half), (False, False))
    band = R * 2.0 * math.pi / n_theta if c["body"] not in POINT_BODIES else lay.h
    e_inf = free_stream_energy(cfg)
    ratio = c["wall_temperature"]
    particles, walls = BOUNDARIES.get("boundary_integral").setup(
        pf, [], band, params, scheme.eos, scheme=scheme, domain=domain, curves=(body,),
        wall_energy={BODY: ratio * e_inf} if ratio > 0.0 else None)
    # an isothermal body's wall energy is a parameter (differentiable, `--wrt geometry.body.wall_e`)
    params = params.updated({k: v for k, v in walls.default_params().items() if k.endswith(".wall_e")})
    heated = ratio > 0.0 and ratio != 1.0      # a temperature difference: the Nusselt number is defined
    _check_far_field_apart(walls, particles)
    _check_line_of_sight(walls, particles, body, params, cfg)
    far = FAR_FIELDS.get(c["far_field"], "case.far_field").setup(
        particles, scheme.eos, lambda xf, P: free_stream(cfg, xf, P, xp=jnp))
    boundary = with_far_field(walls, far)

    def particles_at(P) -> Particles:
        """The initial particles for the parameters ``P`` (jnp, differentiable): the layout
        follows the body's shape parameters, the state is the free stream on it.  The topology
        (neighbour lists, sized from ``problem.particles``) is not re-planned: for the small
        changes of a gradient or an optimisation step at fixed aspect (a rotation keeps every
        pair distance) it stays valid (decision 65)."""
        xj, vj = lay.positions_at(P)
        r_, v_, p_ = initial_state(cfg, xj, P, xp=jnp)
        v_ = jnp.where((particles.kind == int(Kind.FLUID))[:, None], v_, free_stream(cfg, xj, P, xp=jnp)[1])
        Uj = to_conservative(r_, v_, p_, eos, P)
        return particles.replace(x=xj, vol=vj, q=vj[:, None] * Uj)
    p_inf = float(free_stream(cfg, np.zeros((1, 2)), params)[2][0])
    q_inf = 0.5 * RHO_INF * U_INF ** 2

    def reference_length(P):
        """D = 2 R: the circle's or the ellipse's (equal-area) diameter from the Params; for a body
        given by points the fixed scale of its points (decision 103)."""
        key = body.key("radius")
        return 2.0 * P[key] if key in P else 2.0 * R

    def body_centre(P):
        key = body.key("centre")
        return P[key] if key in P else np.zeros(2)

    def coefficients(p: Particles, t: float, P) -> dict:
        """C_D, C_L and their parts (jnp, differentiable)."""
        co = walls.coefficients(p, P, scheme, rho_inf=RHO_INF, u_inf=stream_velocity(P, jnp),
                                length=reference_length(P), curve=BODY)
        co = {**co, "cd_viscous": co["cd"] - co["cd_pressure"], "cl_viscous": co["cl"] - co["cl_pressure"]}
        if heated:    # Nu = Q D / (perimeter kappa (e_w - e_inf)), module docstring
            q, length = walls.heat_rates(p, P, scheme)
            k = [cv.name for cv in walls.curves].index(BODY)
            scale = length[k] * P["physics.kappa"] * (P[f"geometry.{BODY}.wall_e"] - e_inf)
            co["nusselt"] = q[k] * reference_length(P) / scale
        return co

    @jax.jit
    def wall_diagnostics(p: Particles, P):
        """The jnp part of the diagnostics in one compiled call (op by op it cost 0.2-0.4 s per
        time-series sample, decision 70): the coefficients, the wall pressure and the viscous
        traction tau_b n_b."""
        prim = to_primitive(p.U, eos, P)
        bp, _, _, pb, tn, qb = walls.wall_state(p, P, scheme, prim)
        nu = (qb * reference_length(P) / (P["physics.kappa"] * (P[f"geometry.{BODY}.wall_e"] - e_inf))
              if heated else qb)
        return coefficients(p, 0.0, P), bp.x, bp.normal, bp.curve, pb, tn, nu

    def diagnostics(p: Particles, t: float, P) -> dict[str, float]:
        co, xb, normal, curve, pb, tn, nu = wall_diagnostics(p, P)
        out = {k: float(v) for k, v in co.items()}
        theta, cp = body_cp(walls, xb, curve, pb, p_inf, q_inf)
        out["cp_front"] = float(periodic_interpolate(theta, cp, math.pi))
        out["cp_base"] = float(periodic_interpolate(theta, cp, 0.0))
        if heated:
            out["nusselt_front"] = float(periodic_interpolate(*body_values(walls, xb, curve, nu), math.pi))
        if scheme.viscous:
            phi, upper, cf = body_cf(walls, xb, normal, curve, tn, body_centre(P), stream_velocity(P), q_inf)
            out["separation_angle"], out["separation_angle_lower"] = separation_angles(phi, upper, cf)
        return out

    def metrics(p: Particles, t: float, P) -> dict[str, float]:
        out = diagnostics(p, t, P)
        if c["body"] in POINT_BODIES:
            base = rear_on_axis(body_polygon(body, P))
            if float(P[body.key("alpha")]) == 0.0 and base is not None:
                out["recirculation_length"] = axis_recirculation_length(p, P, scheme, base, 2.0 * R, lay.h)
        elif c["layout"] != "polar":
            if c["body"] == "circle" or float(P[body.key("alpha")]) == 0.0:
                base = float(body._axes(P)[0][0]) + float(P[body.key("centre")][0])
                out["recirculation_length"] = axis_recirculation_length(p, P, scheme, base, 2.0 * R, lay.h)
        elif c["body"] == "circle":
            out["recirculation_length"] = recirculation_length(p, P, scheme, R, n_theta)
        elif float(P[body.key("alpha")]) == 0.0:   # at incidence the wake leaves off the layout's rays
            a = float(body._axes(P)[0][0]) + float(P[body.key("centre")][0])
            out["recirculation_length"] = recirculation_length(p, P, scheme, R, n_theta, base=a)
        return out

    def plot(out: Path, p: Particles, t: float, P) -> None:
        _, xb, normal, curve, pb, tn, nu = wall_diagnostics(p, P)     # one wall evaluation for every plot
        plot_cp(Path(out) / "cp.png", *body_cp(walls, xb, curve, pb, p_inf, q_inf), title=_title(cfg, p.n, t),
                references=c["body"] == "circle" and not c["inviscid"])
        if heated:
            plot_nu(Path(out) / "nu.png", *body_values(walls, xb, curve, nu), title=_title(cfg, p.n, t))
        if scheme.viscous:
            plot_cf(Path(out) / "cf.png", *body_cf(walls, xb, normal, curve, tn, body_centre(P),
                                                   stream_velocity(P), q_inf), title=_title(cfg, p.n, t))
        plot_field(Path(out) / "velocity_field.png", p, P, scheme, R, title=_title(cfg, p.n, t),
                   outline=None if c["body"] == "circle" else body_polygon(body, P))

    def series_statistics(series) -> dict:
        if cfg["time"]["local_time_stepping"]:
            return {"note": "local time steps: t is a pseudo-time, no shedding statistics"}
        return shedding_statistics(series, c["transient"], D=2.0 * R)

    return Problem("cylinder", particles, params, scheme, domain, cfg["time"]["t_end"], metrics, plot,
                   config=cfg, description=_title(cfg, particles.n), boundary=boundary, diagnostics=diagnostics,
                   steady_tol=c["steady_tol"], differentiable_metrics=coefficients, particles_at=particles_at,
                   series_statistics=series_statistics)


def shedding_statistics(series, transient: float, D: float) -> dict:
    """Vortex-shedding statistics of a run's time series (module docstring, "Vortex shedding";
    :func:`mlsph_jax.periodic.whole_period_statistics` of C_L after ``transient``): ``metrics``
    ``st`` = f D / U_inf (zero crossings), ``st_spectral`` (interpolated periodogram peak),
    ``cd_mean``, ``cl_mean``, ``cl_amplitude``, ``cl_rms`` and ``n_periods`` over the whole lift
    periods, with their ``window``, ``samples_per_period`` and ``cl_amplitude_drift``; or, with no
    metrics, a ``note`` saying why there are none (too short, no shedding, under-resolved)."""
    w = whole_period_statistics(series["t"], series["cl"], transient, {"cd": series["cd"]})
    if "note" in w:
        return {"transient": float(transient), "note": w["note"], "n_periods": int(w.get("n_periods", 0))}
    metrics = {"st": w["frequency"] * D / U_INF, "st_spectral": w["frequency_spectral"] * D / U_INF,
               "cd_mean": w["means"]["cd"], "cl_mean": w["mean"], "cl_amplitude": w["amplitude"],
               "cl_rms": w["rms"], "n_periods": float(w["n_periods"])}
    return {"transient": float(transient), "metrics": metrics, "window": w["window"],
            "samples_per_period": w["samples_per_period"], "cl_amplitude_drift": w["amplitude_drift"]}


def _check_far_field_apart(walls, p: Particles) -> None:
    """No frozen (far-field) particle may be in the stencil of a wall point (the body would
    exchange fluxes with the imposed free stream directly)."""
    st = walls.stencils(p, walls.points({}).x)
    frozen = np.asarray(p.kind)[np.asarray(st.idx)] == int(Kind.FROZEN)
    if np.any(frozen & np.asarray(st.mask)):
        raise InputError("invalid case.r_far: far-field (frozen) particles lie in the support of the body's wall "
                         "points; allowed: a larger case.r_far or a smaller case.radius")


def _check_line_of_sight(walls, p: Particles, body, params, cfg: Mapping) -> None:
    """No two particles, and no wall point and particle, may be neighbours through the body (a
    body thinner than the particles' support, or a sharp feature the layout does not resolve,
    would pass fluxes and wall-fit samples across it): where the segment between a pair passes
    through the body polygon, the way around the body between them
    (:func:`~mlsph_jax.geometry.checks.detour_around_polygon`) may exceed the straight distance by
    less than :data:`DETOUR_LIMIT` of their support radius (a pair clipping a convex corner adds
    about the corner's depth into the segment, a fraction of a spacing; a pair on the two sides
    of a plate adds the way around its end; a corner sharper than 60 degrees is refused at any
    resolution, see :data:`DETOUR_LIMIT`).  Pairs as the neighbour search makes them, |x_i - x_j| < support
    max(h_i, h_j), h = beta sqrt(V); wall-point stencils as the boundary term uses them (radius
    support h_b), each segment started 1e-3 dGamma_b off the wall into the fluid (the curve's
    polygon is a chordal one)."""
    from scipy.spatial import cKDTree

    poly = body_polygon(body, params)
    x = np.asarray(p.x)
    reach = _support_radius(cfg, 1.0) * np.sqrt(np.asarray(p.vol))      # linear in the spacing
    edge = float(np.max(np.linalg.norm(np.roll(poly, -1, axis=0) - poly, axis=1)))
    near = np.flatnonzero(cKDTree(poly).query(x)[0] < float(reach.max()) + edge)
    pairs = cKDTree(x[near]).query_pairs(float(reach[near].max()), output_type="ndarray")
    i, j = near[pairs[:, 0]], near[pairs[:, 1]]
    limit = np.maximum(reach[i], reach[j])
    keep = np.linalg.norm(x[i] - x[j], axis=1) < limit
    i, j, limit = i[keep], j[keep], limit[keep]
    bad = detour_around_polygon(poly, x[i], x[j]) - np.linalg.norm(x[i] - x[j], axis=1) >= DETOUR_LIMIT * limit
    where = None
    if bad.any():
        k = int(np.argmax(bad))
        where = f"particles {int(i[k])} at {np.round(x[i[k]], 6).tolist()} and {int(j[k])} at " \
                f"{np.round(x[j[k]], 6).tolist()}"
    else:
        bp = walls.points(params)
        st = walls.stencils(p, bp.x)
        on = np.asarray(bp.curve) == [cv.name for cv in walls.curves].index(BODY)
        xb = np.asarray(bp.x) - 1e-3 * np.asarray(bp.dgamma)[:, None] * np.asarray(bp.normal)
        b, s = np.nonzero(np.asarray(st.mask) & on[:, None])
        jj = np.asarray(st.idx)[b, s]
        radius = get_kernel(cfg["scheme"]["kernel"]).support * np.asarray(st.h)[b]
        bad = detour_around_polygon(poly, xb[b], x[jj]) - np.linalg.norm(xb[b] - x[jj], axis=1) >= DETOUR_LIMIT * radius
        if bad.any():
            k = int(np.argmax(bad))
            where = f"wall point {int(b[k])} at {np.round(xb[b[k]], 6).tolist()} and particle {int(jj[k])} at " \
                    f"{np.round(x[jj[k]], 6).tolist()}"
    if where is None:
        return
    c = cfg["case"]
    if c["body"] in POINT_BODIES:
        key = (f"case.body_points={points_text(c['body_points'])} with case.n_theta={c['n_theta']} and "
               f"case.lattice_ratio={show(c['lattice_ratio'])}")
    elif c["body"] == "ellipse":
        key = f"case.aspect={show(c['aspect'])} with case.n_theta={c['n_theta']}"
    else:
        key = f"case.n_theta={c['n_theta']}"
    raise InputError(f"invalid {key}: {where} are neighbours through the body (the way around it between them "
                     f"is longer than the straight line by {DETOUR_LIMIT:g} of their support radius or more: the body "
                     "is thinner than the particles' support there, or has a corner sharper than 60 degrees, so "
                     "fluxes would cross it); allowed: a finer layout (a larger case.n_theta) or a thicker body; a "
                     "corner sharper than 60 degrees is refused at every resolution: round it (e.g. case.body = "
                     "\"spline\" through the points)")


CYLINDER = register_case(
    "cylinder", CYLINDER_KEYS, build, check=check_cylinder, dim=2, particle_count=particle_count,
    defaults_override={"eos.kind": "ideal_gas", "eos.gamma": 1.4, "time.t_end": 30.0, "output.snapshots": 15},
    doc="Flow past a circular cylinder (thesis §4.5.2): a cylinder of radius `radius` in a free stream "
        "at Reynolds number `re` and Mach number `mach`, body-fitted polar layout (or a Cartesian lattice with the "
        "body cut out, or a blend of the two), no-slip body by the "
        "boundary integral of thesis eq. 4.24, frozen free-stream far field beyond `r_far`; drag, lift "
        "and pressure coefficients against thesis Table 4.1.")


def _title(cfg, n: int, t: float | None = None) -> str:
    s, c = cfg["scheme"], cfg["case"]
    when = f", t={t:.4g}" if t is not None else ""
    if c["body"] == "ellipse":
        when += f", ellipse A={c['aspect']:g}, alpha={c['alpha']:g} deg"
    elif c["body"] in POINT_BODIES:
        when += f", {c['body']} of {len(c['body_points'])} points, alpha={c['alpha']:g} deg"
    if c["layout"] != "polar":
        when += f", {c['layout']} layout"
    if c["wall_temperature"] > 0.0:
        when += f", isothermal T_w/T_inf={c['wall_temperature']:g}"
    flow = "Euler" if c["inviscid"] else f"Re={c['re']:g}"
    return (f"cylinder ({flow}, M={c['mach']:g}, {c['n_theta']} on the body, {n} particles{when}): "
            f"{s['method']}, reconstruction degree {s['reconstruction_degree']}")


# --- post-processing ----------------------------------------------------------------------------

def body_values(walls, xb, curve, v):
    """``(theta[Nb], v[Nb])``: the values ``v`` at the body's quadrature points among the walls'
    points ``xb`` (their curve indices ``curve``), theta their angle about the origin."""
    on = np.asarray(curve) == [cv.name for cv in walls.curves].index(BODY)
    x = np.asarray(xb)[on]
    return np.mod(np.arctan2(x[:, 1], x[:, 0]), 2.0 * math.pi), np.asarray(v)[on]


def body_cp(walls, xb, curve, pb, p_inf: float, q_inf: float):
    """``(theta[Nb], cp[Nb])`` of the body's quadrature points with wall pressures ``pb``."""
    theta, p = body_values(walls, xb, curve, pb)
    return theta, (p - p_inf) / q_inf


def body_cf(walls, xb, normal, curve, tn, centre, u_inf, q_inf: float):
    """``(phi[Nb], upper[Nb], cf[Nb])`` at the body's quadrature points: phi the angle from the base
    seen from ``centre`` (0 downstream along ``u_inf``, pi at the front), ``upper`` whether the
    point lies left of the stream, and the skin friction C_f = f_b . s_b / q_inf, f_b = -tau_b n_b
    the viscous traction on the body (``tn`` = tau_b n_b of
    :meth:`~mlsph_jax.wall_integral.BoundaryIntegralWalls.wall_state`, n_b into the body) and s_b
    the unit tangent pointing from the front towards the base along the point's surface (module
    docstring)."""
    on = np.asarray(curve) == [cv.name for cv in walls.curves].index(BODY)
    r = np.asarray(xb)[on] - np.asarray(centre, float)
    n = np.asarray(normal)[on]
    e_d = np.asarray(u_inf, float) / np.linalg.norm(np.asarray(u_inf, float))
    e_l = np.array([-e_d[1], e_d[0]])
    upper = r @ e_l > 0.0
    t_ccw = np.stack([n[:, 1], -n[:, 0]], axis=1)          # counter-clockwise along the body (n into it)
    s = np.where(upper[:, None], -t_ccw, t_ccw)             # front -> base on each surface
    cf = np.sum(-np.asarray(tn)[on] * s, axis=1) / q_inf
    phi = np.arctan2(np.abs(r @ e_l), r @ e_d)              # 0 at the base, pi at the front
    return phi, upper, cf


def separation_angles(phi, upper, cf) -> tuple[float, float]:
    """Separation angles in degrees from the base on the upper and the lower surface (module
    docstring): from each surface's largest C_f towards the base (decreasing ``phi``), the first
    point with C_f <= 0, linear in phi between it and the point before; 0 when C_f stays
    positive down to the base (no separation)."""
    out = []
    for side in (np.asarray(upper), ~np.asarray(upper)):
        ph, f = np.asarray(phi)[side], np.asarray(cf)[side]
        order = np.argsort(-ph)                               # front -> base
        ph, f = ph[order], f[order]
        k0 = int(np.argmax(f))
        below = np.flatnonzero(f[k0:] <= 0.0)
        if f[k0] <= 0.0 or below.size == 0:
            out.append(0.0)
            continue
        k = k0 + int(below[0])
        a = ph[k - 1] + (ph[k] - ph[k - 1]) * f[k - 1] / (f[k - 1] - f[k])
        out.append(float(np.degrees(a)))
    return out[0], out[1]


def periodic_interpolate(theta: np.ndarray, f: np.ndarray, theta0: float) -> float:
    """Cubic Lagrange interpolation at ``theta0`` of a 2 pi-periodic ``f`` sampled at ``theta``
    (the four samples nearest in angle; exact at a sample)."""
    d = np.angle(np.exp(1j * (np.asarray(theta) - theta0)))      # signed angular offsets in (-pi, pi]
    k = np.argsort(np.abs(d))[:4]
    if np.abs(d[k[0]]) < 1e-12:
        return float(f[k[0]])
    xs, ys = d[k], np.asarray(f)[k]
    w = [np.prod([(0.0 - xs[m]) / (xs[j] - xs[m]) for m in range(4) if m != j]) for j in range(4)]
    return float(np.dot(w, ys))


def recirculation_length(p: Particles, P, scheme, radius: float, n_theta: int, base: float | None = None) -> float:
    """L_w / D (module docstring).  ``base``: x of the body's rear point for a mapped (elliptic)
    layout at zero incidence (then x on the axis is the mean x of the two rays, which the map bends
    towards the axis); None: the circle of ``radius``."""
    fluid = np.asarray(p.kind) == int(Kind.FLUID)
    x = np.asarray(p.x)[fluid]
    u = np.asarray(to_primitive(p.U, get_eos(scheme.eos), P).vel)[fluid, 0]
    r = np.hypot(x[:, 0], x[:, 1])
    theta = np.mod(np.arctan2(x[:, 1], x[:, 0]), 2.0 * math.pi)
    dtheta = 2.0 * math.pi / n_theta
    j = np.rint(theta / dtheta - 0.5).astype(int) % n_theta
    up, dn = j == 0, j == n_theta - 1
    ru, rd = r[up], r[dn]
    order_u, order_d = np.argsort(ru), np.argsort(rd)
    rr = ru[order_u]
    ua = 0.5 * (u[up][order_u] + u[dn][order_d])
    xa = rr * math.cos(0.5 * dtheta)
    if base is not None:
        xa = 0.5 * (x[up, 0][order_u] + x[dn, 0][order_d])
        radius = base
    back = np.flatnonzero(ua < 0.0)
    if back.size == 0:
        return 0.0
    ahead = np.flatnonzero((ua >= 0.0) & (np.arange(len(ua)) > back[0]))
    D = 2.0 * float(P[f"geometry.{BODY}.radius"]) if base is not None else 2.0 * radius
    if ahead.size == 0:
        return float((xa[-1] - radius) / D)
    k = int(ahead[0])
    x0 = xa[k - 1] + (xa[k] - xa[k - 1]) * (-ua[k - 1]) / (ua[k] - ua[k - 1])
    return float((x0 - radius) / D)


def rear_on_axis(poly: np.ndarray) -> float | None:
    """The largest x at which the closed polygon ``poly[m, 2]`` meets the axis y = 0 (the body's
    rear on the wake axis), None when it does not reach the axis."""
    a, b = poly, np.roll(poly, -1, axis=0)
    cross = (a[:, 1] <= 0.0) != (b[:, 1] <= 0.0)
    if not cross.any():
        return None
    a, b = a[cross], b[cross]
    return float(np.max(a[:, 0] + (b[:, 0] - a[:, 0]) * (0.0 - a[:, 1]) / (b[:, 1] - a[:, 1])))


def axis_recirculation_length(p: Particles, P, scheme, base: float, D: float, h: float) -> float:
    """L_w / D on a lattice layout (no particle rays on the axis): u_x of the fluid particles
    interpolated linearly (Delaunay, ``scipy.interpolate.LinearNDInterpolator``) at points h / 4
    apart on the wake axis y = 0 from the body's rear point x = ``base``; the first point where u_x
    turns positive again behind the first that flows back (0 when nothing flows back)."""
    from scipy.interpolate import LinearNDInterpolator

    fluid = np.asarray(p.kind) == int(Kind.FLUID)
    x = np.asarray(p.x)[fluid]
    u = np.asarray(to_primitive(p.U, get_eos(scheme.eos), P).vel)[fluid, 0]
    xs = base + 0.25 * h * np.arange(1, int((np.max(x[:, 0]) - base) / (0.25 * h)))
    ua = LinearNDInterpolator(x, u)(np.stack([xs, np.zeros_like(xs)], axis=1))
    ok = np.isfinite(ua)
    xs, ua = xs[ok], ua[ok]
    back = np.flatnonzero(ua < 0.0)
    if back.size == 0:
        return 0.0
    ahead = np.flatnonzero((ua >= 0.0) & (np.arange(len(ua)) > back[0]))
    if ahead.size == 0:
        return float((xs[-1] - base) / D)
    k = int(ahead[0])
    x0 = xs[k - 1] + (xs[k] - xs[k - 1]) * (-ua[k - 1]) / (ua[k] - ua[k - 1])
    return float((x0 - base) / D)


def plot_cp(path: Path, theta, cp, title: str = "", references: bool = True) -> None:
    """C_p(theta) at the wall (theta from the base, thesis Fig. 4.9) with Table 4.1's values (the
    circle's: ``references`` False for another body)."""
    fig, ax = subplots(figsize=(6.0, 4.2))
    order = np.argsort(theta)
    ax.plot(np.degrees(theta[order]), cp[order], "o-", ms=3, label="MLSPH-ALE (wall p_b)")
    for name, (_, front, base) in (ref.TABLE_4_1.items() if references else ()):
        ax.plot([0.0, 180.0, 360.0], [base, front, base], "x", ms=6, label=name)
    _save_angle_plot(fig, ax, path, "theta [deg] (0 = base, 180 = front)", "C_p", title, legend=6)


def _save_angle_plot(fig, ax, path: Path, xlabel: str, ylabel: str, title: str, legend: int) -> None:
    """Labels, grid, legend and title of a wall-distribution plot, then save it."""
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=legend)
    ax.set_title(title, fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def plot_cf(path: Path, phi, upper, cf, title: str = "") -> None:
    """Skin friction C_f against the angle from the base on both surfaces, the separation points
    marked."""
    fig, ax = subplots(figsize=(6.0, 4.2))
    upper = np.asarray(upper)
    for side, name, mark in ((upper, "upper", "o-"), (~upper, "lower", "s--")):
        order = np.argsort(phi[side])
        ax.plot(np.degrees(phi[side][order]), cf[side][order], mark, ms=3, label=f"{name} surface")
    for a in separation_angles(phi, upper, cf):
        if a > 0.0:
            ax.axvline(a, color="0.5", lw=0.8)
    ax.axhline(0.0, color="k", lw=0.6)
    _save_angle_plot(fig, ax, path, "angle from the base [deg] (0 = base, 180 = front)", "C_f", title, legend=7)


def plot_nu(path: Path, theta, nu, title: str = "") -> None:
    """Local Nusselt number q_b D / (k (T_w - T_inf)) of an isothermal body against theta."""
    fig, ax = subplots(figsize=(6.0, 4.2))
    order = np.argsort(theta)
    ax.plot(np.degrees(theta[order]), nu[order], "o-", ms=3, label="MLSPH-ALE (isothermal wall)")
    _save_angle_plot(fig, ax, path, "theta [deg] (0 = base, 180 = front)", "local Nu", title, legend=7)


def plot_field(path: Path, p: Particles, P, scheme, radius: float, title: str = "", grid: int = 161,
               outline=None) -> None:
    """Speed contours with streamlines near the body (thesis Fig. 4.8), the particle velocities
    interpolated linearly (``scipy.interpolate.griddata``) onto a grid of [-2D, 5D] x [-2D, 2D]."""
    from scipy.interpolate import griddata

    pr = to_primitive(p.U, get_eos(scheme.eos), P)
    x, vel = np.asarray(p.x), np.asarray(pr.vel)
    D = 2.0 * radius
    gx, gy = np.linspace(-2 * D, 5 * D, grid), np.linspace(-2 * D, 2 * D, grid * 4 // 7)
    X, Y = np.meshgrid(gx, gy)
    U = griddata(x, vel[:, 0], (X, Y), method="linear")
    V = griddata(x, vel[:, 1], (X, Y), method="linear")
    if outline is None:
        inside = np.hypot(X, Y) < radius
    else:
        from matplotlib.path import Path as Outline

        inside = Outline(outline).contains_points(np.c_[X.ravel(), Y.ravel()]).reshape(X.shape)
    U[inside] = V[inside] = np.nan
    fig, ax = subplots(figsize=(8.0, 4.0))
    cs = ax.contourf(X / D, Y / D, np.hypot(U, V), levels=24, cmap="viridis")
    fig.colorbar(cs, ax=ax, label="|u| / U_inf")
    ax.streamplot(gx / D, gy / D, np.nan_to_num(U), np.nan_to_num(V), density=1.4, color="w", linewidth=0.5,
                  arrowsize=0.5)
    from matplotlib.patches import Circle as Disc
    from matplotlib.patches import Polygon as Patch

    ax.add_patch(Disc((0.0, 0.0), radius / D, color="0.6") if outline is None
                 else Patch(np.asarray(outline) / D, closed=True, color="0.6"))
    ax.set_aspect("equal")
    ax.set_xlabel("x / D")
    ax.set_ylabel("y / D")
    ax.set_title(title, fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
