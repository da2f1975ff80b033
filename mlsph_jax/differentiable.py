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
  step is recomputed during the backward pass (memory ~ steps x state; what a step reads of the
  carried state is q where the frame does not move the particles, nv * 8 bytes per particle in
  float64, and x, vol and q otherwise; the records are taken inside the checkpointed step and
  store nothing);
* ``"nested"`` (default): steps are grouped into segments of ``segment`` steps (default
  ~sqrt(n_steps)); the scan over segments is checkpointed and so is each step inside, so only
  segment boundaries plus one segment of states are stored (memory ~ (steps/segment + segment)
  x state) for about one extra forward pass of work.

``policy`` is passed to ``jax.checkpoint`` (e.g. ``jax.checkpoint_policies.dots_saveable``).

Time averages (``average``, ``window``): the run also accumulates, inside the scan, the time
average over the window [t_start, t_end] of each scalar q of ``average(particles, t, params)`` and
the mean square of its fluctuation about that mean (``SimOutput.averages[name] = {"mean": <q>,
"variance": <(q - <q>)^2>}``).  The rule is
the trapezoidal rule on the step grid: the integral over the window of the piecewise-linear
interpolant of the values at every step time t_k = k dt, divided by the window's length
(:func:`window_weights`; a window end between two steps cuts the linear piece there, so any
window in [0, t_end] is exact for a quantity linear in t).  Both are accumulated by a weighted
Welford update of (W, mean, M2): W += w_k; d = q_k - mean; mean += (w_k / W) d; M2 += w_k d
(q_k - mean); variance = M2 / W.  The mean equals sum_k w_k q_k to round-off, and the variance has
no cancellation (the one-pass <q^2> - <q>^2 loses all digits of a fluctuation below ~1e-8 of the
mean).  The weights are fixed on the host before tracing; a step with w_k = 0 (outside the window,
t = 0 included) skips the evaluation (``lax.cond``), so the cost is one
evaluation of ``average`` per step inside the window and nothing else changes: no host
synchronisation, one compilation, and without ``average`` the scan is the one above.
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
from .rhs import check_conservation_projection
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
    #: ``{name: {"mean": ..., "variance": ...}}``: the time averages over the window of the
    #: quantities of ``make_simulate(..., average=...)`` (module docstring; empty without it).
    averages: dict = dataclasses.field(default_factory=dict)

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
                  nspec=None, remat_blocks: bool = True, average: Callable | None = None,
                  window: tuple[float, float] | None = None) -> Callable[[Params, Particles], SimOutput]:
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
    capacity headroom of moving particles (fixed, Eulerian particles get their largest count,
    decision 91); the capacity is fixed for the whole run (an overflow is a failure).
    ``nspec``: a :class:`~mlsph_jax.neighbors.NeighborSpec` to use instead of sizing one
    (:func:`mlsph_jax.run.setup_run`).  ``remat_blocks``: rematerialise each row block of the
    stencil passes in reverse mode (:func:`mlsph_jax.approximation.block_remat`; same values,
    about half the cost of a right-hand side's gradient); ``False`` stores the blocks'
    intermediates as before.

    ``average(particles, t, params) -> dict`` of differentiable scalars: their time averages (and
    the variances about them) over ``window`` = (t_start, t_end) (default: the whole run, (0,
    t_end)) are accumulated in the run and returned in ``SimOutput.averages`` (module docstring,
    "Time averages").  A window outside [0, t_end] or empty is an InputError naming it.
    """
    options = dict(n_steps=n_steps, t_end=t_end, checkpoint=checkpoint, segment=segment, policy=policy,
                   record_every=record_every, diagnostics=diagnostics, headroom=headroom, cfl=cfl,
                   cfl_viscous=cfl_viscous, nspec=nspec, remat_blocks=remat_blocks)
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
    if window is not None and average is None:
        raise InputError(f"invalid window={window!r} without average=: the window applies to the time averages "
                         "only; allowed: window=None, or an average= function")
    weights = None if average is None else jnp.asarray(window_weights(n_steps, dt, window))
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
        if not isinstance(particles.kind, jax.core.Tracer):   # the caller's own particles (host check)
            check_conservation_projection(scheme, particles.kind, boundary)
        geom_fn = setup.geometry_fn(particles)
        bnd = fixed_boundary(boundary, scheme, particles, params)   # wall searches once (fixed particles)
        st0, bad0 = state_status(particles, params, scheme)
        st0 = st0 | setup.initial_status()
        failed0 = jnp.where(st0 != 0, 0, -1).astype(jnp.int32)
        # carry: (state, steps taken, status, first failing step, first offending particle)
        def accumulate(acc, p, k):
            """Add step k's weighted value to the running (weight W, mean, M2) of each quantity, a
            weighted Welford update (module docstring, "Time averages"); skipped where w_k = 0."""
            w = weights[k]

            def add(acc):
                vals = average(p, k * dt, params)
                out = {}
                for n, (W, mean, m2) in acc.items():
                    W = W + w
                    d = vals[n] - mean
                    mean = mean + (w / jnp.where(W > 0, W, 1.0)) * d   # W >= w > 0 here; guarded for tracing
                    out[n] = (W, mean, m2 + w * d * (vals[n] - mean))
                return out

            return jax.lax.cond(w != 0, add, lambda a: a, acc)

        acc0 = {}
        if average is not None:   # the window's first point t = 0, under the same condition as every step
            shapes = jax.eval_shape(lambda p: average(p, 0.0, params), particles)
            acc0 = accumulate({n: (jnp.zeros(v.shape, v.dtype),) * 3 for n, v in shapes.items()}, particles,
                              jnp.asarray(0, jnp.int32))
        # Fixed particles (a frame that does not move them, e.g. Eulerian): a step changes q and ppd
        # only (integrate._euler keeps x and vol bit for bit), so the scan carries at most those
        # and reads x, vol and kind from ``base``, a constant of the scan.  Moving particles carry
        # x and vol as well; their kind never changes in a run.  The per-particle degrees ppd change
        # only under a limiter that works on them (MOOD: ``needs_high_order`` in the limiter
        # protocol of :mod:`mlsph_jax.mood`); without one they stay the initial ones, read from
        # ``base`` too, and MOOD resets them at every step's start, so a recomputed step never
        # reads the carried ones.  Reverse mode then stores nv * 8 bytes per particle and step
        # (fixed) or x, vol and q (moving) instead of the whole state (docs/performance.md, "What
        # reverse mode keeps per step").  ``base`` has its mirror ghosts regenerated from their
        # parents, as every step's output has.
        base = particles if bnd is None else bnd.apply(particles, params)
        carried = (("x", "vol") if scheme.moving else ()) + ("q",) + \
            (("ppd",) if scheme.component("limiter").needs_high_order else ())

        def pack(p):
            return tuple(getattr(p, f) for f in carried)

        def unpack(c):
            return base.replace(**dict(zip(carried, c, strict=True)))

        carry0 = (pack(particles), jnp.asarray(0, jnp.int32), st0, failed0, bad0, acc0)

        def step(carry, j):
            c, k, st, failed, bad, acc = carry
            p = unpack(c)
            p2, ovf, stats = ssp_rk3_step(p, params, dt, scheme, geom_fn, bnd)
            st2, bad2 = step_status(p, p2, params, scheme, dt, ovf, stats, dt_fixed=True, cfl=cfl,
                                    cfl_viscous=cfl_viscous, boundary=bnd)
            alive = st == 0
            commit = alive & (st2 == 0)   # a failing step is not committed; later steps are no-ops
            c = jax.tree_util.tree_map(lambda a, b: jnp.where(commit, a, b), pack(p2), c)
            new_fail = alive & (st2 != 0)
            if average is not None:
                acc = accumulate(acc, unpack(c), k + 1)
            # A block's record is taken inside its last step: under the step's checkpoint reverse
            # mode keeps nothing for it beyond the step's input.  Taken after the step (as it was),
            # it stored its own input, a second copy of the state, and its intermediates.
            t = (k + 1) * dt                                  # = (block + 1) * record_every * dt
            if record_every == 1:
                rec = diag(unpack(c), t, params)
            else:
                rec = jax.lax.cond(j == record_every - 1, lambda c: diag(unpack(c), t, params),
                                   lambda c: jax.tree_util.tree_map(jnp.zeros_like, rec_shapes), c)
            return (c, k + 1, jnp.where(alive, st2, st), jnp.where(new_fail, k + 1, failed),
                    jnp.where(new_fail, bad2, bad), acc), rec

        rec_shapes = None if record_every == 1 else jax.eval_shape(lambda: diag(particles, 0.0, params))
        if checkpoint in ("step", "nested"):
            step = jax.checkpoint(step, policy=policy)

        def block(carry, k):
            carry, recs = jax.lax.scan(step, carry, jnp.arange(record_every))
            return carry, jax.tree_util.tree_map(lambda a: a[-1], recs)

        if checkpoint == "nested":
            def segment_fn(carry, ks):
                return jax.lax.scan(block, carry, ks)

            segment_fn = jax.checkpoint(segment_fn, policy=policy)
            ks = jnp.arange(n_rec).reshape(n_rec // blocks_per_seg, blocks_per_seg)
            (cf, _, st, failed, bad, acc), rec = jax.lax.scan(segment_fn, carry0, ks)
            rec = jax.tree_util.tree_map(lambda a: a.reshape((n_rec,) + a.shape[2:]), rec)
        else:
            (cf, _, st, failed, bad, acc), rec = jax.lax.scan(block, carry0, jnp.arange(n_rec))
        pf = unpack(cf)
        first = diag(particles, 0.0, params)
        series = {k: jnp.concatenate([jnp.asarray(first[k])[None], rec[k]]) for k in rec}
        times = jnp.arange(n_rec + 1) * (record_every * dt)
        failed_time = jnp.maximum(failed - 1, 0) * dt
        averages = {n: {"mean": mean, "variance": m2 / jnp.where(W > 0, W, 1.0)} for n, (W, mean, m2) in acc.items()}
        return SimOutput(pf, series, times, st, failed, failed_time, bad, averages)

    simulate.n_steps = n_steps
    simulate.dt = dt
    simulate.record_every = record_every
    simulate.setup = setup
    simulate.problem = problem
    simulate.cfl = cfl
    simulate.cfl_viscous = cfl_viscous
    simulate.diagnostics = diag
    simulate.window = None if average is None else _window(window, n_steps * dt)
    simulate.options = {**options, "n_steps": n_steps, "nspec": setup.nspec}
    return simulate


def _window(window, t_end: float) -> tuple[float, float]:
    """The checked window (t_start, t_end) of a time average (default the whole run)."""
    if window is None:
        return 0.0, float(t_end)
    try:
        a, b = (float(v) for v in window)
    except (TypeError, ValueError):
        raise InputError(f"invalid window (--window) {window!r}; allowed: two numbers T_START T_END with "
                         f"0 <= T_START < T_END <= {t_end:.10g} (the run's end)") from None
    tol = 1e-12 * max(abs(t_end), 1.0)
    if not (math.isfinite(a) and math.isfinite(b)) or a < -tol or b > t_end + tol or not b > a:
        why = ("not a finite number" if not (math.isfinite(a) and math.isfinite(b))
               else "empty (T_END <= T_START)" if b <= a else "outside the run [0, t_end]")
        raise InputError(f"invalid window (--window) = ({a:.10g}, {b:.10g}): {why}; allowed: "
                         f"0 <= T_START < T_END <= {t_end:.10g} (the run's end time, n_steps x dt)")
    return max(a, 0.0), min(b, float(t_end))


def window_weights(n_steps: int, dt: float, window=None) -> np.ndarray:
    """Weights w_k (k = 0..n_steps) with sum_k w_k f(t_k) = (1 / (b - a)) * integral over [a, b]
    of the piecewise-linear interpolant of f at t_k = k dt (the trapezoidal rule on the step
    grid, a window end inside a step cutting its linear piece); ``window`` = (a, b), default the
    whole run, an end within :data:`SNAP` dt of a step time taken at that step time.  They sum to 1."""
    a, b = (_snap(v, dt) for v in _window(window, n_steps * dt))
    w = np.zeros(n_steps + 1)
    k0 = min(int(math.floor(a / dt)), n_steps - 1)
    k1 = min(int(math.ceil(b / dt)), n_steps)
    for k in range(k0, k1):          # the pieces [t_k, t_k+1] that overlap [a, b]
        tk, tk1 = k * dt, (k + 1) * dt
        lo, hi = max(a, tk), min(b, tk1)
        if hi <= lo:
            continue
        # (tk1-lo)^2 - (tk1-hi)^2 and (hi-tk)^2 - (lo-tk)^2, factored: no cancellation for hi - lo << dt
        w[k] += (hi - lo) * (2 * tk1 - lo - hi) / (2 * dt)
        w[k + 1] += (hi - lo) * (lo + hi - 2 * tk) / (2 * dt)
    return w / (b - a)


#: A window end closer than this many steps to a step time is moved onto it (no weights of
#: round-off size, ~1e-32, from a piece of length 1e-17 next to the grid point).
SNAP = 1e-9


def _snap(t: float, dt: float) -> float:
    """``t`` moved onto the nearest step time k dt when within :data:`SNAP` dt of it."""
    k = round(t / dt)
    return k * dt if abs(t / dt - k) <= SNAP else t


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
                  "(make_simulate(..., headroom=...); it sizes the lists of moving particles, a fixed, Eulerian "
                  "list holds its largest count and is never rebuilt)")
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
