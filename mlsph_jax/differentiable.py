"""Differentiable whole-run simulation: ``simulate(params, particles) -> SimOutput``.

:func:`make_simulate` turns a :class:`~mlsph_jax.simulation.Problem` into a pure function that
runs a fixed number of SSP-RK3 steps of fixed size and returns the final state, the time series
of differentiable diagnostics and the run's status word (:class:`~mlsph_jax.status.Status`).  It is ``jit``-able and
differentiable with ``jax.grad``, ``jax.jacfwd`` and ``jax.vjp`` with respect to every float in
the parameter pytree (EOS constants, viscosity, body force, wall velocities, ...), the initial
fields and the particle positions.

What carries no gradient: the topology (neighbour indices, fixed-capacity lists sized on the
host from the initial state; rebuilt per stage for moving particles with the same capacity) and
the MOOD flags (:mod:`mlsph_jax.mood`).

Failures are never silent.  Every step computes, inside ``jit``, the status of its candidate
state as the driver does (NaN/inf, inadmissible or non-positive density/volume, neighbour-list
overflow by cause, a fixed step above the CFL limit of the current state, unresolved MOOD
flags; :func:`mlsph_jax.integrate.step_status`).  The first failing step is not committed: it
and all later steps become no-ops (``jnp.where``, so the function stays differentiable) that
keep the last good state, and ``SimOutput`` carries ``status``, ``failed_step``,
``failed_time`` and ``bad_particle``.  :func:`run_differentiable` and :func:`check` raise
:class:`~mlsph_jax.errors.SimulationError` (``NeighborOverflowError`` for an overflow) naming the
step, time, particle and cause; inside ``jax.grad`` return the ``SimOutput`` as auxiliary
output and call :func:`check` on it afterwards (:mod:`mlsph_jax.sensitivity` does).

Time step: fixed, ``dt = t_end / n_steps``.  An adaptive CFL step would make the number of steps
depend on the parameters; with a fixed count the outputs are smooth functions of them.  By
default ``n_steps`` comes from the initial CFL step of the problem with a safety factor
(:func:`default_steps`); a given ``n_steps`` whose ``dt`` exceeds the CFL limit of the initial
state (with ``cfl``, ``cfl_viscous``) is refused before running with an
:class:`~mlsph_jax.errors.InputError` naming the smallest admissible step count
(:func:`mlsph_jax.run.check_fixed_step`).

Reverse-mode memory (``checkpoint``):

* ``"none"``: every intermediate of every stage is stored (fastest, memory ~ steps x stages x
  the right-hand side's working set);
* ``"step"``: ``jax.checkpoint`` around each step: only the state at every step is stored and a
  step is recomputed during the backward pass (memory ~ steps x state);
* ``"nested"`` (default): steps are grouped into segments of ``segment`` steps (default
  ~sqrt(n_steps)); the scan over segments is checkpointed and so is each step inside, so only
  segment boundaries plus one segment of states are stored (memory ~ (steps/segment + segment)
  x state) for about one extra forward pass of work.

``policy`` is passed to ``jax.checkpoint`` (e.g. ``jax.checkpoint_policies.dots_saveable``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping

import jax
import jax.numpy as jnp
import numpy as np

from .approximation import block_remat
from .errors import InputError
from .integrate import fixed_boundary, ssp_rk3_step, step_status
from .run import cfl_limit, check_fixed_step, default_steps, setup_run
from .spatial import refuse_in
from .state import Kind, Params, Particles
from .status import Status, failure, state_status

CHECKPOINTS = ("none", "step", "nested")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SimOutput:
    """Result of a differentiable run: final particles, ``series[name][k]`` recorded after every
    ``record_every`` steps (plus the initial value at index 0), the record times, and the run's
    status: ``status`` (:class:`~mlsph_jax.status.Status` bits, 0 = ok), ``failed_step`` (the
    first failing step, 1-based; 0 for a bad initial state; -1 if none), ``failed_time`` (the
    time that step started from) and ``bad_particle`` (first offending particle or -1).  After a
    failure ``particles`` and the rest of ``series`` are the last good state."""

    particles: Particles
    series: dict
    times: jax.Array
    status: jax.Array
    failed_step: jax.Array
    failed_time: jax.Array
    bad_particle: jax.Array

    @property
    def ok(self) -> jax.Array:
        return self.status == 0

    @property
    def overflow(self) -> jax.Array:
        """Whether a neighbour list overflowed (any of the three neighbour bits)."""
        return (self.status & int(Status.NEIGHBOR_OVERFLOW)) != 0


def kinetic_energy(p: Particles, params: Params) -> jax.Array:
    """sum over fluid particles of V |rho u|^2 / (2 rho) (differentiable)."""
    fluid = p.kind == Kind.FLUID
    d = p.dim
    mom = p.q[:, 1:1 + d]
    ke = 0.5 * jnp.sum(mom * mom, axis=1) / p.q[:, 0]
    return jnp.sum(jnp.where(fluid, ke, 0.0))


def base_diagnostics(p: Particles, t, params: Params) -> dict:
    """Differentiable diagnostics every case has: kinetic energy, mass, momentum."""
    fluid = (p.kind == Kind.FLUID)[:, None]
    tot = jnp.sum(jnp.where(fluid, p.q, 0.0), axis=0)
    out = {"ke": kinetic_energy(p, params), "mass": tot[0]}
    for a, name in zip(range(p.dim), "xyz", strict=False):
        out[f"momentum_{name}"] = tot[1 + a]
    return out


def make_simulate(problem, *, n_steps: int | None = None, t_end: float | None = None,
                  checkpoint: str = "nested", segment: int | None = None, policy=None,
                  record_every: int = 1, diagnostics: Callable | None = None,
                  headroom: float = 1.6, cfl: float = 0.3, cfl_viscous: float = 0.125,
                  nspec=None, remat_blocks: bool = True) -> Callable[[Params, Particles], SimOutput]:
    """Build ``simulate(params, particles) -> SimOutput`` for ``problem`` (module docstring).

    ``diagnostics(particles, t, params) -> dict`` of differentiable scalars recorded every
    ``record_every`` steps (default :func:`base_diagnostics`, plus the problem's own
    ``differentiable_diagnostics`` when it has one).  ``n_steps`` must be a multiple of
    ``record_every``.  Nested segments are whole multiples of ``record_every`` (a record is taken
    at the end of a block of steps), so keep ``record_every`` <= ~sqrt(n_steps) for the nested
    memory saving: recording only at the end leaves one segment, i.e. the storage of ``"step"``.

    ``cfl``/``cfl_viscous``: the CFL numbers of the step-size checks: ``n_steps`` (default
    :func:`default_steps`) is refused with an :class:`~mlsph_jax.errors.InputError` if
    ``t_end / n_steps`` exceeds the CFL limit of ``problem.particles``, and a step whose state's
    limit drops below ``dt`` fails with ``Status.DT_ABOVE_CFL``.  ``headroom``: neighbour
    capacity headroom; the capacity is fixed for the whole run (an overflow is a failure).
    ``nspec``: a :class:`~mlsph_jax.neighbors.NeighborSpec` to use instead of sizing one
    (:func:`mlsph_jax.run.setup_run`).  ``remat_blocks``: rematerialise each row block of the
    stencil passes in reverse mode (:func:`mlsph_jax.approximation.block_remat`; same values,
    about half the cost of a right-hand side's gradient); ``False`` stores the blocks'
    intermediates as before.
    """
    if checkpoint not in CHECKPOINTS:
        raise InputError(f"invalid checkpoint={checkpoint!r}; allowed: {', '.join(CHECKPOINTS)}")
    refuse_in(problem, "the differentiated runs (mlsph_jax.differentiable, mlsph sensitivity / calibrate)")
    t_end = float(problem.t_end if t_end is None else t_end)
    n_steps = default_steps(problem, cfl=cfl, cfl_viscous=cfl_viscous, t_end=t_end) if n_steps is None \
        else int(n_steps)
    if n_steps < 1 or record_every < 1 or n_steps % record_every:
        raise InputError(f"invalid n_steps={n_steps} / record_every={record_every}; allowed: positive integers "
                         "with n_steps a multiple of record_every")
    check_fixed_step(problem, n_steps, t_end, cfl=cfl, cfl_viscous=cfl_viscous)
    dt = t_end / n_steps
    scheme, boundary = problem.scheme, problem.boundary
    setup = setup_run(problem, headroom=headroom, nspec=nspec)
    extra = getattr(problem, "differentiable_diagnostics", None)

    def diag(p, t, params):
        out = dict(base_diagnostics(p, t, params))
        if extra is not None:
            out.update(extra(p, t, params))
        if diagnostics is not None:
            out.update(diagnostics(p, t, params))
        return out

    n_rec = n_steps // record_every
    seg = record_every if checkpoint != "nested" else (segment or max(record_every, _segment(n_steps, record_every)))
    if checkpoint == "nested" and (seg % record_every or n_steps % seg):
        seg = record_every  # fall back to record blocks as segments
    blocks_per_seg = seg // record_every

    def simulate(params: Params, particles: Particles) -> SimOutput:
        with block_remat(remat_blocks):   # a trace-time setting: it covers every stage traced below
            return _simulate(params, particles)

    def _simulate(params: Params, particles: Particles) -> SimOutput:
        geom_fn = setup.geometry_fn(particles)
        bnd = fixed_boundary(boundary, scheme, particles, params)   # wall searches once (fixed particles)
        st0, bad0 = state_status(particles, params, scheme)
        st0 = st0 | setup.initial_status()
        failed0 = jnp.where(st0 != 0, 0, -1).astype(jnp.int32)
        # carry: (state, steps taken, status, first failing step, first offending particle)
        carry0 = (particles, jnp.asarray(0, jnp.int32), st0, failed0, bad0)

        def step(carry, _):
            p, k, st, failed, bad = carry
            p2, ovf, stats = ssp_rk3_step(p, params, dt, scheme, geom_fn, bnd)
            st2, bad2 = step_status(p, p2, params, scheme, dt, ovf, stats, dt_fixed=True, cfl=cfl,
                                    cfl_viscous=cfl_viscous, boundary=bnd)
            alive = st == 0
            commit = alive & (st2 == 0)   # a failing step is not committed; later steps are no-ops
            p = jax.tree_util.tree_map(lambda a, b: jnp.where(commit, a, b), p2, p)
            new_fail = alive & (st2 != 0)
            return (p, k + 1, jnp.where(alive, st2, st), jnp.where(new_fail, k + 1, failed),
                    jnp.where(new_fail, bad2, bad)), None

        if checkpoint in ("step", "nested"):
            step = jax.checkpoint(step, policy=policy)

        def block(carry, k):
            carry, _ = jax.lax.scan(step, carry, None, length=record_every)
            t = (k + 1) * record_every * dt
            return carry, diag(carry[0], t, params)

        if checkpoint == "nested":
            def segment_fn(carry, ks):
                return jax.lax.scan(block, carry, ks)

            segment_fn = jax.checkpoint(segment_fn, policy=policy)
            ks = jnp.arange(n_rec).reshape(n_rec // blocks_per_seg, blocks_per_seg)
            (pf, _, st, failed, bad), rec = jax.lax.scan(segment_fn, carry0, ks)
            rec = jax.tree_util.tree_map(lambda a: a.reshape((n_rec,) + a.shape[2:]), rec)
        else:
            (pf, _, st, failed, bad), rec = jax.lax.scan(block, carry0, jnp.arange(n_rec))
        first = diag(particles, 0.0, params)
        series = {k: jnp.concatenate([jnp.asarray(first[k])[None], rec[k]]) for k in rec}
        times = jnp.arange(n_rec + 1) * (record_every * dt)
        failed_time = jnp.maximum(failed - 1, 0) * dt
        return SimOutput(pf, series, times, st, failed, failed_time, bad)

    simulate.n_steps = n_steps
    simulate.dt = dt
    simulate.record_every = record_every
    simulate.setup = setup
    simulate.problem = problem
    simulate.cfl = cfl
    simulate.cfl_viscous = cfl_viscous
    return simulate


def _segment(n_steps: int, record_every: int) -> int:
    """A divisor of n_steps (multiple of record_every) near sqrt(n_steps)."""
    target = max(record_every, int(round(math.sqrt(n_steps))))
    cands = [s for s in range(record_every, n_steps + 1, record_every) if n_steps % s == 0]
    return min(cands, key=lambda s: abs(s - target))


def run_differentiable(simulate, params: Params, particles: Particles) -> SimOutput:
    """Run ``simulate`` and raise on a failure (:func:`check`; a host check, not for use inside
    ``grad``: there return the ``SimOutput`` as auxiliary output and :func:`check` it after)."""
    out = simulate(params, particles)
    check(out, simulate, params)
    return out


def check(out: SimOutput, simulate=None, params: Params | None = None) -> None:
    """Raise :class:`~mlsph_jax.errors.SimulationError` (``NeighborOverflowError`` if the only
    cause is a neighbour-list overflow) if the run's status is not ok, naming the first failing
    step, the time it started from, the first offending particle and the cause (host side).
    With the ``simulate`` function and the ``params`` of the run, a step above the CFL limit
    also names the step count that the last good state needs."""
    st = Status(int(out.status))
    if st == Status.OK:
        return
    i = int(out.bad_particle)
    x = np.asarray(out.particles.x[i]) if i >= 0 else None
    detail = ""
    if st & Status.NEIGHBOR_OVERFLOW:
        detail = ("the neighbour capacity of a differentiated run is fixed (sized on the host from the initial "
                  "state, so the topology carries no gradient); rerun with a larger headroom "
                  "(make_simulate(..., headroom=...))")
    elif st & Status.DT_ABOVE_CFL:
        detail = ("the flow sped up: use more steps (make_simulate(..., n_steps=...); mlsph: --n-steps, or a "
                  "larger CFL number with --set time.cfl=...)")
        if simulate is not None and params is not None and hasattr(simulate, "problem"):
            t_end = simulate.n_steps * simulate.dt
            limit = cfl_limit(simulate.problem, cfl=simulate.cfl, cfl_viscous=simulate.cfl_viscous,
                              particles=out.particles, params=params)
            if np.isfinite(limit) and limit > 0:
                detail += (f"; dt = {simulate.dt:.4g} but the state at t={float(out.failed_time):.6g} allows "
                           f"{limit:.4g} (cfl={simulate.cfl}), i.e. n_steps >= {math.ceil(t_end / limit)} for it")
    raise failure(st, step=int(out.failed_step), time=float(out.failed_time), particle=i, x=x, detail=detail,
                  last_good="the returned state and the rest of the series are the last good state")


#: Backwards-compatible name of :func:`check` (it checks every cause, not only overflow).
check_overflow = check


def param_paths(params: Params) -> list[str]:
    """Names of the float parameters (the keys ``--wrt`` accepts)."""
    return [k for k in params if jnp.issubdtype(jnp.asarray(params[k]).dtype, jnp.floating)]


def with_param(params: Params, key: str, value) -> Params:
    """A copy of ``params`` with ``key`` replaced (differentiable in ``value``)."""
    if key not in params:
        raise InputError(f"invalid parameter {key!r}; allowed: {', '.join(param_paths(params))}")
    vals: Mapping = {k: params[k] for k in params}
    return Params({**vals, key: value})
