"""The semi-discrete MLSPH-ALE / SPH-ALE system as a ``diffrax`` ODE (differentiable simulations).

The particle method is a method of lines: after the spatial discretisation (thesis eq. 4.36,
4.32, 4.28; SPEC §5.3) the state y = (x, V, V U) obeys the ODE system

    dy/dt = L(y),   L = :func:`mlsph_jax.rhs.rhs`,

which the built-in integrator advances with the Shu–Osher SSP-RK3 scheme (SPEC §7.1,
:func:`mlsph_jax.integrate.ssp_rk3_step`).  This module exposes L as a
:class:`diffrax.ODETerm` so that any ``diffrax`` solver, step-size controller and adjoint can be
used on it:

* :func:`ode_term` — ``(term, y0, args)``: the state ``y = (x, vol, q)`` is a pytree of floats
  only; the particle kinds, MOOD degrees and the ghost boundary live inside the vector field;
  the parameters (and the static geometry) travel in ``args`` so gradients flow through them;
* :class:`SSPRK3` — the Shu–Osher SSP-RK3 scheme written as a Butcher tableau;
* :func:`make_solve` / :func:`solve` — ``diffeqsolve`` with fixed steps (``dt = t_end/n_steps``
  exactly like :func:`mlsph_jax.differentiable.make_simulate`) or adaptive steps
  (:class:`diffrax.PIDController`), with any adjoint (default
  :class:`diffrax.RecursiveCheckpointAdjoint`);
* :func:`final_particles` / :func:`to_particles` — a state ``y`` back to :class:`Particles`.

Correspondence with the built-in step (so that ``SSPRK3`` reproduces it to round-off):

* the built-in stage k regenerates the ghosts from the stage state (``boundary.apply``),
  computes the stage geometry (once for Eulerian particles, from the *initial* state with a
  neighbour list built on the host; per stage for moving particles, with a fixed-capacity list
  ``nb.update(x, h, nspec)``), evaluates ``rhs`` and updates the **fluid** particles only.  The
  vector field here does the same in the same order: ``f(y) = 1_fluid * rhs(G(y))`` with
  ``G`` = rebuild the Particles + regenerate the ghosts.  Ghost, boundary and frozen components
  of y therefore have an exactly zero derivative: they keep their initial values throughout a
  solve, they are never read (the ghosts are regenerated from their parents before every
  evaluation), and :func:`to_particles` regenerates them when a state is read back, as the
  built-in step does after its last stage;
* the MOOD limiter (SPEC §7.2) acts on the forward-Euler sub-steps of SSP-RK3 and has no ODE
  form; ``scheme.limiter == "mood"`` is rejected (use :mod:`mlsph_jax.differentiable`).

What carries no gradient is the same as in :mod:`mlsph_jax.differentiable`: the neighbour
topology, sized by the run layer (:func:`mlsph_jax.run.plan_neighbors`, like ``make_simulate``).
A neighbour-list overflow inside the vector field raises at run time (``equinox.error_if``)
unless ``check_overflow=False``.

Failures are never silent: the solve of :func:`make_solve` adds the status word
(:class:`~mlsph_jax.status.Status`) of its saved states to ``sol.stats`` (``"status"``,
``"bad_particle"``, ``"failed_save"``: the first saved state that fails, -1 if none), computed
inside ``jit``; :func:`check` raises :class:`~mlsph_jax.errors.SimulationError` on it, and
:func:`solve` calls it.  A fixed step above the CFL limit of the initial state is refused before
solving (:func:`mlsph_jax.run.check_fixed_step`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import ClassVar

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from . import neighbors as nb
from .errors import InputError, NeighborOverflowError, SimulationError
from .integrate import cfl_dt, cfl_limiting_particle, complete_rows_if_needed, make_stage_geometry
from .rhs import geometry, rhs
from .run import check_fixed_step, default_steps, setup_run
from .spatial import refuse_in
from .state import Kind, Params, Particles
from .status import Status, combine, state_status

__all__ = ["SSPRK3", "SSPRK3_TABLEAU", "ode_term", "make_solve", "solve", "to_particles", "final_particles",
           "neighbor_setup", "solution_status", "check"]


# ---------------------------------------------------------------------------------------------
# SSP-RK3 as a Butcher tableau
# ---------------------------------------------------------------------------------------------

#: Shu–Osher SSP-RK3 (SPEC §7.1) in Butcher form.  Expanding the Shu–Osher stages
#:
#:     y1 = y + dt L(y)
#:     y2 = 3/4 y + 1/4 (y1 + dt L(y1))       = y + dt (1/4 k1 + 1/4 k2)
#:     y' = 1/3 y + 2/3 (y2 + dt L(y2))       = y + dt (1/6 k1 + 1/6 k2 + 2/3 k3)
#:
#: gives c = (0, 1, 1/2), a21 = 1, a31 = a32 = 1/4, b = (1/6, 1/6, 2/3).  The two forms are
#: algebraically identical; in floating point they differ only by the order of the additions
#: (round-off, ~1e-16 relative per step).  The embedded solution is the first two stages'
#: Heun / SSP-RK2 method b* = (1/2, 1/2, 0), a 3(2) pair, so ``b_error = b - b*``.
SSPRK3_TABLEAU = diffrax.ButcherTableau(
    c=np.array([1.0, 0.5]),
    a_lower=(np.array([1.0]), np.array([0.25, 0.25])),
    b_sol=np.array([1.0 / 6.0, 1.0 / 6.0, 2.0 / 3.0]),
    b_error=np.array([1.0 / 6.0 - 0.5, 1.0 / 6.0 - 0.5, 2.0 / 3.0]),
)


def _linear_interpolation(*, t0, t1, y0, y1, k):
    """Dense output between step ends (first order; exact at the step ends up to round-off)."""
    del k
    return diffrax.LocalLinearInterpolation(t0=t0, t1=t1, y0=y0, y1=y1)


class SSPRK3(diffrax.AbstractERK):
    """Shu–Osher's strong-stability-preserving 3-stage, 3rd-order Runge–Kutta scheme (SPEC §7.1,
    the time integrator of the thesis) as a ``diffrax`` explicit RK solver.

    Tableau :data:`SSPRK3_TABLEAU`: c = (0, 1, 1/2), a = ((1), (1/4, 1/4)), b = (1/6, 1/6, 2/3).
    It equals the Shu–Osher convex-combination form used by
    :func:`mlsph_jax.integrate.ssp_rk3_step` up to round-off (different order of the floating
    point additions).  It has an embedded 2nd-order (Heun) solution, so it also works with a
    :class:`diffrax.PIDController`; dense output is linear between step ends.
    """

    tableau: ClassVar[diffrax.ButcherTableau] = SSPRK3_TABLEAU
    interpolation_cls: ClassVar[Callable[..., diffrax.LocalLinearInterpolation]] = staticmethod(
        _linear_interpolation)

    def order(self, terms):
        del terms
        return 3


# ---------------------------------------------------------------------------------------------
# The ODE term
# ---------------------------------------------------------------------------------------------

def neighbor_setup(problem, nspec_or_nl=None, *, headroom: float = 1.6, particles: Particles | None = None):
    """Host side: ``(nspec, nl0)`` exactly as :func:`mlsph_jax.differentiable.make_simulate` sizes
    them (the run layer, :func:`mlsph_jax.run.setup_run`, same ``headroom``).  ``nspec_or_nl``
    may be a ready :class:`~mlsph_jax.neighbors.NeighborSpec` (an Eulerian list is then built
    from it) or, for Eulerian schemes, a ready :class:`~mlsph_jax.neighbors.NeighborList`
    (``nspec`` is then ``None``)."""
    scheme = problem.scheme
    if isinstance(nspec_or_nl, nb.NeighborList):
        if scheme.moving:
            raise InputError("invalid nspec_or_nl: a NeighborList for moving particles (scheme.frame="
                             f"{scheme.frame!r}); allowed: a NeighborSpec (lists are rebuilt per evaluation) or None")
        return None, nspec_or_nl
    if nspec_or_nl is not None and not isinstance(nspec_or_nl, nb.NeighborSpec):
        raise InputError(f"invalid nspec_or_nl of type {type(nspec_or_nl).__name__}; allowed: "
                         "NeighborSpec, NeighborList or None")
    setup = setup_run(problem, headroom=headroom, particles=particles, nspec=nspec_or_nl)
    return setup.nspec, setup.nl


def _check_scheme(problem):
    refuse_in(problem, "the diffrax path")
    if problem.scheme.component("limiter").acts_on_substeps:
        raise InputError("invalid scheme.limiter='mood' for the diffrax path: MOOD limits the forward-Euler "
                         "sub-steps of SSP-RK3 and has no ODE form; allowed: 'none' (or use "
                         "mlsph_jax.differentiable.make_simulate)")
    if problem.scheme.moving and problem.scheme.geometry_update != "stage":
        raise InputError(f"invalid scheme.geometry_update={problem.scheme.geometry_update!r} for the diffrax "
                         "path: a vector field has no Runge-Kutta step to hold its geometry over; allowed: "
                         "'stage' (or use mlsph_jax.differentiable.make_simulate or the chunked driver)")


def _vector_field(problem, nspec, check_overflow: bool):
    scheme = problem.scheme
    stage_geometry = make_stage_geometry(scheme, problem.domain, nspec, problem.boundary) if scheme.moving else None

    def vf(t, y, args):
        del t  # the semi-discrete system is autonomous
        params = args["params"]
        p = to_particles(problem, y, params, kind=args["kind"], ppd=args["ppd"])  # ghosts regenerated
        geom = args["geom"] if stage_geometry is None else stage_geometry(p)
        dx, dvol, dq = rhs(p, params, geom, scheme, problem.boundary)
        fluid = p.kind == Kind.FLUID
        dx = jnp.where(fluid[:, None], dx, 0.0)
        dvol = jnp.where(fluid, dvol, 0.0)
        dq = jnp.where(fluid[:, None], dq, 0.0)
        if check_overflow and stage_geometry is not None:
            dq = eqx.error_if(dq, jnp.asarray(geom.overflow) != 0,   # Status neighbour bits (or a bool)
                              "neighbour-list capacity overflowed in the diffrax vector field (row or cell "
                              "capacity, or the cell size); rerun with a larger headroom")
        return dx, dvol, dq

    return vf


def make_args(problem, params: Params, particles: Particles, nl0=None) -> dict:
    """``args`` of the vector field: the parameters, the particle kinds and MOOD degrees and, for
    Eulerian schemes, the static geometry computed from ``particles`` with the list ``nl0``
    (traceable: call it inside a differentiated function for gradients w.r.t. the initial
    positions)."""
    geom = None
    if not problem.scheme.moving:
        if nl0 is None:
            raise InputError("missing nl0 for an Eulerian scheme; allowed: the list from neighbor_setup")
        geom = geometry(particles.x, particles.vol, nl0, problem.scheme, problem.domain,
                        complete_rows_if_needed(particles, problem.scheme, problem.boundary))
    return {"params": params, "geom": geom, "kind": particles.kind, "ppd": particles.ppd}


def ode_term(problem, nspec_or_nl=None, *, headroom: float = 1.6, check_overflow: bool = True,
             params: Params | None = None, particles: Particles | None = None):
    """``(diffrax.ODETerm, y0, args)`` of the semi-discrete system of ``problem`` (module docstring).

    ``y0 = (x, vol, q)`` of ``particles`` (default ``problem.particles``); ``args`` from
    :func:`make_args` with ``params`` (default ``problem.params``).  ``nspec_or_nl``: see
    :func:`neighbor_setup` (default: sized like ``make_simulate``).  The Eulerian static geometry
    in ``args`` is checked for overflow here (host side).
    """
    _check_scheme(problem)
    params = problem.params if params is None else params
    particles = problem.particles if particles is None else particles
    nspec, nl0 = neighbor_setup(problem, nspec_or_nl, headroom=headroom, particles=particles)
    args = make_args(problem, params, particles, nl0)
    if check_overflow and args["geom"] is not None and bool(args["geom"].overflow):
        raise NeighborOverflowError("neighbour-list capacity overflow in the initial (static) geometry; "
                                    "rerun with a larger headroom (moving particles; a fixed, Eulerian list holds "
                                    "its largest count, decision 91)")
    term = diffrax.ODETerm(_vector_field(problem, nspec, check_overflow))
    return term, (particles.x, particles.vol, particles.q), args


def to_particles(problem, y, params: Params | None = None, *, kind=None, ppd=None) -> Particles:
    """Particles of a state ``y = (x, vol, q)`` with the static ``kind``/``ppd`` (default those of
    ``problem.particles``) and the ghosts regenerated by ``problem.boundary`` (if any), as the
    built-in step does before every stage and after the last one."""
    x, vol, q = y
    kind = problem.particles.kind if kind is None else kind
    ppd = problem.particles.ppd if ppd is None else ppd
    p = Particles(x=x, vol=vol, q=q, kind=kind, ppd=ppd)
    if problem.boundary is not None:
        p = problem.boundary.apply(p, problem.params if params is None else params)
    return p


def final_particles(problem, sol: diffrax.Solution, params: Params | None = None, index: int = -1,
                    particles: Particles | None = None) -> Particles:
    """Particles of the saved state ``index`` (default: the last) of a solution."""
    ref = problem.particles if particles is None else particles
    y = jax.tree_util.tree_map(lambda a: a[index], sol.ys)
    return to_particles(problem, y, params, kind=ref.kind, ppd=ref.ppd)


# ---------------------------------------------------------------------------------------------
# Solving
# ---------------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class _Options:
    solver: diffrax.AbstractSolver
    n_steps: int
    adaptive: bool
    rtol: float
    atol: float
    adjoint: diffrax.AbstractAdjoint
    saveat: diffrax.SaveAt
    max_steps: int
    dt0: float | None


def make_solve(problem, solver: diffrax.AbstractSolver | None = None, *, n_steps: int | None = None,
               t_end: float | None = None, adaptive: bool = False, rtol: float = 1e-6, atol: float = 1e-9,
               adjoint: diffrax.AbstractAdjoint | None = None, saveat: diffrax.SaveAt | None = None,
               ts=None, max_steps: int | None = None, dt0: float | None = None, nspec_or_nl=None,
               headroom: float = 1.6, check_overflow: bool = True, pcoeff: float = 0.0, icoeff: float = 1.0,
               throw: bool = True, cfl: float = 0.3,
               cfl_viscous: float = 0.125) -> Callable[[Params, Particles], diffrax.Solution]:
    """Build ``solve(params, particles) -> diffrax.Solution`` (pure, ``jit``/``grad``-able).

    * fixed steps (``adaptive=False``, default): exactly ``n_steps`` steps of size
      ``t_end / n_steps`` (:class:`diffrax.StepTo` on ``k t_end / n_steps``), the built-in
      differentiable path's step (:func:`mlsph_jax.differentiable.make_simulate`); ``n_steps``
      defaults to :func:`~mlsph_jax.differentiable.default_steps`;
    * adaptive (``adaptive=True``): :class:`diffrax.PIDController` (``rtol``, ``atol``,
      ``pcoeff``, ``icoeff``) from ``dt0`` (default ``t_end / n_steps``), at most ``max_steps``
      steps (default 4096);
    * ``solver``: default :class:`SSPRK3`; any diffrax ODE solver (``diffrax.Tsit5()``, ...);
    * ``adjoint``: default :class:`diffrax.RecursiveCheckpointAdjoint` (reverse mode through the
      solver with binomial checkpointing; ``checkpoints=None`` sizes it from ``max_steps``);
    * output: ``saveat`` (default: the final state; or ``ts`` = save times).

    Eulerian geometry is rebuilt inside ``solve`` from ``particles`` with the host-built list,
    like ``make_simulate``; the neighbour topology is fixed at build time.

    Status: ``sol.stats`` gains ``"status"``, ``"bad_particle"`` and ``"failed_save"``
    (:func:`solution_status` of the saved states; with fixed steps a saved state whose CFL limit,
    with ``cfl``/``cfl_viscous``, is below ``dt`` counts as ``DT_ABOVE_CFL``); check it on the host
    with :func:`check`.  Fixed steps: ``n_steps`` whose ``dt`` exceeds the CFL limit of the
    initial state is refused with an InputError (:func:`mlsph_jax.run.check_fixed_step`).
    """
    _check_scheme(problem)
    t_end = float(problem.t_end if t_end is None else t_end)
    n_steps = default_steps(problem, cfl=cfl, cfl_viscous=cfl_viscous, t_end=t_end) if n_steps is None \
        else int(n_steps)
    if n_steps < 1:
        raise InputError(f"invalid n_steps={n_steps}; allowed: a positive integer")
    if not adaptive:
        check_fixed_step(problem, n_steps, t_end, cfl=cfl, cfl_viscous=cfl_viscous)
    solver = SSPRK3() if solver is None else solver
    adjoint = diffrax.RecursiveCheckpointAdjoint() if adjoint is None else adjoint
    if saveat is None:
        saveat = diffrax.SaveAt(t1=True) if ts is None else diffrax.SaveAt(ts=jnp.asarray(ts, jnp.float64))
    nspec, nl0 = neighbor_setup(problem, nspec_or_nl, headroom=headroom)
    term = diffrax.ODETerm(_vector_field(problem, nspec, check_overflow))
    if adaptive:
        controller = diffrax.PIDController(rtol=rtol, atol=atol, pcoeff=pcoeff, icoeff=icoeff)
        first = t_end / n_steps if dt0 is None else float(dt0)
        max_steps = 4096 if max_steps is None else int(max_steps)
    else:
        steps = np.arange(n_steps + 1, dtype=np.float64) * (t_end / n_steps)
        steps[-1] = t_end
        controller = diffrax.StepTo(ts=jnp.asarray(steps))
        first = None
        max_steps = n_steps if max_steps is None else int(max_steps)

    def solve_fn(params: Params, particles: Particles) -> diffrax.Solution:
        args = make_args(problem, params, particles, nl0)
        y0 = (particles.x, particles.vol, particles.q)
        sol = diffrax.diffeqsolve(term, solver, 0.0, t_end, first, y0, args, saveat=saveat,
                                  stepsize_controller=controller, adjoint=adjoint, max_steps=max_steps,
                                  throw=throw)
        return solution_status(problem, sol, params, particles, dt=None if adaptive else t_end / n_steps,
                               cfl=cfl, cfl_viscous=cfl_viscous)

    solve_fn.n_steps = n_steps
    solve_fn.dt = t_end / n_steps
    solve_fn.t_end = t_end
    solve_fn.term = term
    return solve_fn


def solve(problem, solver: diffrax.AbstractSolver | None = None, *, params: Params | None = None,
          particles: Particles | None = None, jit: bool = True, check_status: bool = True,
          **kw) -> diffrax.Solution:
    """One-shot :func:`make_solve` (same keywords) on ``problem.params``/``problem.particles``
    (or the given ones); turn the result into particles with :func:`final_particles`.  Raises
    :class:`~mlsph_jax.errors.SimulationError` if a saved state failed (:func:`check`) unless
    ``check_status=False``."""
    fn = make_solve(problem, solver, **kw)
    if jit:
        fn = jax.jit(fn)
    sol = fn(problem.params if params is None else params, problem.particles if particles is None else particles)
    if check_status:
        check(sol)
    return sol


# ---------------------------------------------------------------------------------------------
# Status of a solution
# ---------------------------------------------------------------------------------------------

def solution_status(problem, sol: diffrax.Solution, params: Params | None = None,
                    particles: Particles | None = None, *, dt=None, cfl: float = 0.3,
                    cfl_viscous: float = 0.125) -> diffrax.Solution:
    """``sol`` with ``sol.stats`` extended by the status of its saved states (traceable, no
    gradient): ``"status"`` (:class:`~mlsph_jax.status.Status` bits of the first failing saved
    state, 0 if none), ``"bad_particle"`` (its first offending particle, -1) and
    ``"failed_save"`` (its index in ``sol.ts``/``sol.ys``, -1).  The fluid particles of each
    saved state (``kind``/``ppd`` of ``particles``, default the problem's) are checked like the
    driver's steps (:func:`mlsph_jax.status.state_status`); with a fixed step ``dt`` also
    ``dt`` against the state's CFL limit (``DT_ABOVE_CFL``).  Unused save slots (``ts = inf``)
    are skipped."""
    params = problem.params if params is None else params
    ref = problem.particles if particles is None else particles
    scheme = problem.scheme
    zero, none = jnp.asarray(0, jnp.int32), jnp.asarray(-1, jnp.int32)
    if sol.ys is None:
        bits, bad, first = zero, none, none
    else:
        def one(y):
            p = jax.lax.stop_gradient(to_particles(problem, y, params, kind=ref.kind, ppd=ref.ppd))
            b, i = state_status(p, params, scheme)
            if dt is not None:
                above = dt > cfl_dt(p, params, scheme, cfl, cfl_viscous)
                b, i = combine(b, i, jnp.where(above, jnp.int32(Status.DT_ABOVE_CFL), 0),
                               jnp.where(above, cfl_limiting_particle(p, params, scheme), -1))
            return b, i

        ys = jax.lax.stop_gradient(sol.ys)
        bits_k, bad_k = jax.vmap(one)(ys)
        used = jnp.isfinite(sol.ts) if sol.ts is not None else jnp.ones(bits_k.shape, bool)
        failing = used & (bits_k != 0)
        k = jnp.argmax(failing)
        any_fail = jnp.any(failing)
        bits = jnp.where(any_fail, bits_k[k], 0).astype(jnp.int32)
        bad = jnp.where(any_fail, bad_k[k], -1).astype(jnp.int32)
        first = jnp.where(any_fail, k, -1).astype(jnp.int32)
    stats = {**sol.stats, "status": bits, "bad_particle": bad, "failed_save": first}
    return eqx.tree_at(lambda s: s.stats, sol, stats)


def check(sol: diffrax.Solution) -> None:
    """Raise :class:`~mlsph_jax.errors.SimulationError` if the solve did not succeed
    (``sol.result``) or a saved state failed (``sol.stats["status"]`` of
    :func:`solution_status`), naming the cause, the saved time and the particle (host side)."""
    if not bool(sol.result == diffrax.RESULTS.successful):
        raise SimulationError(f"diffrax solve failed: {diffrax.RESULTS[sol.result]!s}")
    if "status" not in sol.stats:
        raise InputError("invalid sol: it has no status; allowed: a solution of make_solve/solve or one passed "
                         "through solution_status")
    st = Status(int(sol.stats["status"]))
    if st == Status.OK:
        return
    k, i = int(sol.stats["failed_save"]), int(sol.stats["bad_particle"])
    t = float(sol.ts[k])
    where = ""
    if i >= 0:
        x = np.asarray(sol.ys[0][k, i])
        where = f", particle {i} at x={np.array2string(x, precision=6)}"
    cls = NeighborOverflowError if st.neighbor_overflow_only else SimulationError
    raise cls(f"diffrax solve stopped being valid: {st.describe()} in the saved state {k} at t={t:.6g}{where}",
              time=t, particle=i if i >= 0 else None, status=st)
