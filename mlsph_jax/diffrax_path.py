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
topology.  A neighbour-list overflow inside the vector field raises at run time
(``equinox.error_if``) unless ``check_overflow=False``.
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
from .differentiable import default_steps
from .errors import InputError, NeighborOverflowError
from .integrate import make_stage_geometry
from .rhs import geometry, rhs
from .state import Kind, Params, Particles

__all__ = ["SSPRK3", "SSPRK3_TABLEAU", "ode_term", "make_solve", "solve", "to_particles", "final_particles",
           "neighbor_setup"]


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
    them (same cell size and ``headroom``).  ``nspec_or_nl`` may be a ready
    :class:`~mlsph_jax.neighbors.NeighborSpec` (an Eulerian list is then built from it) or, for
    Eulerian schemes, a ready :class:`~mlsph_jax.neighbors.NeighborList` (``nspec`` is then
    ``None``)."""
    scheme, domain = problem.scheme, problem.domain
    p0 = problem.particles if particles is None else particles
    h0 = scheme.beta * np.asarray(p0.vol) ** (1.0 / p0.dim)
    if isinstance(nspec_or_nl, nb.NeighborList):
        if scheme.moving:
            raise InputError("invalid nspec_or_nl: a NeighborList for moving particles (scheme.frame="
                             f"{scheme.frame!r}); allowed: a NeighborSpec (lists are rebuilt per evaluation) or None")
        return None, nspec_or_nl
    if isinstance(nspec_or_nl, nb.NeighborSpec):
        return nspec_or_nl, nb.update(np.asarray(p0.x), h0, nspec_or_nl)
    if nspec_or_nl is not None:
        raise InputError(f"invalid nspec_or_nl of type {type(nspec_or_nl).__name__}; allowed: "
                         "NeighborSpec, NeighborList or None")
    cell = scheme.support * float(h0.max()) * (2.5 if p0.dim == 1 else 1.5) if scheme.moving else None
    return nb.allocate(np.asarray(p0.x), h0, domain, support=scheme.support, headroom=headroom, cell_size=cell)


def _check_scheme(problem):
    if problem.scheme.limiter == "mood":
        raise InputError("invalid scheme.limiter='mood' for the diffrax path: MOOD limits the forward-Euler "
                         "sub-steps of SSP-RK3 and has no ODE form; allowed: 'none' (or use "
                         "mlsph_jax.differentiable.make_simulate)")


def _vector_field(problem, nspec, check_overflow: bool):
    scheme = problem.scheme
    stage_geometry = make_stage_geometry(scheme, problem.domain, nspec) if scheme.moving else None

    def vf(t, y, args):
        del t  # the semi-discrete system is autonomous
        params = args["params"]
        p = to_particles(problem, y, params, kind=args["kind"], ppd=args["ppd"])  # ghosts regenerated
        geom = args["geom"] if stage_geometry is None else stage_geometry(p)
        dx, dvol, dq = rhs(p, params, geom, scheme)
        fluid = p.kind == Kind.FLUID
        dx = jnp.where(fluid[:, None], dx, 0.0)
        dvol = jnp.where(fluid, dvol, 0.0)
        dq = jnp.where(fluid[:, None], dq, 0.0)
        if check_overflow and stage_geometry is not None:
            dq = eqx.error_if(dq, geom.overflow, "neighbour-list capacity overflowed in the diffrax vector field; "
                              "rerun with a larger headroom")
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
        geom = geometry(particles.x, particles.vol, nl0, problem.scheme, problem.domain)
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
                                    "rerun with a larger headroom")
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
               throw: bool = True) -> Callable[[Params, Particles], diffrax.Solution]:
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
    """
    _check_scheme(problem)
    t_end = float(problem.t_end if t_end is None else t_end)
    n_steps = default_steps(problem) if n_steps is None else int(n_steps)
    if n_steps < 1:
        raise InputError(f"invalid n_steps={n_steps}; allowed: a positive integer")
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
        return diffrax.diffeqsolve(term, solver, 0.0, t_end, first, y0, args, saveat=saveat,
                                   stepsize_controller=controller, adjoint=adjoint, max_steps=max_steps,
                                   throw=throw)

    solve_fn.n_steps = n_steps
    solve_fn.dt = t_end / n_steps
    solve_fn.t_end = t_end
    solve_fn.term = term
    return solve_fn


def solve(problem, solver: diffrax.AbstractSolver | None = None, *, params: Params | None = None,
          particles: Particles | None = None, jit: bool = True, **kw) -> diffrax.Solution:
    """One-shot :func:`make_solve` (same keywords) on ``problem.params``/``problem.particles``
    (or the given ones); turn the result into particles with :func:`final_particles`."""
    fn = make_solve(problem, solver, **kw)
    if jit:
        fn = jax.jit(fn)
    return fn(problem.params if params is None else params, problem.particles if particles is None else particles)
