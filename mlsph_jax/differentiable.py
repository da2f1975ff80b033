"""Differentiable whole-run simulation: ``simulate(params, particles) -> SimOutput``.

:func:`make_simulate` turns a :class:`~mlsph_jax.simulation.Problem` into a pure function that
runs a fixed number of SSP-RK3 steps of fixed size and returns the final state, the time series
of differentiable diagnostics and the neighbour-overflow flag.  It is ``jit``-able and
differentiable with ``jax.grad``, ``jax.jacfwd`` and ``jax.vjp`` with respect to every float in
the parameter pytree (EOS constants, viscosity, body force, wall velocities, ...), the initial
fields and the particle positions.

What carries no gradient: the topology (neighbour indices, fixed-capacity lists sized on the
host from the initial state; rebuilt per stage for moving particles with the same capacity) and
the MOOD flags (:mod:`mlsph_jax.mood`).  A neighbour overflow during a differentiated run is
reported in ``SimOutput.overflow``; :func:`run_differentiable` raises
:class:`~mlsph_jax.errors.NeighborOverflowError` on it (never a silent truncation).

Time step: fixed, ``dt = t_end / n_steps``.  An adaptive CFL step would make the number of steps
depend on the parameters; with a fixed count the outputs are smooth functions of them.  By
default ``n_steps`` comes from the initial CFL step of the problem with a safety factor
(:func:`default_steps`).

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

from . import neighbors as nb
from .errors import InputError, NeighborOverflowError
from .integrate import cfl_dt, make_stage_geometry, ssp_rk3_step
from .rhs import geometry
from .state import Kind, Params, Particles

CHECKPOINTS = ("none", "step", "nested")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SimOutput:
    """Result of a differentiable run: final particles, ``series[name][k]`` recorded after every
    ``record_every`` steps (plus the initial value at index 0), the record times, and whether a
    neighbour list overflowed."""

    particles: Particles
    series: dict
    times: jax.Array
    overflow: jax.Array


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


def default_steps(problem, cfl: float = 0.3, safety: float = 0.8, cfl_viscous: float = 0.125) -> int:
    """Fixed step count for ``t_end``: the initial CFL step times ``safety`` (host side)."""
    dt0 = float(cfl_dt(problem.particles, problem.params, problem.scheme, cfl, cfl_viscous))
    return max(1, math.ceil(problem.t_end / (safety * dt0)))


def make_simulate(problem, *, n_steps: int | None = None, t_end: float | None = None,
                  checkpoint: str = "nested", segment: int | None = None, policy=None,
                  record_every: int = 1, diagnostics: Callable | None = None,
                  headroom: float = 1.6) -> Callable[[Params, Particles], SimOutput]:
    """Build ``simulate(params, particles) -> SimOutput`` for ``problem`` (module docstring).

    ``diagnostics(particles, t, params) -> dict`` of differentiable scalars recorded every
    ``record_every`` steps (default :func:`base_diagnostics`, plus the problem's own
    ``differentiable_diagnostics`` when it has one).  ``n_steps`` must be a multiple of
    ``record_every``.  Nested segments are whole multiples of ``record_every`` (a record is taken
    at the end of a block of steps), so keep ``record_every`` <= ~sqrt(n_steps) for the nested
    memory saving: recording only at the end leaves one segment, i.e. the storage of ``"step"``.
    """
    if checkpoint not in CHECKPOINTS:
        raise InputError(f"invalid checkpoint={checkpoint!r}; allowed: {', '.join(CHECKPOINTS)}")
    t_end = float(problem.t_end if t_end is None else t_end)
    n_steps = default_steps(problem) if n_steps is None else int(n_steps)
    if n_steps < 1 or record_every < 1 or n_steps % record_every:
        raise InputError(f"invalid n_steps={n_steps} / record_every={record_every}; allowed: positive integers "
                         "with n_steps a multiple of record_every")
    dt = t_end / n_steps
    scheme, domain, boundary = problem.scheme, problem.domain, problem.boundary
    p0 = problem.particles
    h0 = scheme.beta * np.asarray(p0.vol) ** (1.0 / p0.dim)
    cell = scheme.support * float(h0.max()) * (2.5 if p0.dim == 1 else 1.5) if scheme.moving else None
    nspec, nl0 = nb.allocate(np.asarray(p0.x), h0, domain, support=scheme.support, headroom=headroom, cell_size=cell)
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
        if scheme.moving:
            geom_fn = make_stage_geometry(scheme, domain, nspec)
            overflow0 = jnp.asarray(False)
        else:
            g = geometry(particles.x, particles.vol, nl0, scheme, domain)
            geom_fn = lambda p: g  # noqa: E731
            overflow0 = g.overflow

        def step(carry, _):
            p, ovf = carry
            p2, o, _stats = ssp_rk3_step(p, params, dt, scheme, geom_fn, boundary)
            return (p2, ovf | o), None

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
            (pf, ovf), rec = jax.lax.scan(segment_fn, (particles, overflow0), ks)
            rec = jax.tree_util.tree_map(lambda a: a.reshape((n_rec,) + a.shape[2:]), rec)
        else:
            (pf, ovf), rec = jax.lax.scan(block, (particles, overflow0), jnp.arange(n_rec))
        first = diag(particles, 0.0, params)
        series = {k: jnp.concatenate([jnp.asarray(first[k])[None], rec[k]]) for k in rec}
        times = jnp.arange(n_rec + 1) * (record_every * dt)
        return SimOutput(pf, series, times, ovf)

    simulate.n_steps = n_steps
    simulate.dt = dt
    simulate.record_every = record_every
    return simulate


def _segment(n_steps: int, record_every: int) -> int:
    """A divisor of n_steps (multiple of record_every) near sqrt(n_steps)."""
    target = max(record_every, int(round(math.sqrt(n_steps))))
    cands = [s for s in range(record_every, n_steps + 1, record_every) if n_steps % s == 0]
    return min(cands, key=lambda s: abs(s - target))


def run_differentiable(simulate, params: Params, particles: Particles) -> SimOutput:
    """Run ``simulate`` and raise on a neighbour overflow (host check; not for use inside grad —
    there check ``SimOutput.overflow`` yourself or call :func:`check_overflow` afterwards)."""
    out = simulate(params, particles)
    check_overflow(out)
    return out


def check_overflow(out: SimOutput) -> None:
    if bool(out.overflow):
        raise NeighborOverflowError(
            "neighbour-list capacity overflowed during a differentiated run (its capacity is fixed so the "
            "topology carries no gradient); rerun with a larger headroom (make_simulate(..., headroom=...))")


def param_paths(params: Params) -> list[str]:
    """Names of the float parameters (the keys ``--wrt`` accepts)."""
    return [k for k in params if jnp.issubdtype(jnp.asarray(params[k]).dtype, jnp.floating)]


def with_param(params: Params, key: str, value) -> Params:
    """A copy of ``params`` with ``key`` replaced (differentiable in ``value``)."""
    if key not in params:
        raise InputError(f"invalid parameter {key!r}; allowed: {', '.join(param_paths(params))}")
    vals: Mapping = {k: params[k] for k in params}
    return Params({**vals, key: value})
