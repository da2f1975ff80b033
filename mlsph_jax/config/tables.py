"""The config tables shared by every case: ``[scheme]``, ``[time]``, ``[output]``, ``[physics]``,
the ``[eos]`` keys of each equation of state, and the two selector keys ``case.name`` and
``eos.kind``.

Keys that name a component (a method, kernel, flux, frame, limiter, EOS, case, ...) take their
allowed values from the component registries (:func:`mlsph_jax.registry.names_of`), the only
list of those names: a component a user registers is accepted by the config at once.  Numerical
defaults that depend on a component (the smoothing-length factor of a method) belong to the
component, not to this module (:func:`effective_beta`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from ..registry import names_of, registry
from ..schema import REQUIRED, Key
from ..scheme import GEOMETRY_UPDATES
from ..spatial import DECOMPOSITIONS

__all__ = ["CASE_NAME", "EOS_KIND", "EOS_SCHEMAS", "OUTPUT_KEYS", "PHYSICS_KEYS", "RUN_KEYS", "SCHEMA_COMMON",
           "SCHEME_KEYS", "TABLES", "TABLE_DOCS", "TIME_KEYS", "all_eos_keys", "effective_beta", "eos_keys"]

#: The tables of a config, in the order a resolved config holds them.
TABLES = ("case", "scheme", "eos", "physics", "time", "output", "run")

TABLE_DOCS = {
    "case": "The test case: `name` selects the case; its other keys depend on the case.",
    "scheme": "The numerical method: approximation, reconstruction, flux, frame, limiter.",
    "eos": "Equation of state: `kind` selects the EOS; its other keys depend on the kind.",
    "physics": "Physical parameters shared by all cases.",
    "time": "Time integration (SSP-RK3) and time-step control.",
    "output": "What the run writes (snapshots, plots) and shows (progress).",
    "run": "Where the run executes: devices (sharding over the particle axis); no effect on the numbers "
           "beyond round-off.",
}

#: ``[scheme]``: the numerical method.
SCHEME_KEYS: dict[str, Key] = {
    "method": Key(str, "mlsph_ale", choices=names_of("scheme.method"),
                  doc="particle method: MLSPH-ALE (MLS areas, thesis ch. 4) or kernel SPH-ALE "
                      "(thesis ch. 3)"),
    "approximation": Key(str, "mls", choices=names_of("scheme.approximation"),
                         doc="shape functions used for the area vectors in mlsph_ale: MLS, "
                             "kernel W*V, Shepard W/sum(W), or corrected kernel"),
    "degree": Key(int, 2, minimum=0, maximum=3,
                  doc="degree of the MLS polynomial basis (0 constant, 1 linear, 2 quadratic, "
                      "3 cubic)"),
    "kernel": Key(str, "cubic_spline",
                  choices=names_of("scheme.kernel"),
                  doc="smoothing kernel (also the MLS weight function)"),
    "beta": Key(float, 0.0, minimum=0.0, note="0 = method default",
                doc="smoothing-length factor, h_i = beta V_i^(1/d); 0 selects the method "
                    "default (1.5 for mlsph_ale, 2.0 for sph_ale)"),
    "derivative": Key(str, "full", choices=("full", "fixed_centre"),
                      doc="MLS shape-function derivatives: full (exact derivative of N_j) or "
                          "fixed_centre (diffuse, moment matrix frozen at the centre)"),
    "reconstruction_degree": Key(int, 2, minimum=0, maximum=3,
                                 doc="degree of the MLS reconstruction of the Riemann states "
                                     "at the pair midpoints (0 = first order, no "
                                     "reconstruction)"),
    "reconstruction": Key(str, "taylor", choices=names_of("scheme.reconstruction"),
                          doc="Riemann-state reconstruction at x_ij: taylor = U_i plus the MLS "
                              "derivatives of U at x_i (thesis eq. 3.11; stable on irregular "
                              "layouts), mls_direct = the MLS fit of the stencil evaluated at "
                              "x_ij (eq. 4.39 read literally; unstable on jittered layouts)"),
    "reconstruction_variables": Key(str, "conservative", choices=names_of("scheme.reconstruction_variables"),
                                    doc="variables reconstructed at the pair midpoints"),
    "low_mach_reconstruction": Key(str, "none", choices=names_of("scheme.low_mach_reconstruction"),
                                   doc="low-Mach correction of the reconstructed Riemann states, applied "
                                       "before any flux: none, or thornber (Thornber et al. 2008, JCP 227: "
                                       "the velocity jump scaled by z = min(1, M_loc); no change for "
                                       "M_loc >= 1)"),
    "flux": Key(str, "rusanov", choices=names_of("scheme.flux"),
                doc="numerical (Riemann) flux at the pair midpoints: rusanov (thesis), hllc (Toro 2009 "
                    "ch. 10, Davis wave speeds, any EOS), hllc_lm (HLLC-LM of Fleischmann, Adami & Adams "
                    "2020, JCP 423: acoustic terms scaled by phi = sin(min(1, M_loc/M_ref) pi/2), needs "
                    "reference_mach), hllc_zha (HLLC with the star-pressure dissipation limited after "
                    "Zhang, Hu & Adams 2017, JCP 335); each low-Mach flux is hllc for M_loc >= 1"),
    "reference_mach": Key(float, 0.0, minimum=0.0, maximum=1.0, note="0 = not given",
                          doc="reference (cutoff) Mach number M_ref of the options that need one "
                              "(hllc_lm: 0.1 in Fleischmann et al. 2020); must be 0 when no option "
                              "in use reads it"),
    "parachute_flux": Key(str, "same", choices=lambda: ["same", *registry("scheme.flux").names()],
                          doc="flux of the pairs MOOD reconstructs at first order (min(ppd_i, ppd_j) "
                              "= 0): same (the scheme's flux) or a registered flux, e.g. rusanov "
                              "(needs limiter = mood)"),
    "wave_speed": Key(str, "rusanov_abs", choices=names_of("scheme.wave_speed"),
                      doc="Rusanov wave-speed estimate (read by rusanov only): max(|(u-w).n|+c) (standard), or the "
                          "signed formulas printed in thesis ch. 3 / ch. 4 (reproduction "
                          "studies)"),
    "dissipation_normal": Key(str, "area", choices=names_of("scheme.dissipation_normal"),
                              doc="normal of the Rusanov dissipation term: A_ij/|A_ij| (area) "
                                  "or the unit vector between the particles (pair); read by rusanov "
                                  "only (the HLLC fluxes use A_ij/|A_ij|)"),
    "area_correction": Key(str, "none", choices=names_of("scheme.area_correction"),
                           doc="correction of the MLSPH-ALE area vectors A_ij (decision 59): none (thesis "
                               "eq. 4.36, one-point quadrature), or the smallest antisymmetric correction "
                               "making the midpoint divergence exact for fluxes of degree <= 1 (linear) or <= 2 "
                               "(quadratic) on any layout (one CG solve per geometry); linear_interior / "
                               "quadratic_interior impose it only on complete stencils (uncorrected "
                               "closure <= 0.05 V/h; decision 88); linear_complete / quadratic_complete "
                               "impose it on the fluid rows with no boundary-integral wall term (frozen, "
                               "ghost and wall rows left free; for bodies in a stream and irregular clouds, "
                               "decision 92)"),
    "self_flux": Key(bool, True,
                     doc="include the self-flux term -F_i.sum_j A_ij (thesis default; keeps "
                         "uniform states exact, conserves only up to a quadrature defect)"),
    "conservation_projection": Key(bool, False,
                                   doc="with the self-flux term: subtract V_i R / sum V from every fluid row of "
                                       "d(VU)/dt (moving frames: also V_i R_V / sum V from dV/dt), R the fluid "
                                       "rows' sum of the terms that are not pair or wall fluxes (the self term, "
                                       "the wall bracket's s F.beta, the wall rows' first-moment correction), so "
                                       "the totals of V U (mass, momentum, energy) and V change only by the wall "
                                       "fluxes and sources, to round-off, and uniform states stay exact "
                                       "(decision 112); refused with scheme.self_flux = false, with particles "
                                       "that are not fluid (mirror ghosts, frozen far field), open "
                                       "boundary-integral walls, time.local_time_stepping and "
                                       "run.decomposition = \"spatial\""),
    "ghost_shear_dissipation": Key(bool, True,
                                   doc="mirror-ghost walls: the numerical flux of a fluid-ghost pair "
                                       "dissipates the jump of the wall-tangential velocity too (true, "
                                       "thesis), or that jump is removed before the flux (false: no "
                                       "inviscid wall friction, the wall's tangential force is the viscous "
                                       "stress alone; single-wall ghosts of no-slip and slip walls alike, corner "
                                       "ghosts untouched; docs/architecture.md decision 81); no effect without "
                                       "mirror ghosts; refused with run.decomposition = \"spatial\""),
    "frame": Key(str, "eulerian", choices=names_of("scheme.frame"),
                 doc="ALE frame velocity: eulerian (w = 0, particles fixed), lagrangian "
                     "(w = u) or ale_shift (w = u + particle-shifting drift, docs/architecture.md decision 24)"),
    "shift_law": Key(str, "xu", choices=names_of("scheme.shift_law"),
                     doc="drift law of the ale_shift frame: xu (repulsion C U_max sum_j (r_i/r_ij)^2 "
                         "e_ji / n_i, Xu et al. 2009 type; jumps where a neighbour crosses the support edge, "
                         "which makes SSP-RK3 order ~1 in dt), xu_smooth (the same with the weights tapered by "
                         "(1 - r_ij^2/R_i^2)^2: third order in dt, decision 80) or fickian (-C U_max h_i sum_j V_j "
                         "grad W_ij, smooth where "
                         "neighbours cross the support edge)"),
    "shift_coefficient": Key(float, 0.02, minimum=0.0,
                             doc="coefficient C of the ale_shift drift (every law of scheme.shift_law; "
                                 "mlsph_jax.rhs.shifting_velocity)"),
    "stress": Key(str, "stokes", choices=names_of("scheme.stress"),
                  doc="viscous stress: stokes (mu (grad u + grad u^T - 2/3 div u I)) or "
                      "incompressible (no -2/3 div u term, thesis ch. 3)"),
    "geometry_update": Key(str, "stage", choices=GEOMETRY_UPDATES,
                           doc="moving frames: neighbour list and geometry (area vectors, fit) at every "
                               "Runge-Kutta stage (stage, default; exact SSP-RK3) or once per step at the "
                               "step's start positions, reused by its three stages (step: opt-in, about "
                               "half the cost of a moving step, but SSP-RK3 is then first order in time: "
                               "measured, docs/performance.md, decision 79); no effect in the eulerian frame"),
    "position_update": Key(str, "w_i", choices=names_of("scheme.position_update"),
                           doc="velocity that moves the particles in the lagrangian and ale_shift frames, "
                               "also used by their fluxes (eq. 4.36) and volumes (eq. 4.32): the "
                               "particle's own w_i (default), the method's interpolant of the frame "
                               "velocity (thesis eq. 4.28: MLS for mlsph_ale, Shepard T(3.7) for "
                               "sph_ale) or its Shepard average, plus the shifting drift "
                               "(architecture decision 44, docs/moving_particles.md)"),
    "rcond": Key(float, 1e-2, minimum=0.0, maximum=1.0, exclusive_maximum=True,
                 doc="MLS degree fallback: a degree level is dropped when a pivot ratio "
                     "s_j / M_jj of its monomials falls below rcond (architecture decision 2; "
                     "lattice stencils have >= 0.2, stretched moving-particle stencils reach "
                     "1e-3, docs/moving_particles.md)"),
    "wall_rcond": Key(float, 0.1, minimum=0.0, maximum=1.0, exclusive_maximum=True,
                      doc="pivot-ratio threshold of the MLS fits (area shape functions, reconstruction/"
                          "viscous fit) whose stencil a boundary truncates (kernel sum sum_j V_j W_ij < "
                          "0.9: the rows at boundary-integral walls, the edge of a frozen far field; "
                          "mirror ghosts complete the stencils at their walls) and of the fits at wall "
                          "points; max(rcond, wall_rcond) is used. "
                          "One-sided cubic fits with pivot ratios 0.01-0.1 blew up at the impulsive "
                          "start of the cylinder (architecture decisions 75, 77)"),
    "limiter": Key(str, "none", choices=names_of("scheme.limiter"),
                   doc="a-posteriori limiter: none or MOOD (local reduction of the "
                       "reconstruction degree)"),
    "mood_variables": Key(list, ["rho", "p"], item_type=str, choices=names_of("scheme.mood_variables"),
                          doc="variables checked by the MOOD NAD detector (relaxed discrete maximum "
                              "principle, thesis eq. 3.12); vel = every velocity component, "
                              "conservative = every component of U"),
    "mood_delta_abs": Key(float, 1e-4, minimum=0.0,
                          doc="absolute NAD tolerance floor (thesis eq. 3.13; in the variable's units)"),
    "mood_delta_floor": Key(str, "scaled", choices=names_of("scheme.mood_delta_floor"),
                            doc="NAD floor: scaled = mood_delta_abs * max |phi| over all particles "
                                "(default; unit-free), absolute = mood_delta_abs as printed in "
                                "thesis eq. 3.13 (in the variable's units: Pa, kg/m^3)"),
    "mood_delta_rel": Key(float, 1e-3, minimum=0.0,
                          doc="NAD tolerance relative to the stencil range max - min (thesis eq. 3.13)"),
    "mood_pad": Key(bool, True, doc="MOOD physical-admissibility detector (finite, rho > 0; p > 0 for "
                                    "the ideal gas, p + pc > 0 for the stiffened gas)"),
    "mood_nad": Key(bool, True, doc="MOOD numerical-admissibility detector (no new extrema)"),
    "mood_max_iter": Key(int, 8, minimum=1,
                         doc="bound on the MOOD detect-and-demote iterations per Runge-Kutta stage"),
    "neighbor_headroom": Key(float, 1.3, minimum=1.0,
                             doc="moving particles: neighbour-list capacity as a multiple of the largest "
                                 "initial neighbour count (fixed, Eulerian particles get their largest count: "
                                 "their list never changes, decision 91)"),
    "moving_neighbor_headroom": Key(float, 0.0, minimum=0.0,
                                    doc="moving frames, chunked driver: the smallest neighbour-list headroom "
                                        "(max of this and neighbor_headroom); 0 = automatic (2.0 in 1D, 1.3 "
                                        "otherwise, decision 84: an overflow regrows the capacity and recompiles, "
                                        "never drops a neighbour). A higher value (e.g. 1.6) leaves a compressing "
                                        "flow room before it regrows; every padding slot costs every pass over "
                                        "the stencil (docs/performance.md); it scales the cell capacity too; the "
                                        "same numbers to round-off (bitwise in the measured runs)"),
}


#: ``[time]``: time integration and time-step control.
TIME_KEYS: dict[str, Key] = {
    "t_end": Key(float, minimum=0.0, exclusive_minimum=True, unit="s",
                 doc="final physical time"),
    "cfl": Key(float, 0.3, minimum=0.0, maximum=1.0, exclusive_minimum=True,
               doc="CFL number C in dt = C min_i dx_i / (|u_i - w_i| + c_i)"),
    "cfl_viscous": Key(float, 0.125, minimum=0.0, maximum=1.0, exclusive_minimum=True,
                       doc="diffusive time-step factor: dt <= cfl_viscous min_i rho_i dx_i^2 / max(mu, kappa)"),
    "dt": Key(float, 0.0, minimum=0.0, unit="s", note="0 = adaptive",
              doc="fixed time step; 0 selects the adaptive CFL step"),
    "max_steps": Key(int, 1_000_000, minimum=1,
                     doc="the run stops (exit 1) after exactly this many time steps if t_end is not reached; "
                         "continue it with `mlsph run --restart DIR --set time.max_steps=...`"),
    "chunk": Key(int, 50, minimum=1,
                 doc="time steps per jitted scan chunk (output, progress and neighbour checks "
                     "happen between chunks)"),
    "local_time_stepping": Key(bool, False,
                               doc="steady runs only: every fluid particle advances by its own CFL step and t by "
                                   "the smallest (pseudo-time; the transient is not time-accurate); needs time.dt = 0 "
                                   "and scheme.frame = 'eulerian'; differentiated runs (sensitivity, calibrate) "
                                   "refuse it: --set time.local_time_stepping=false (architecture decision 62)"),
    "local_step_ratio": Key(float, 4.0, minimum=1.0,
                            doc="with time.local_time_stepping: the largest ratio of a particle's step to the "
                                "smallest (uncapped steps diverged on the cylinder at r_far = 40 D; 1 = the "
                                "global step)"),
    "dt_min": Key(float, 1e-14, minimum=0.0, maximum=1.0, exclusive_minimum=True,
                  exclusive_maximum=True,
                  doc="time-step underflow threshold relative to t_end: the run fails if "
                      "dt < dt_min * t_end"),
}


def local_time_stepping_conflict(dt: float, frame: str) -> str | None:
    """Why ``time.local_time_stepping`` cannot run with the fixed step ``dt`` or ``scheme.frame``
    (None if it can): the config check and :class:`mlsph_jax.simulation.Simulation` share it."""
    if dt > 0:
        return f"time.dt={dt!r} fixes one step for every particle"
    if frame != "eulerian":
        return f"scheme.frame={frame!r} moves the particles (their positions would advance by different steps)"
    return None


#: what ``time.local_time_stepping = true`` needs (the end of its error message)
LOCAL_TIME_STEPPING_ALLOWED = ("local time stepping with the adaptive step (time.dt = 0) and scheme.frame = "
                               "'eulerian' (or time.local_time_stepping = false)")


#: ``[output]``: what a run writes and shows.
OUTPUT_KEYS: dict[str, Key] = {
    "snapshots": Key(int, 10, minimum=1,
                     doc="number of snapshots written besides the initial one (equally spaced "
                         "in time)"),
    "series_interval": Key(float, 0.0, minimum=0.0, unit="s", note="0 = at the output times only",
                           doc="time between two samples of the time series (the case's diagnostics, e.g. the "
                               "cylinder's C_D and C_L: timeseries.csv, summary.json timeseries and "
                               "series_statistics), recorded without writing a snapshot; must divide the output "
                               "interval t_end / snapshots, so the samples are uniform and include the output "
                               "times. Each sample time is a step target like an output time (the step before it "
                               "is shortened to reach it): the steps equal those of a run with outputs at every "
                               "sample time (the steady-state stop still tests only the outputs, so with "
                               "case.steady_tol > 0 the stop can differ). "
                               "With time.local_time_stepping the samples are at pseudo-times (a convergence "
                               "history)"),
    "plots": Key(bool, True, doc="write PNG plots at the end of the run"),
    "progress": Key(bool, True, doc="show a progress bar during the run"),
    "degree_fallback_warn": Key(float, 0.01, minimum=0.0, maximum=1.0, note="1 = never warn",
                                doc="warn (DegreeFallbackWarning; one line from mlsph run) when, in some step, a "
                                    "larger fraction of the fluid particles than this has a reduced approximation "
                                    "degree: MLS degree fallback (pivot ratio < scheme.rcond, scheme.wall_rcond in "
                                    "truncated stencils) of the area shape "
                                    "functions or of the reconstruction/viscous fit, the corrected -> kernel "
                                    "gradient fallback, or exactly-zero fixed-centre derivatives at degree 0 "
                                    "(fractions in summary.json degree_fallback, per-particle degrees in fields.h5)"),
}


#: relative mismatch of ``output.series_interval`` against a whole fraction of the output interval
#: that is taken for round-off (0.25 in a 5.0 interval is exact; 0.1 in 1/3 is not a divisor)
SERIES_RTOL = 1e-9


def series_per_output(t_end: float, snapshots: int, interval: float) -> tuple[int, str | None]:
    """``(m, None)``: ``output.series_interval`` = ``interval`` samples the time series ``m``
    times per output interval t_end / snapshots (m = 1 for ``interval`` = 0: at the output times);
    ``(0, why)`` when it cannot (negative, not finite, longer than the output interval or not a
    whole fraction of it).  The config check and :class:`mlsph_jax.simulation.Simulation` share it."""
    if isinstance(interval, bool) or not isinstance(interval, int | float) or not math.isfinite(interval) \
            or interval < 0:
        return 0, "not a finite number >= 0"
    if interval == 0:
        return 1, None
    out = t_end / snapshots
    m = round(out / interval)
    if m < 1 or abs(m * interval - out) > SERIES_RTOL * out:
        return 0, (f"not a whole fraction of the output interval time.t_end / output.snapshots = {t_end!r} / "
                   f"{snapshots} = {out!r}")
    if snapshots * m > MAX_SERIES_SAMPLES:
        return 0, (f"{snapshots * m} samples (time.t_end / output.series_interval), more than "
                   f"{MAX_SERIES_SAMPLES}: each sample ends a compiled chunk on the host")
    return m, None


#: the most time-series samples a run may take (each ends a compiled chunk and runs the diagnostics)
MAX_SERIES_SAMPLES = 100_000


def series_allowed(t_end: float, snapshots: int, interval: float | None = None) -> str:
    """What ``output.series_interval`` may be for this end time and output count (error messages),
    and, for an ``interval`` that divides t_end, the output counts that would take it."""
    out = t_end / snapshots
    text = (f"0 (samples at the output times) or the output interval {out!r} divided by a whole number "
            f"(e.g. {out / 2!r}, {out / 10!r}), at most {MAX_SERIES_SAMPLES} samples in all")
    if interval and math.isfinite(interval) and interval > 0:
        total = t_end / interval
        n = round(total)
        if n >= 1 and abs(n - total) <= SERIES_RTOL * total:
            fits = [k for k in range(1, min(n, 2000) + 1) if n % k == 0 and k <= 1000]
            near = sorted(fits, key=lambda k: abs(k - snapshots))[:3]
            text += (f"; or keep it and set output.snapshots to a divisor of time.t_end / output.series_interval "
                     f"= {n} (e.g. {', '.join(str(k) for k in sorted(near))})")
        else:
            text += "; or change output.snapshots"
    else:
        text += "; or change output.snapshots"
    return text


#: ``[run]``: execution (devices); docs/performance.md.
RUN_KEYS: dict[str, Key] = {
    "devices": Key(int, 1, minimum=0, note="0 = every available device",
                   doc="devices the particle state is sharded over (jax.sharding, 1-D mesh on the particle "
                       "axis, mlsph_jax.sharding); must divide the particle count (run.decomposition = index) "
                       "and not exceed len(jax.devices()) (host devices: "
                       "XLA_FLAGS=--xla_force_host_platform_device_count=N; several hosts: "
                       "jax.distributed.initialize)"),
    "decomposition": Key(str, "index", choices=DECOMPOSITIONS,
                         doc="how run.devices > 1 splits the particles: index = index ranges, XLA's SPMD "
                             "partitioner all-gathers the fields each stage (every frame); spatial = Morton-ordered "
                             "compact regions with a two-stencil halo exchanged by jax.shard_map collectives "
                             "(Eulerian frame, no MOOD, no boundary-integral walls, no local time stepping; "
                             "docs/performance.md)"),
    "precision": Key(str, "float64", choices=("float64", "float32"),
                     doc="floating-point precision of the particle state, the parameters and the geometry; "
                         "float32 keeps the MLS moment matrices and their solves and the Tait pressure in "
                         "float64 (docs/performance.md: its accuracy and speed)"),
    "max_particles": Key(int, 200_000, minimum=1,
                         doc="largest particle count (fluid, walls and far field) of a run: a config whose count, "
                             "estimated from the config before any array is built (each case's particle_count), "
                             "exceeds it is refused at load, naming the keys that set the count, the estimate and "
                             "this limit; the built count is checked again after building. Raise it for a "
                             "deliberately large run (built-in configs: at most ~10,000 particles, blast_2d; the "
                             "thesis' cylinder 10,800; case.layout = \"cartesian\" on configs/cylinder.toml ~3.3 "
                             "million)"),
}


#: ``[physics]``: physical parameters shared by all cases.
PHYSICS_KEYS: dict[str, Key] = {
    "mu": Key(float, 0.0, minimum=0.0, unit="Pa s",
              doc="dynamic viscosity (0 = inviscid Euler equations)"),
    "kappa": Key(float, 0.0, minimum=0.0, unit="kg/(m s)",
                 doc="heat conduction coefficient k/c_v of q = -kappa grad e (0 = none; must be 0 "
                     "for the Tait EOS, which has no energy equation)"),
    "body_force": Key(list, [], item_type=float, unit="m/s^2",
                      note="empty, or one component per space dimension",
                      doc="body-force acceleration vector (empty = no body force)"),
}

#: The ``[eos]`` keys of the built-in equations of state (besides ``kind``), by ``eos.kind``.  The
#: keys of an EOS registered from a user's script are derived from it (:func:`eos_keys`).
EOS_SCHEMAS: dict[str, dict[str, Key]] = {
    "ideal_gas": {
        "gamma": Key(float, 1.4, minimum=1.0, exclusive_minimum=True,
                     doc="ratio of specific heats, p = (gamma - 1) rho e"),
    },
    "tait": {
        "rho0": Key(float, minimum=0.0, exclusive_minimum=True, unit="kg/m^3",
                    doc="reference density"),
        "c0": Key(float, minimum=0.0, exclusive_minimum=True, unit="m/s",
                  doc="sound speed at the reference density"),
        "gamma": Key(float, 7.0, minimum=0.0, exclusive_minimum=True,
                     doc="Tait exponent, p = rho0 c0^2/gamma ((rho/rho0)^gamma - 1) + p0"),
        "p0": Key(float, 0.0, unit="Pa", doc="background pressure added to the Tait pressure"),
    },
    "stiffened_gas": {
        "gamma": Key(float, minimum=1.0, exclusive_minimum=True,
                     doc="Tammann exponent, p = (gamma - 1) rho e - gamma pc"),
        "pc": Key(float, minimum=0.0, unit="Pa", doc="stiffening pressure"),
    },
}

#: The ``[eos].kind`` key: a registered EOS (:data:`mlsph_jax.eos.EOS_REGISTRY`); its other
#: ``[eos]`` keys are :func:`eos_keys`.
EOS_KIND = Key(str, "ideal_gas", choices=names_of("eos.kind"),
               doc="equation of state; selects the other [eos] keys")

#: The ``[case].name`` key: a registered case (:data:`mlsph_jax.cases.CASES`), which declares
#: the other ``[case]`` keys.
CASE_NAME = Key(str, REQUIRED, choices=names_of("case.name"),
                doc="the test case; selects the other [case] keys")

#: The tables that do not depend on the case or the EOS.
SCHEMA_COMMON: dict[str, dict[str, Key]] = {
    "scheme": SCHEME_KEYS, "time": TIME_KEYS, "output": OUTPUT_KEYS, "physics": PHYSICS_KEYS, "run": RUN_KEYS}


def eos_keys(kind: str) -> dict[str, Key]:
    """The ``[eos]`` keys (besides ``kind``) of the registered EOS ``kind``: :data:`EOS_SCHEMAS` for
    a built-in one; for one registered from a user's script, a float key per ``eos.*`` entry of its
    ``params_keys``, with its ``defaults`` where given (required otherwise)."""
    if kind in EOS_SCHEMAS:
        return EOS_SCHEMAS[kind]
    eos = registry("eos.kind").get(kind)
    defaults = getattr(eos, "defaults", None) or {}
    return {k.partition(".")[2]: Key(float, defaults.get(k, REQUIRED), doc=f"parameter {k} of the EOS {kind!r}")
            for k in eos.params_keys if k.startswith("eos.")}


def all_eos_keys() -> dict[str, dict[str, Key]]:
    """:func:`eos_keys` of every registered EOS, by kind (built-in ones first, in their order)."""
    kinds = [*EOS_SCHEMAS, *(k for k in registry("eos.kind").names() if k not in EOS_SCHEMAS)]
    return {k: eos_keys(k) for k in kinds}


def effective_beta(scheme: Mapping) -> float:
    """Smoothing-length factor of a resolved ``[scheme]`` table (``beta = 0``: the method's default)."""
    from ..scheme import default_beta  # the numerics own the default (and import nothing from config)

    return float(scheme["beta"]) or float(default_beta(scheme["method"]))
