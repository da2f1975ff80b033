"""The status word of a run: one bit per cause of failure, computed inside ``jit`` on every path.

Every run path (the chunked driver :class:`mlsph_jax.simulation.Simulation`, the differentiated
runs of :func:`mlsph_jax.differentiable.make_simulate` and the :mod:`mlsph_jax.diffrax_path`
solves) computes the same :class:`Status` of every candidate state it produces, together with
the first offending particle, without a host synchronisation.  The host reads it afterwards
(once per chunk, once per differentiated run) and either fixes the cause (the driver grows the
neighbour limit named by the bit) or raises :class:`~mlsph_jax.errors.SimulationError` naming
the step, the time, the particle and the cause (:func:`failure`).

Only fluid particles are checked; boundary, frozen and ghost particles are never updated by a
step (their state is whatever the case or the boundary regeneration gave them).
"""

from __future__ import annotations

import enum

import jax
import jax.numpy as jnp
import numpy as np

from . import neighbors as nb
from .eos import get_eos, to_primitive
from .errors import NeighborOverflowError, SimulationError
from .state import Kind, Params, Particles

__all__ = ["Status", "state_status", "combine", "failure"]


class Status(enum.IntFlag):
    """Causes of a failed step as bits (several may be set at once; ``OK`` = 0).

    The neighbour bits equal :data:`mlsph_jax.neighbors.OVERFLOW_ROW` / ``OVERFLOW_CELL`` /
    ``OVERFLOW_REACH``, so ``NeighborList.overflow_bits`` is a status word as it is.
    """

    OK = 0
    NEIGHBOR_OVERFLOW_ROW = nb.OVERFLOW_ROW
    NEIGHBOR_OVERFLOW_CELL = nb.OVERFLOW_CELL
    NEIGHBOR_OVERFLOW_REACH = nb.OVERFLOW_REACH
    NONFINITE = 8
    INADMISSIBLE = 16
    NEGATIVE_DENSITY = 32
    NEGATIVE_VOLUME = 64
    DT_UNDERFLOW = 128
    DT_ABOVE_CFL = 256
    MOOD_UNRESOLVED = 512
    GHOST_BAND = 1024
    WALL_CROSSED = 2048
    BOUNDARY_OVERFLOW = 4096
    AREA_CORRECTION_UNCONVERGED = 8192
    #: any neighbour-list overflow (the three neighbour bits)
    NEIGHBOR_OVERFLOW = NEIGHBOR_OVERFLOW_ROW | NEIGHBOR_OVERFLOW_CELL | NEIGHBOR_OVERFLOW_REACH

    @property
    def causes(self) -> list[Status]:
        """The single-bit members set in this status word."""
        return [s for s in _DESCRIPTIONS if s & self]

    @property
    def neighbor_overflow_only(self) -> bool:
        """True if the only causes are neighbour-list overflows (the driver can regrow)."""
        return bool(self) and not (self & ~Status.NEIGHBOR_OVERFLOW)

    def describe(self) -> str:
        """Human-readable causes, e.g. ``"non-finite value (NaN/inf) in the state"``."""
        if not self:
            return "ok"
        return "; ".join(_DESCRIPTIONS[s] for s in self.causes)


_DESCRIPTIONS = {
    Status.NONFINITE: "non-finite value (NaN/inf) in the state",
    Status.NEGATIVE_VOLUME: "non-positive particle volume",
    Status.NEGATIVE_DENSITY: "non-positive density",
    Status.INADMISSIBLE: ("physically inadmissible state for the equation of state (EOS.admissible: p > 0 for "
                          "an ideal gas, p + pc > 0 for a stiffened gas)"),
    Status.MOOD_UNRESOLVED: ("MOOD flags not resolved within scheme.mood_max_iter iterations (a particle kept a "
                             "flagged, possibly invalid state)"),
    Status.DT_ABOVE_CFL: "fixed time step above the CFL limit of the current state",
    Status.GHOST_BAND: ("a fluid particle entered the ghost band of a mirror wall it has no ghost across (ghosts "
                        "are assigned at setup; mirror walls need flows parallel to the walls or Eulerian particles)"),
    Status.WALL_CROSSED: ("a fluid particle crossed a boundary-integral wall (inside a body, outside a container or "
                          "beyond a wall segment; nothing keeps moving particles in the fluid but the wall pressure)"),
    Status.BOUNDARY_OVERFLOW: ("a boundary-integral wall point has more particles within its support than the stencil "
                               "capacity sized at set-up (the particles crowded against a wall), or its support "
                               "outgrew the cells of the wall-stencil search (the particles next to a wall grew)"),
    Status.AREA_CORRECTION_UNCONVERGED: ("the conjugate-gradient solve of scheme.area_correction stopped at its "
                                         "iteration cap (area_correction.CG_MAXITER) above its tolerance: the area "
                                         "vectors are only partly corrected"),
    Status.DT_UNDERFLOW: "time step underflow (below time.dt_min * t_end)",
    Status.NEIGHBOR_OVERFLOW_ROW: "neighbour-list overflow: a particle has more neighbours than the row capacity",
    Status.NEIGHBOR_OVERFLOW_CELL: "neighbour-list overflow: a cell holds more particles than the cell capacity",
    Status.NEIGHBOR_OVERFLOW_REACH: "neighbour-list overflow: a support radius exceeds the cell size",
}

#: Order in which the first offending particle is chosen when several causes are set.
_PARTICLE_PRIORITY = (Status.NONFINITE, Status.NEGATIVE_VOLUME, Status.NEGATIVE_DENSITY, Status.INADMISSIBLE)


def first_index(mask) -> jax.Array:
    """Index of the first particle where ``mask`` holds, or -1 (int32; traceable)."""
    return jnp.where(jnp.any(mask), jnp.argmax(mask), -1).astype(jnp.int32)


def state_status(p: Particles, params: Params, scheme, first=first_index) -> tuple[jax.Array, jax.Array]:
    """``(status bits int32, first offending particle int32 or -1)`` of a state (traceable).

    Checks the fluid particles: finite x, V and V U (NONFINITE); V > 0 (NEGATIVE_VOLUME);
    rho > 0 (NEGATIVE_DENSITY); the EOS admissibility ``get_eos(scheme.eos).admissible(rho, p)``
    of the remaining particles (INADMISSIBLE).  Each particle is counted under its first cause
    only, in that order.  No gradient flows through it.  ``first(mask)``: the reported particle
    of a cause (default :func:`first_index`; the spatial decomposition's collective version
    returns the smallest original index over every shard).
    """
    p = jax.lax.stop_gradient(p)
    fluid = p.kind == Kind.FLUID
    finite = (jnp.all(jnp.isfinite(p.q), axis=1) & jnp.all(jnp.isfinite(p.x), axis=1) & jnp.isfinite(p.vol))
    nonfinite = fluid & ~finite
    negvol = fluid & finite & (p.vol <= 0)
    rest = fluid & finite & ~negvol
    negrho = rest & (p.q[:, 0] <= 0)
    rest = rest & ~negrho
    eos = get_eos(scheme.eos)
    safe_vol = jnp.where(rest, p.vol, 1.0)
    safe_q = jnp.where(rest[:, None], p.q, jnp.ones_like(p.q))
    prim = to_primitive(safe_q / safe_vol[:, None], eos, params)
    inadmissible = rest & ~eos.admissible(prim.rho, prim.p, params)
    masks = {Status.NONFINITE: nonfinite, Status.NEGATIVE_VOLUME: negvol, Status.NEGATIVE_DENSITY: negrho,
             Status.INADMISSIBLE: inadmissible}
    bits = jnp.zeros((), jnp.int32)
    bad = jnp.asarray(-1, jnp.int32)
    for s in reversed(_PARTICLE_PRIORITY):   # the highest priority cause wins the particle
        f = first(masks[s])
        hit = f >= 0
        bits = bits | jnp.where(hit, jnp.int32(s), 0)
        bad = jnp.where(hit, f, bad)
    return bits, bad


def combine(bits_a, bad_a, bits_b, bad_b):
    """Merge two (bits, particle) pairs: bits are OR-ed, the particle of ``a`` wins if it has one."""
    return bits_a | bits_b, jnp.where(bad_a >= 0, bad_a, bad_b).astype(jnp.int32)


def failure(status, *, step: int, time: float, particle: int | None = None, x=None,
            detail: str = "", last_good: str = "") -> SimulationError:
    """The host-side error for a failed run: names the cause, step, start time and particle.

    Returns a :class:`~mlsph_jax.errors.NeighborOverflowError` (a ``SimulationError``) when the
    only causes are neighbour-list overflows, else a ``SimulationError``.
    """
    st = Status(int(status))
    where = ""
    if particle is not None and int(particle) >= 0:
        where = f", particle {int(particle)}"
        if x is not None:
            where += f" at x={np.array2string(np.asarray(x), precision=6)}"
    msg = f"simulation stopped: {st.describe()} in step {int(step)} starting at t={float(time):.6g}{where}"
    if detail:
        msg += f"; {detail}"
    if last_good:
        msg += f"; {last_good}"
    cls = NeighborOverflowError if st.neighbor_overflow_only else SimulationError
    return cls(msg, step=int(step), time=float(time),
               particle=int(particle) if particle is not None and int(particle) >= 0 else None, status=st)
