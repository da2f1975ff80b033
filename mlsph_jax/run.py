"""The run layer: what every run path sets up the same way.

Three paths advance a :class:`~mlsph_jax.simulation.Problem`: the chunked host driver
(:class:`~mlsph_jax.simulation.Simulation`), the differentiated fixed-step runs
(:func:`mlsph_jax.differentiable.make_simulate`) and the diffrax solves
(:mod:`mlsph_jax.diffrax_path`).  They share, from here:

* neighbour sizing (:func:`plan_neighbors`, the one copy of the cell-size heuristic: for moving
  particles the cells are ``2.5`` (1D) / ``1.5`` (2D, 3D) times ``support * max(h)`` so that
  particles may move and ``h`` grow without regrowth) and capacity headroom;
* :class:`RunSetup` (:func:`setup_run`): the neighbour spec and initial list, the geometry
  (computed once from the initial list for Eulerian schemes, rebuilt per stage for moving
  particles), chunk compilation and cause-directed regrowth;
* the fixed-step admissibility check (:func:`check_fixed_step`): a fixed step count whose
  ``dt = t_end / n_steps`` exceeds the CFL limit of the initial state is refused before running,
  naming the smallest admissible step count, and :func:`default_steps`;
* the status word (:class:`~mlsph_jax.status.Status`, re-exported here) computed inside ``jit``
  on every path, and :func:`~mlsph_jax.status.failure` for the host-side error.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from . import integrate
from . import neighbors as nb
from .errors import InputError
from .rhs import check_conservation_projection
from .state import Domain, Params, Particles
from .status import Status, combine, failure, state_status

__all__ = ["RunSetup", "Status", "check_fixed_step", "cfl_limit", "combine", "default_steps", "failure",
           "moving_cell_size", "plan_neighbors", "setup_run", "smoothing_lengths", "state_status"]

#: Growth factor of a limit named by an overflow bit when the driver regrows.
REGROW_FACTOR = 1.3


def smoothing_lengths(particles: Particles, scheme) -> np.ndarray:
    """Host copy of ``h_i = beta V_i^(1/d)``."""
    return scheme.beta * np.asarray(particles.vol) ** (1.0 / particles.dim)


def moving_cell_size(h: np.ndarray, scheme, dim: int) -> float | None:
    """Cell size for moving particles (``None``, i.e. the tight automatic size, for Eulerian
    ones): room for particles to move and ``h`` to grow without regrowing (recompiling)."""
    if not scheme.moving:
        return None
    return scheme.support * float(np.max(h)) * (2.5 if dim == 1 else 1.5)


def moving_min_headroom(dim: int) -> float:
    """Smallest capacity headroom the driver uses for moving particles: 2.0 in 1D (a shock
    tube's Lagrangian particles compress by large factors), else 1.3, the
    ``scheme.neighbor_headroom`` default (decision 84: every padding slot costs every pass over
    the stencil of every stage; a compressing 2D/3D flow regrows, i.e. stops the chunk, grows the
    capacity from the counts it measured and recompiles, never drops a neighbour)."""
    return 2.0 if dim == 1 else 1.3


#: Capacity headroom of fixed (Eulerian) particles: none.  Their list is built once from the
#: positions and volumes that never change, so its largest count is exactly what every stage needs
#: (decision 91: K = 31 instead of 41 slots at N = 4e4; every padding slot costs every pass over
#: the stencil).  A list rebuilt on the host from other particles (a restart, a user edit) still
#: regrows (:meth:`RunSetup.host_geometry`).
FIXED_HEADROOM = 1.0


def plan_neighbors(particles: Particles, scheme, domain: Domain, *, headroom: float,
                   min_moving_headroom: bool | float = False) -> tuple[nb.NeighborSpec, nb.NeighborList]:
    """``(spec, list)`` sized from ``particles`` (host side): the cell size of
    :func:`moving_cell_size` and capacities ``ceil(max count * headroom)``.  ``headroom`` applies
    to moving particles only (fixed ones get :data:`FIXED_HEADROOM`, their largest count).  With
    ``min_moving_headroom`` (the driver, which can regrow but recompiles each time) the headroom
    of moving particles is at least :func:`moving_min_headroom` (``True``) or the number given
    (``scheme.moving_neighbor_headroom``); a differentiated run (fixed capacity) uses
    ``headroom`` as given."""
    h = smoothing_lengths(particles, scheme)
    if not scheme.moving:
        headroom = FIXED_HEADROOM
    elif min_moving_headroom is not False:
        floor = (moving_min_headroom(particles.dim) if isinstance(min_moving_headroom, bool)
                 else float(min_moving_headroom))
        headroom = max(headroom, floor)
    return nb.allocate(np.asarray(particles.x), h, domain, support=scheme.support, headroom=headroom,
                       cell_size=moving_cell_size(h, scheme, particles.dim))


@dataclasses.dataclass(frozen=True)
class RunSetup:
    """Neighbour spec, initial list and geometry policy of one run (see the module docstring).

    ``nl`` is the list of the particles the setup was sized from: the (only) list of an
    Eulerian run and the initial one of a moving run.
    """

    scheme: object
    domain: Domain
    boundary: object | None
    nspec: nb.NeighborSpec
    nl: nb.NeighborList
    headroom: float

    @property
    def moving(self) -> bool:
        return bool(self.scheme.moving)

    # --- geometry ----------------------------------------------------------------------------
    def geometry_fn(self, particles: Particles):
        """Traceable ``p -> Geometry`` for a run starting from ``particles``: for Eulerian
        schemes the geometry of ``particles`` with the setup's list, computed once (here) and
        reused by every stage; for moving particles the list rebuilt per stage with the
        setup's fixed spec.  ``Geometry.overflow`` holds the :class:`Status` neighbour bits."""
        if self.moving:
            return integrate.make_stage_geometry(self.scheme, self.domain, self.nspec, self.boundary)
        from .rhs import geometry

        complete = integrate.complete_rows_if_needed(particles, self.scheme, self.boundary)
        g = integrate.with_overflow_bits(geometry(particles.x, particles.vol, self.nl, self.scheme, self.domain,
                                                  complete), self.nl)
        return lambda p: g

    def initial_status(self):
        """Neighbour bits of the setup's list (0 unless sized with an explicit capacity)."""
        return jnp.asarray(0 if self.moving else self.nl.overflow_bits, jnp.int32)

    def host_geometry(self, particles: Particles):
        """``(setup, geometry)`` for the driver: for Eulerian schemes the list of ``particles``
        (regrown on the host if it overflows) and its geometry; ``(self, None)`` for moving
        particles (the chunk rebuilds lists per stage)."""
        if self.moving:
            return self, None
        h = self.scheme.beta * particles.vol ** (1.0 / particles.dim)
        nspec, nl = nb.update_or_grow(particles.x, h, self.nspec)
        new = dataclasses.replace(self, nspec=nspec, nl=nl)
        return new, integrate.static_geometry(particles, nl, self.scheme, self.domain, self.boundary)

    # --- compilation ------------------------------------------------------------------------
    def make_chunk(self, control: integrate.StepControl, n_steps: int, sharding=None):
        """Jitted ``chunk(carry, params, static_geom, t_stop)`` of :func:`mlsph_jax.integrate.make_chunk`
        (``sharding``: the :class:`mlsph_jax.sharding.ParticleSharding` or
        :class:`mlsph_jax.spatial.SpatialSharding` of a multi-device run)."""
        from .spatial import SpatialSharding

        spatial = sharding if isinstance(sharding, SpatialSharding) else None
        return integrate.make_chunk(self.scheme, self.domain, control, n_steps,
                                    nspec=self.nspec if self.moving else None, boundary=self.boundary,
                                    sharding=None if spatial else sharding, spatial=spatial)

    # --- regrowth -----------------------------------------------------------------------------
    def regrow(self, particles: Particles, status) -> RunSetup:
        """A setup whose neighbour limits named by the overflow bits of ``status`` grow by at
        least :data:`REGROW_FACTOR` (``ROW``: the row capacity, ``CELL``: the cell capacity,
        ``REACH``: the cell size), everything re-sized from ``particles`` (the last good state,
        which may still fit the old limits) with the setup's headroom; never shrinks."""
        st = Status(int(status))
        old = self.nspec
        xa = np.asarray(particles.x)
        h = smoothing_lengths(particles, self.scheme)
        n = xa.shape[0]
        cell = old.cell_size * REGROW_FACTOR if st & Status.NEIGHBOR_OVERFLOW_REACH else old.cell_size
        new = nb.grow(dataclasses.replace(old, cell_size=cell), xa, h, headroom=self.headroom)
        cap, ccap = new.capacity, new.cell_capacity
        if st & Status.NEIGHBOR_OVERFLOW_ROW:
            cap = max(cap, min(n, math.ceil(old.capacity * REGROW_FACTOR)))
        if st & Status.NEIGHBOR_OVERFLOW_CELL:
            ccap = max(ccap, min(n, math.ceil(old.cell_capacity * REGROW_FACTOR)))
        spec = dataclasses.replace(new, capacity=int(cap), cell_capacity=int(ccap))
        nl = nb.update(xa, h, spec)
        return dataclasses.replace(self, nspec=spec, nl=nl)


def setup_run(problem, *, headroom: float = 1.3, min_moving_headroom: bool | float = False,
              particles: Particles | None = None, nspec: nb.NeighborSpec | None = None) -> RunSetup:
    """The :class:`RunSetup` of ``problem`` (sized from ``particles``, default the problem's).

    ``nspec``: use this spec instead of sizing one (the list is built from it).  Walls whose
    velocity crosses them are refused here, on every run path (``check_motion`` of the boundary,
    with the problem's Params; skipped when they are traced, e.g. a problem built inside a
    transformation: the check is host side), and so is ``scheme.conservation_projection`` on a
    layout with particles that are not fluid (:func:`mlsph_jax.rhs.check_conservation_projection`)."""
    check_motion = getattr(problem.boundary, "check_motion", None)
    if check_motion is not None and not any(isinstance(v, jax.core.Tracer)
                                            for v in jax.tree_util.tree_leaves(dict(problem.params))):
        check_motion(problem.params)
    p = problem.particles if particles is None else particles
    if not isinstance(p.kind, jax.core.Tracer):
        check_conservation_projection(problem.scheme, p.kind, problem.boundary, problem.params)
    if nspec is None:
        nspec, nl = plan_neighbors(p, problem.scheme, problem.domain, headroom=headroom,
                                   min_moving_headroom=min_moving_headroom)
    else:
        nl = nb.update(np.asarray(p.x), smoothing_lengths(p, problem.scheme), nspec)
    return RunSetup(problem.scheme, problem.domain, problem.boundary, nspec, nl, float(headroom))


# --------------------------------------------------------------------------------------------
# fixed time steps
# --------------------------------------------------------------------------------------------

def cfl_limit(problem, *, cfl: float = 0.3, cfl_viscous: float = 0.125, particles: Particles | None = None,
              params: Params | None = None) -> float:
    """Host value of :func:`mlsph_jax.integrate.cfl_dt` of the initial state."""
    p = problem.particles if particles is None else particles
    prm = problem.params if params is None else params
    return float(integrate.cfl_dt(p, prm, problem.scheme, cfl, cfl_viscous))


def default_steps(problem, cfl: float = 0.3, safety: float = 0.8, cfl_viscous: float = 0.125,
                  t_end: float | None = None) -> int:
    """Fixed step count for ``t_end`` (default the problem's): the initial CFL step times
    ``safety`` (host side)."""
    t_end = float(problem.t_end if t_end is None else t_end)
    dt0 = cfl_limit(problem, cfl=cfl, cfl_viscous=cfl_viscous)
    return max(1, math.ceil(t_end / (safety * dt0)))


def check_fixed_step(problem, n_steps: int, t_end: float, *, cfl: float = 0.3, cfl_viscous: float = 0.125,
                     name: str = "n_steps") -> float:
    """Refuse (``InputError``) a fixed step ``dt = t_end / n_steps`` above the CFL limit of the
    initial state (:func:`cfl_limit` with ``cfl``/``cfl_viscous``); the message names
    ``n_steps``, ``dt``, the limit and the smallest admissible step count
    ``ceil(t_end / dt_cfl)``.  Returns the limit."""
    limit = cfl_limit(problem, cfl=cfl, cfl_viscous=cfl_viscous)
    if not (math.isfinite(limit) and limit > 0):
        raise InputError(f"invalid initial state: its CFL limit is {limit!r} (cfl={cfl}); allowed: a state "
                         "with finite, positive sound speeds and volumes")
    dt = t_end / n_steps
    if dt > limit * (1.0 + 1e-12):
        n_min = max(1, math.ceil(t_end / limit))
        raise InputError(
            f"invalid {name}={n_steps}: the fixed step dt = t_end / {name} = {t_end:.6g} / {n_steps} = {dt:.4g} "
            f"exceeds the CFL limit {limit:.4g} of the initial state (cfl={cfl}, cfl_viscous={cfl_viscous}), "
            f"so the run would be unstable; allowed: {name} >= {n_min} (or the default, "
            f"{default_steps(problem, cfl=cfl, cfl_viscous=cfl_viscous, t_end=t_end)} steps)")
    return limit
