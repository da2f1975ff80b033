"""SSP-RK3 time integration with a CFL step, chunked ``lax.scan`` stepping and health checks.

Shu–Osher SSP-RK3 for y = (x, V, V U) (SPEC §7.1):

    y1 = y + dt L(y);  y2 = 3/4 y + 1/4 (y1 + dt L(y1));  y' = 1/3 y + 2/3 (y2 + dt L(y2))

CFL step (SPEC §7.1, [REC]): dt = C min_i dx_i / (|u_i - w_i| + c_i) over fluid particles,
dx_i = V_i^(1/d); clipped so that output times are hit exactly.

A chunk of ``n`` steps is one jitted ``lax.scan`` (no host synchronisation inside).  Each step
checks the candidate state; a failing step is *not committed*: the carry keeps the last good
state and a status code, and later steps of the chunk are no-ops.  The host inspects the status
between chunks (see :mod:`mlsph_jax.simulation`).
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp

from . import fallback, verlet
from . import neighbors as nb
from .area_correction import complete_rows, wants_complete_rows
from .eos import get_eos, to_primitive
from .kernels import safe_norm
from .rhs import Geometry, frame_velocity, geometry, rhs
from .scheme import Scheme
from .state import Domain, Kind, Params, Particles, tiny
from .status import Status, combine, first_index, state_status

__all__ = ["MOOD_STATS", "Carry", "LocalOps", "Status", "StepControl", "cfl_dt", "cfl_limiting_particle",
           "initial_carry", "local_steps", "make_chunk", "make_stage_geometry", "make_verlet_stage_geometry",
           "ssp_rk3_step", "state_status", "static_geometry", "step_status"]


@dataclasses.dataclass(frozen=True)
class StepControl:
    """Static time-step settings: CFL number, fixed step (0 = adaptive), underflow threshold."""

    cfl: float = 0.3
    cfl_viscous: float = 0.125
    dt_fixed: float = 0.0
    dt_min: float = 0.0
    #: local time stepping (``time.local_time_stepping``, decision 62): every fluid particle
    #: advances by its own CFL step (:func:`local_steps`), at most ``local_ratio`` times the
    #: smallest (``time.local_step_ratio``); ``t`` advances by the smallest one
    local: bool = False
    local_ratio: float = 4.0


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Carry:
    """Scan carry: state, time, step counter, status code and the first offending particle,
    the last step and the MOOD statistics; ``degree[N, 2]`` the smallest active degree of the
    area shape functions and of the fit over the stages of the last step (-1: none, or no step
    yet) and ``fallback`` the reduced-degree statistics (:mod:`mlsph_jax.fallback`)."""

    particles: Particles
    t: jax.Array
    step: jax.Array
    status: jax.Array
    bad_particle: jax.Array
    dt_last: jax.Array
    mood: jax.Array
    degree: jax.Array
    fallback: jax.Array

#: Entries of ``Carry.mood`` (MOOD statistics accumulated over committed steps).
MOOD_STATS = ("flagged_fraction_max", "flagged_fraction_sum", "rhs_evaluations", "unresolved_stages")


def cfl_dt(particles: Particles, params: Params, scheme: Scheme, cfl: float, cfl_viscous: float = 0.125):
    """C min_i V_i^(1/d) / (|u_i - w_i| + c_i) over fluid particles (SPEC §7.1), and with viscous
    (heat) fluxes also C_v min_i rho_i dx_i^2 / mu (kappa) (explicit diffusion limit): the
    smallest of the per-particle limits of :func:`particle_limits`."""
    return jnp.min(particle_limits(particles, params, scheme, cfl, cfl_viscous))


def _diffusivity(particles: Particles, params: Params, scheme: Scheme):
    """max(mu, kappa) of the active diffusive terms (floored at the dtype's tiny)."""
    diff = jnp.zeros((), particles.q.dtype)
    if scheme.viscous:
        diff = diff + params["physics.mu"]
    if scheme.heat_conduction and "physics.kappa" in params:
        diff = jnp.maximum(diff, params["physics.kappa"])
    return jnp.maximum(diff, tiny(diff.dtype))


def particle_limits(particles: Particles, params: Params, scheme: Scheme, cfl: float, cfl_viscous: float = 0.125):
    """Each fluid particle's explicit step limit, min(C dx_i / (|u_i - w_i| + c_i), C_v rho_i
    dx_i^2 / max(mu, kappa)) (the second only with viscous or heat fluxes); +inf for every other
    particle.  :func:`cfl_dt` is their minimum, :func:`local_steps` starts from them."""
    dt = cfl * _local_dt(particles, params, scheme)
    if scheme.viscous or scheme.heat_conduction:
        rho = particles.q[:, 0] / particles.vol
        dx2 = particles.vol ** (2.0 / particles.dim)
        dt = jnp.minimum(dt, cfl_viscous * rho * dx2 / _diffusivity(particles, params, scheme))
    return jnp.where(particles.kind == Kind.FLUID, dt, jnp.inf)


def local_steps(particles: Particles, params: Params, scheme: Scheme, cfl: float, cfl_viscous: float = 0.125,
                geom: Geometry | None = None, ratio: float | None = None):
    """Per-particle time steps of local time stepping (decision 62): for each fluid particle
    its own limit of :func:`particle_limits` (whose minimum is :func:`cfl_dt`); with ``geom``
    the smallest of these over the particle's stencil, and with ``ratio`` at most ``ratio`` times
    the smallest step; 0 for every other particle (never updated).  A steady state of the
    semi-discrete system is a fixed point of the step whatever the steps are, so a steady run
    converges to the same state in fewer steps where the particle sizes are graded; the
    transient is not time-accurate."""
    dt = particle_limits(particles, params, scheme, cfl, cfl_viscous)
    if geom is not None:   # the smallest over the stencil: a pair's two ends advance alike
        dt = jnp.minimum(dt, jnp.min(jnp.where(geom.mask, dt[geom.jsafe], jnp.inf), axis=1))
    if ratio is not None:  # at most ``ratio`` times the smallest step
        dt = jnp.minimum(dt, ratio * jnp.min(dt))
    return jnp.where(particles.kind == Kind.FLUID, dt, 0.0)


def cfl_limiting_particle(particles: Particles, params: Params, scheme: Scheme, ops=None):
    """Index of the fluid particle with the smallest convective step dx_i / (|u_i - w_i| + c_i)
    (``ops``: :class:`LocalOps` by default; the spatial decomposition's finds it over every shard)."""
    ops = LocalOps() if ops is None else ops
    return ops.argmin(_local_dt(jax.lax.stop_gradient(particles), params, scheme))


def _local_dt(particles: Particles, params: Params, scheme: Scheme):
    eos = get_eos(scheme.eos)
    U = particles.U
    prim = to_primitive(U, eos, params)
    w = frame_velocity(U, particles.kind, scheme, params)
    speed = safe_norm(prim.vel - w) + prim.c   # |u - w| = 0 in the Lagrangian frame: keep its gradient finite
    dxi = particles.vol ** (1.0 / particles.dim)
    return jnp.where(particles.kind == Kind.FLUID, dxi / speed, jnp.inf)


def _euler(z, dt, dz, moving: bool = True):
    """Forward-Euler sub-step z + dt*dz on the (x, vol, q) parts of fluid particles; other
    particles keep their state bit for bit (frozen/boundary particles are never updated).
    ``moving=False`` (a frame whose particles stay put, e.g. Eulerian: dx/dt = dV/dt = 0) evolves
    q only, so positions and volumes stay the set-up values bit for bit (a*x + b*x with the
    Shu-Osher weights would move them by round-off)."""
    dx, dvol, dq = dz
    f1 = (z.kind == Kind.FLUID)[:, None]
    dtc = dt[:, None] if jnp.ndim(dt) else dt     # per-particle steps (local time stepping) or one
    # (a float32 state stays float32 where a term was computed wider; no-op in float64)
    q = jnp.where(f1, z.q + dtc * dq, z.q).astype(z.q.dtype)
    if not moving:
        return z.replace(q=q)
    return z.replace(x=jnp.where(f1, z.x + dtc * dx, z.x).astype(z.x.dtype),
                     vol=jnp.where(f1[:, 0], z.vol + dt * dvol, z.vol).astype(z.vol.dtype), q=q)


def _combine(a, y, b, e, moving: bool = True):
    """Shu-Osher combination a*y + b*e of the fluid particles (others keep y bit for bit);
    ``moving=False``: of q only (:func:`_euler`)."""
    f1 = (y.kind == Kind.FLUID)[:, None]
    q = jnp.where(f1, a * y.q + b * e.q, y.q)
    if not moving:
        return y.replace(q=q)
    return y.replace(x=jnp.where(f1, a * y.x + b * e.x, y.x), vol=jnp.where(f1[:, 0], a * y.vol + b * e.vol, y.vol),
                     q=q)


def complete_rows_if_needed(p: Particles, scheme: Scheme, boundary):
    """The complete rows of ``p`` if the area correction needs them (decision 92), else None."""
    return complete_rows(p, boundary) if wants_complete_rows(scheme) else None


def make_stage_geometry(scheme: Scheme, domain: Domain, nspec, boundary=None):
    """Function particles -> Geometry for moving particles (neighbour list rebuilt every stage)."""

    def stage_geometry(p: Particles) -> Geometry:
        h = scheme.beta * p.vol ** (1.0 / p.dim)
        nl = nb.update(p.x, h, nspec)
        complete = complete_rows_if_needed(p, scheme, boundary)
        return with_overflow_bits(geometry(p.x, p.vol, nl, scheme, domain, complete), nl)

    return stage_geometry


def make_verlet_stage_geometry(scheme: Scheme, domain: Domain, nspec, skin: float = verlet.VERLET_SKIN,
                               boundary=None):
    """``(init, stage_geometry)`` for moving particles with a Verlet-skin candidate list
    (:mod:`mlsph_jax.verlet`): ``init(p)`` the initial (stale) state, ``stage_geometry(p, v) ->
    (Geometry, v)`` restricts them to the stage's stencil (rebuilding them first when a particle
    has moved half the skin).  The lists, hence the geometries, are those of
    :func:`make_stage_geometry`."""
    cspec = verlet.candidate_spec(nspec, skin)

    def h_of(p: Particles):
        return scheme.beta * p.vol ** (1.0 / p.dim)

    def init(p: Particles):             # built by the first stage (one neighbour kernel in the chunk)
        return verlet.stale(p.x, h_of(p), cspec)

    def stage_geometry(p: Particles, v):
        nl, v = verlet.refresh(v, p.x, h_of(p), nspec, cspec, skin)
        complete = complete_rows_if_needed(p, scheme, boundary)
        return with_overflow_bits(geometry(p.x, p.vol, nl, scheme, domain, complete), nl), v

    return init, stage_geometry


def with_overflow_bits(geom: Geometry, nl) -> Geometry:
    """``geom`` with the neighbour bits of ``overflow`` replaced by the list's cause bits
    (``NeighborList.overflow_bits``, equal to the :class:`Status` neighbour bits); its other bits
    (an unconverged area correction) stay."""
    other = jnp.asarray(overflow_bits(geom)) & ~jnp.int32(Status.NEIGHBOR_OVERFLOW)
    return dataclasses.replace(geom, overflow=other | jnp.asarray(nl.overflow_bits, jnp.int32))


def overflow_bits(geom: Geometry) -> jax.Array:
    """The :class:`Status` neighbour bits of a geometry (a bool ``overflow`` means: cause unknown,
    all three bits)."""
    ovf = jnp.asarray(geom.overflow)
    if ovf.dtype == jnp.bool_:
        return jnp.where(ovf, jnp.int32(Status.NEIGHBOR_OVERFLOW), 0).astype(jnp.int32)
    return ovf.astype(jnp.int32)


SSP_RK3_A = (0.0, 0.75, 1.0 / 3.0)  # Shu-Osher form: z_{k+1} = a_k y + b_k (z_k + dt L(z_k))
SSP_RK3_B = (1.0, 0.25, 2.0 / 3.0)


def ssp_rk3_step(p: Particles, params: Params, dt, scheme: Scheme, geom_fn, boundary=None, cache=None):
    """One SSP-RK3 step.  ``geom_fn(p)`` returns the Geometry of a stage (constant for Eulerian
    runs).  Each stage is a forward-Euler sub-step E = z + dt L(z) combined as a y^n + b E; with
    the limiter of ``scheme.limiter`` computes the sub-step (MOOD: :mod:`mlsph_jax.mood`).

    Returns ``(new state, overflow, stats)``: ``overflow`` the :class:`Status` neighbour bits
    of the stages' lists (int32, 0 if none overflowed) and ``stats = (ppd, rhs evaluations,
    unresolved stages, first unresolved particle or -1, degree)`` where ``ppd`` is the smallest
    per-particle degree used in the three stages (the state's ``ppd`` field carries it out) and
    ``degree[N, 2]`` the smallest ``Geometry.degree`` of the stages.

    The three stages run as a ``lax.scan`` over the Shu-Osher coefficients, so the right-hand
    side is traced (and compiled) once, not three times.  ``boundary`` (e.g.
    :class:`mlsph_jax.boundaries.MirrorWalls`) regenerates ghost particles before every stage
    and after the step.

    ``scheme.geometry_update = "step"`` (moving frames, opt-in): ``geom_fn`` is called once, on
    the step's start state, and its geometry (list, area vectors, fit) serves all three stages;
    the states, frame velocities and fluxes are still those of each stage.  The pair terms stay
    antisymmetric (totals conserved to round-off) but the geometry is first order in time
    (accuracy measured in docs/performance.md).  The default ``"stage"`` rebuilds it every stage.

    ``cache`` (e.g. the Verlet candidate list of :func:`make_verlet_stage_geometry`): then
    ``geom_fn(p, cache) -> (Geometry, cache)``, the cache is threaded through the stages and
    returned as a fourth output.
    """
    limiter = scheme.component("limiter")
    dt = jnp.asarray(dt, p.q.dtype)  # the state's precision (run.precision); the time itself stays float64

    def stage(carry, ab):
        z, overflow, ppd_min, n_evals, unresolved, unres_particle, deg_min, cch = carry
        a, b = ab
        if boundary is not None:
            z = boundary.apply(z, params)
        if step_geom is not None:
            geom = step_geom
        elif cch is None:
            geom = geom_fn(z)
        else:
            geom, cch = geom_fn(z, cch)

        def euler(zz):
            return _euler(zz, dt, rhs(zz, params, geom, scheme, boundary), scheme.moving)

        e, ppd, n, unres = limiter.substep(z, params, dt, geom, scheme, euler)
        ppd_min = jnp.minimum(ppd_min, ppd)
        unres = jax.lax.stop_gradient(unres)
        first = jnp.where(jnp.any(unres), jnp.argmax(unres), -1).astype(jnp.int32)
        unres_particle = jnp.where(unres_particle >= 0, unres_particle, first)
        n_evals, unresolved = n_evals + n, unresolved + jnp.any(unres).astype(jnp.int32)
        cand = _combine(a, p, b, e, scheme.moving)
        deg_min = jnp.minimum(deg_min, geom.degree)
        return (cand, overflow | overflow_bits(geom), ppd_min, n_evals, unresolved, unres_particle, deg_min,
                cch), None

    step_geom = None
    if scheme.moving and scheme.geometry_update == "step":    # opt-in: one geometry per step
        z0 = p if boundary is None else boundary.apply(p, params)
        if cache is None:
            step_geom = geom_fn(z0)
        else:
            step_geom, cache = geom_fn(z0, cache)
    coeffs = (jnp.asarray(SSP_RK3_A, p.q.dtype), jnp.asarray(SSP_RK3_B, p.q.dtype))
    ppd_start = jnp.full_like(p.ppd, scheme.reconstruction_degree) if limiter.needs_high_order else p.ppd
    zero = jnp.asarray(0, jnp.int32)
    deg0 = jnp.full((p.n, 2), jnp.iinfo(jnp.int32).max, jnp.int32)
    init = (p, zero, ppd_start, zero, zero, jnp.asarray(-1, jnp.int32), deg0, cache)
    (out, overflow, ppd_min, n_evals, unresolved, unres_particle, deg_min, cache), _ = jax.lax.scan(
        stage, init, coeffs)
    if boundary is not None:
        out = boundary.apply(out, params)
    res = out.replace(ppd=ppd_min), overflow, (ppd_min, n_evals, unresolved, unres_particle, deg_min)
    return res if cache is None else (*res, cache)


def _mood_stats(stats, p: Particles, scheme: Scheme, count=jnp.sum):
    """This step's contribution to ``Carry.mood`` (see :data:`MOOD_STATS`; ``count(mask)``: the
    number of particles where ``mask`` holds, :meth:`LocalOps.count`)."""
    ppd, n_evals, unresolved = stats[:3]
    fluid = p.kind == Kind.FLUID
    demoted = count(fluid & (ppd < scheme.reconstruction_degree)) / jnp.maximum(count(fluid), 1)
    return jnp.stack([demoted, demoted, n_evals.astype(demoted.dtype), unresolved.astype(demoted.dtype)])


def step_status(p: Particles, newp: Particles, params: Params, scheme: Scheme, dt, overflow, stats, *,
                dt_fixed: bool = False, cfl: float = 0.3, cfl_viscous: float = 0.125, dt_min: float = 0.0,
                last=False, boundary=None, ops=None):
    """``(status bits, first offending particle)`` of one step from ``p`` to the candidate ``newp``
    (traceable, no host synchronisation, no gradient):

    * :func:`~mlsph_jax.status.state_status` of the candidate (NONFINITE, NEGATIVE_VOLUME,
      NEGATIVE_DENSITY, INADMISSIBLE), with its particle;
    * the stages' neighbour bits ``overflow`` (from :func:`ssp_rk3_step`);
    * MOOD_UNRESOLVED when a stage left MOOD flags unresolved (``stats`` of :func:`ssp_rk3_step`);
    * with ``dt_fixed``: DT_ABOVE_CFL when ``dt`` exceeds :data:`FIXED_DT_SLACK` times
      :func:`cfl_dt` of ``p`` (the state the step starts from) with the same ``cfl``/``cfl_viscous``.
      A fixed step is refused before the run unless it is within the CFL limit of the initial
      state (:func:`mlsph_jax.run.check_fixed_step`); during the run the flow may speed up (Sod's
      post-shock state is faster than either initial state), so the in-run test allows an
      effective Courant number of twice ``cfl`` (0.6 by default, still inside SSP-RK3's linear
      stability range) before it stops the run;
    * DT_UNDERFLOW when ``dt < dt_min`` and the step is not the ``last`` one before an output time;
    * the ``boundary``'s ``band_status(newp, params)`` if it has one (mirror walls: GHOST_BAND).

    For the dt causes the particle is the one limiting the CFL step.  ``ops`` (:class:`LocalOps`
    by default): how the particle of a cause is found (the spatial decomposition finds it over
    every shard, by original index).
    """
    ops = LocalOps() if ops is None else ops
    bits, bad = state_status(newp, params, scheme, first=ops.first)
    bits = bits | overflow
    if getattr(boundary, "band_status", None) is not None:
        bits, bad = combine(bits, bad, *boundary.band_status(newp, params))
    unresolved, unres_particle = stats[2], stats[3]
    mood = unresolved > 0
    bits, bad = combine(bits, bad, jnp.where(mood, jnp.int32(Status.MOOD_UNRESOLVED), 0),
                        jnp.where(mood, unres_particle, -1))
    dt_bits = jnp.zeros((), jnp.int32)
    if dt_fixed:
        limit = cfl_dt(jax.lax.stop_gradient(p), params, scheme, cfl, cfl_viscous)
        above = jax.lax.stop_gradient(dt) > FIXED_DT_SLACK * limit
        dt_bits = dt_bits | jnp.where(above, jnp.int32(Status.DT_ABOVE_CFL), 0)
    if dt_min > 0:
        dt_bits = dt_bits | jnp.where((dt < dt_min) & ~last, jnp.int32(Status.DT_UNDERFLOW), 0)
    if dt_fixed or dt_min > 0:
        limiting = cfl_limiting_particle(p, params, scheme, ops)
        bits, bad = combine(bits, bad, dt_bits, jnp.where(dt_bits != 0, limiting, -1))
    return bits.astype(jnp.int32), bad.astype(jnp.int32)


#: How far a fixed step may exceed the CFL step of the current state during a run (see
#: :func:`step_status`) before the run stops with ``Status.DT_ABOVE_CFL``.
FIXED_DT_SLACK = 2.0


def fixed_boundary(boundary, scheme: Scheme, p: Particles, params: Params):
    """``boundary`` with the searches that depend only on fixed particles done once for ``p``
    (its ``fix``, e.g. :meth:`mlsph_jax.wall_integral.BoundaryIntegralWalls.fix`) when the
    particles do not move; otherwise ``boundary`` itself."""
    if scheme.moving or getattr(boundary, "fix", None) is None:
        return boundary
    return boundary.fix(p, params)


class LocalOps:
    """The cross-particle operations of a step when one program sees every particle (one
    device, or the index-sharded run whose partitioner inserts the communication).  The spatial
    decomposition replaces them by collectives (:class:`mlsph_jax.spatial.Collectives`)."""

    def __init__(self, boundary=None):
        self.boundary = boundary

    def min(self, x):
        """Global minimum of a value already reduced over this program's particles."""
        return x

    def count(self, mask):
        """Number of particles where ``mask`` holds."""
        return jnp.sum(mask)

    def status(self, bits, bad):
        """Global status bits and offending particle (original index)."""
        return bits, bad

    def first(self, mask):
        """Index of the first particle where ``mask`` holds, or -1."""
        return first_index(mask)

    def argmin(self, values):
        """Index of the (first) smallest value."""
        return jnp.argmin(values).astype(jnp.int32)


def make_chunk(scheme: Scheme, domain: Domain, control: StepControl, n_steps: int, nspec=None, boundary=None,
               sharding=None, skin: float = verlet.VERLET_SKIN, spatial=None):
    """Build ``chunk(carry, params, static_geom, t_stop, step_stop=None) -> carry`` running ``n_steps``
    steps (steps once ``carry.t`` reaches ``t_stop`` or ``carry.step`` reaches ``step_stop`` are no-ops:
    ``time.max_steps`` is exact).

    For Eulerian schemes pass the precomputed Geometry as ``static_geom``; for moving particles
    pass ``None`` and a neighbour spec ``nspec``: the list of every stage is restricted from a
    Verlet-skin candidate list built at the chunk's start and rebuilt only when a particle has
    moved half the skin (:mod:`mlsph_jax.verlet`; ``skin`` as a fraction of ``support max h``,
    0 = rebuild every stage; the same lists either way).  ``sharding`` (a
    :class:`mlsph_jax.sharding.ParticleSharding`, multi-device runs) pins the layout of the
    carry and the geometry to the particle-axis sharding at entry and exit; the partitioner
    does the rest.  ``spatial`` (a :class:`mlsph_jax.spatial.SpatialSharding`, Eulerian runs):
    the chunk runs per shard inside ``jax.shard_map`` on the local layout, ``static_geom`` is a
    :class:`mlsph_jax.spatial.SpatialGeometry`, and the halo exchange and the reductions are
    explicit collectives.
    """

    def steps(carry: Carry, params: Params, static_geom, t_stop, step_stop, ops):
        boundary = ops.boundary
        cache = None
        if not scheme.moving:
            geom_fn = lambda p: static_geom  # noqa: E731
        elif skin > 0:
            init, geom_fn = make_verlet_stage_geometry(scheme, domain, nspec, skin, boundary)
            cache = init(carry.particles)
        else:
            geom_fn = make_stage_geometry(scheme, domain, nspec, boundary)

        def one(cv, _):
            c, v = cv
            active = (c.status == Status.OK) & (c.t < t_stop)
            if step_stop is not None:
                active = active & (c.step < step_stop)

            def advance(cv):
                c, v = cv
                dt = (jnp.asarray(control.dt_fixed) if control.dt_fixed > 0
                      else ops.min(cfl_dt(c.particles, params, scheme, control.cfl, control.cfl_viscous)))
                remaining = t_stop - c.t
                last = dt >= remaining
                if control.local:   # each particle its own step, all cut by the same factor at an output time
                    steps = local_steps(c.particles, params, scheme, control.cfl, control.cfl_viscous,
                                        geom=geom_fn(c.particles) if v is None else None,
                                        ratio=control.local_ratio)
                    steps = steps * jnp.minimum(1.0, remaining / dt)
                dt = jnp.minimum(dt, remaining)
                newp, overflow, stats, *vs = ssp_rk3_step(c.particles, params, steps if control.local else dt,
                                                          scheme, geom_fn, boundary, v)
                st, bad = ops.status(*step_status(c.particles, newp, params, scheme, dt, overflow, stats,
                                                  dt_fixed=control.dt_fixed > 0, cfl=control.cfl,
                                                  cfl_viscous=control.cfl_viscous, dt_min=control.dt_min,
                                                  last=last, boundary=boundary, ops=ops))
                ok = st == Status.OK
                keep = lambda new, old: jax.tree_util.tree_map(lambda a, b: jnp.where(ok, a, b), new, old)
                t_new = jnp.where(last, t_stop, c.t + dt)
                inc = _mood_stats(stats, newp, scheme, ops.count)
                mood = jnp.where(ok, c.mood.at[0].set(jnp.maximum(c.mood[0], inc[0])).at[1:].add(inc[1:]), c.mood)
                fb = fallback.update_stats(c.fallback, fallback.step_fractions(stats[4], c.particles.kind, scheme,
                                                                               ops.count))
                return (Carry(keep(newp, c.particles), jnp.where(ok, t_new, c.t),
                              c.step + ok.astype(c.step.dtype), st, jnp.where(ok, c.bad_particle, bad),
                              jnp.where(ok, dt, c.dt_last), mood, jnp.where(ok, stats[4], c.degree),
                              jnp.where(ok, fb, c.fallback)),
                        vs[0] if vs else v)       # (candidates stay valid whatever the step's fate)

            return jax.lax.cond(active, advance, lambda cv: cv, (c, v)), None

        (out, _), _ = jax.lax.scan(one, (carry, cache), None, length=n_steps)
        return out

    if spatial is not None:
        from .spatial import Collectives, shard_chunk

        shifts = spatial.layout.shifts

        def local(carry, params, tables, t_stop, step_stop):
            ops = Collectives(tables, spatial.devices, shifts, boundary)
            return steps(carry, params, tables.geom, t_stop, step_stop, ops)

        spmd = shard_chunk(local, spatial)
        return jax.jit(lambda carry, params, sgeom, t_stop, step_stop=None: spmd(carry, params, sgeom, t_stop,
                                                                                step_stop))

    def chunk(carry: Carry, params: Params, static_geom, t_stop, step_stop=None):
        if sharding is not None:
            carry, static_geom = sharding.constrain((carry, static_geom))
        out = steps(carry, params, static_geom, t_stop, step_stop,
                    LocalOps(fixed_boundary(boundary, scheme, carry.particles, params)))
        return out if sharding is None else sharding.constrain(out)

    return jax.jit(chunk)


def initial_carry(particles: Particles, t0: float = 0.0) -> Carry:
    return Carry(particles, jnp.asarray(t0, jnp.float64), jnp.asarray(0, jnp.int32),
                 jnp.asarray(Status.OK, jnp.int32), jnp.asarray(-1, jnp.int32), jnp.asarray(0.0),
                 jnp.zeros(len(MOOD_STATS)), fallback.initial_degrees(particles.n), fallback.initial_stats())


@functools.partial(jax.jit, static_argnames=("scheme", "domain"))
def static_geometry(particles: Particles, nl, scheme: Scheme, domain: Domain, boundary=None) -> Geometry:
    """Geometry of fixed (Eulerian) particles, computed once (``overflow`` = the list's
    :class:`Status` neighbour bits; ``boundary``: for the complete rows of decision 92)."""
    return with_overflow_bits(geometry(particles.x, particles.vol, nl, scheme, domain,
                                       complete_rows_if_needed(particles, scheme, boundary)), nl)
