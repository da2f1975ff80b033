"""Host-side driver: runs a :class:`Problem` chunk by chunk, writes outputs, stops loudly.

The time loop is a sequence of jitted ``lax.scan`` chunks (:mod:`mlsph_jax.integrate`); between
chunks the host reads the carry's status (one synchronisation per chunk), writes snapshots at
the output times, updates the progress bar and handles neighbour-capacity overflow by growing
the capacity and resuming from the last good state (the failing step was never committed).
Any other failure (NaN, non-positive density or volume, time-step underflow) raises
:class:`~mlsph_jax.errors.SimulationError` naming the step, time and particle, after the last
good state has been written as a snapshot and ``summary.json`` records the failure.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Mapping
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from . import io
from . import neighbors as nb
from .eos import get_eos, to_primitive
from .errors import NeighborOverflowError, SimulationError
from .integrate import MOOD_STATS, Carry, Status, StepControl, initial_carry, make_chunk, static_geometry
from .scheme import Scheme
from .state import Domain, Kind, Params, Particles


@dataclasses.dataclass
class Problem:
    """A ready-to-run simulation: initial particles, parameters, scheme, domain and end time,
    plus the case's metrics (``metrics(particles, t, params) -> dict``) and plotting hook
    (``plot(out_dir, particles, t, params)``), an optional ``boundary`` (ghost regeneration,
    :class:`mlsph_jax.boundaries.MirrorWalls`), ``diagnostics(particles, t, params) -> dict``
    recorded at every output time (the ``timeseries`` of the summary and ``timeseries.csv``) and
    ``steady_tol``: when > 0 the run stops early once the velocity changes by less than
    ``steady_tol`` (relative to its maximum, per unit of time) between two output times.
    ``differentiable_diagnostics`` / ``differentiable_metrics``: jnp versions recorded by
    :func:`mlsph_jax.differentiable.make_simulate` (time series) and offered as objectives by
    :mod:`mlsph_jax.sensitivity`."""

    case: str
    particles: Particles
    params: Params
    scheme: Scheme
    domain: Domain
    t_end: float
    metrics: Callable[[Particles, float, Params], Mapping[str, float]] | None = None
    plot: Callable[[Path, Particles, float, Params], None] | None = None
    config: Mapping | None = None
    description: str = ""
    boundary: object | None = None
    diagnostics: Callable[[Particles, float, Params], Mapping[str, float]] | None = None
    steady_tol: float = 0.0
    differentiable_diagnostics: Callable[[Particles, float, Params], Mapping] | None = None
    differentiable_metrics: Callable[[Particles, float, Params], Mapping] | None = None


@dataclasses.dataclass
class Result:
    """Outcome of :meth:`Simulation.run`: final particles and the summary written to disk."""

    particles: Particles
    summary: dict
    out_dir: Path | None


def snapshot_fields(p: Particles, params: Params, scheme: Scheme) -> dict[str, np.ndarray]:
    """Fields written per snapshot (the output contract: x, vol, rho, vel, p, e, ppd, kind)."""
    eos = get_eos(scheme.eos)
    pr = to_primitive(p.U, eos, params)
    out = {"x": p.x, "vol": p.vol, "rho": pr.rho, "vel": pr.vel, "p": pr.p, "ppd": p.ppd, "kind": p.kind}
    if eos.has_energy:
        out["e"] = pr.e
    return {k: np.asarray(v) for k, v in out.items()}


def conserved_totals(p: Particles) -> np.ndarray:
    """sum_i V_i U_i over fluid and frozen particles (ghosts are images, not carriers)."""
    return np.asarray(jnp.sum(jnp.where((p.kind != Kind.GHOST)[:, None], p.q, 0.0), axis=0))


MAX_REGROWTHS = 8


class Simulation:
    """Runs a :class:`Problem` with SSP-RK3 in jitted chunks (one compilation per case)."""

    def __init__(self, problem: Problem, *, cfl: float = 0.3, dt: float = 0.0, chunk: int = 50,
                 max_steps: int = 1_000_000, dt_min: float = 1e-14, headroom: float = 1.3,
                 cfl_viscous: float = 0.125):
        self.problem = problem
        self.control = StepControl(cfl=cfl, cfl_viscous=cfl_viscous, dt_fixed=dt, dt_min=dt_min * problem.t_end)
        self.chunk_steps = int(chunk)
        self.max_steps = int(max_steps)
        self.headroom = headroom
        self._regrowths = 0
        p = problem.particles
        h = problem.scheme.beta * np.asarray(p.vol) ** (1.0 / p.dim)
        cell = None
        if problem.scheme.moving:  # room for particles to move without regrowing (recompiling)
            cell = problem.scheme.support * float(h.max()) * (2.5 if p.dim == 1 else 1.5)
            headroom = max(headroom, 2.0 if p.dim == 1 else 1.6)
        self.nspec, self.nl = nb.allocate(np.asarray(p.x), h, problem.domain, support=problem.scheme.support,
                                          headroom=headroom, cell_size=cell)
        self._build()

    def _build(self):
        pb = self.problem
        self._chunk = make_chunk(pb.scheme, pb.domain, self.control, self.chunk_steps,
                                 nspec=self.nspec if pb.scheme.moving else None, boundary=pb.boundary)
        self._compiled = None

    def _geom(self, p: Particles):
        if self.problem.scheme.moving:
            return None
        h = self.problem.scheme.beta * p.vol ** (1.0 / p.dim)
        self.nspec, self.nl = nb.update_or_grow(p.x, h, self.nspec)
        return static_geometry(p, self.nl, self.problem.scheme, self.problem.domain)

    def run(self, out_dir: str | Path | None = None, snapshots: int = 10, progress: bool = True,
            plots: bool = True) -> Result:
        pb = self.problem
        out = Path(out_dir) if out_dir is not None else None
        writer = io.SnapshotWriter(out, pb.particles.dim) if out is not None else None
        if out is not None and pb.config is not None:
            io.write_config(out, pb.config)
        carry = initial_carry(pb.particles)
        totals0 = conserved_totals(pb.particles)
        if writer:
            writer.write(0.0, snapshot_fields(pb.particles, pb.params, pb.scheme), attrs={"step": 0})
        targets = list(np.linspace(0.0, pb.t_end, snapshots + 1)[1:])
        targets[-1] = pb.t_end
        series = []
        if pb.diagnostics is not None:
            series.append({"t": 0.0, **pb.diagnostics(pb.particles, 0.0, pb.params)})
        steady = None
        vel_prev, t_prev = _velocity(pb.particles), 0.0

        t_wall0 = time.perf_counter()
        geom = self._geom(carry.particles)
        compile_time = 0.0
        bar = _progress(pb.t_end, progress)
        status, failure = "ok", None
        try:
            for target in targets:
                while True:
                    if self._compiled is None:
                        tc = time.perf_counter()
                        self._compiled = self._chunk.lower(carry, pb.params, geom, jnp.asarray(target)).compile()
                        compile_time += time.perf_counter() - tc
                    carry = self._compiled(carry, pb.params, geom, jnp.asarray(target))
                    st = Status(int(carry.status))  # one host sync per chunk
                    t = float(carry.t)
                    bar.update(t, int(carry.step))
                    if st == Status.NEIGHBOR_OVERFLOW:
                        self._regrow(carry.particles)
                        carry = dataclasses.replace(carry, status=jnp.asarray(0, jnp.int32))
                        geom = self._geom(carry.particles)
                        continue
                    if st != Status.OK:
                        failure = self._failure(st, carry)
                        break
                    if int(carry.step) >= self.max_steps and t < pb.t_end:
                        failure = SimulationError(
                            f"maximum number of steps time.max_steps={self.max_steps} reached at "
                            f"t={t:.6g} < t_end={pb.t_end:.6g}", step=int(carry.step), time=t)
                        break
                    if t >= target:
                        break
                if failure is not None:
                    status = "failed: " + str(failure)
                    break
                if writer:
                    writer.write(float(carry.t), snapshot_fields(carry.particles, pb.params, pb.scheme),
                                 attrs={"step": int(carry.step)})
                t = float(carry.t)
                if pb.diagnostics is not None:
                    series.append({"t": t, **pb.diagnostics(carry.particles, t, pb.params)})
                if pb.steady_tol > 0:
                    vel = _velocity(carry.particles)
                    scale = max(float(np.abs(vel).max()), 1e-300)
                    rate = float(np.abs(vel - vel_prev).max()) / scale / max(t - t_prev, 1e-300)
                    vel_prev, t_prev = vel, t
                    if rate < pb.steady_tol:
                        steady = {"converged": True, "t": t, "residual": rate, "tolerance": pb.steady_tol}
                        break
                    steady = {"converged": False, "t": t, "residual": rate, "tolerance": pb.steady_tol}
        finally:
            bar.close()
        wall = time.perf_counter() - t_wall0
        if failure is not None and writer:  # the carry holds the last good state
            writer.write(float(carry.t), snapshot_fields(carry.particles, pb.params, pb.scheme),
                         attrs={"step": int(carry.step)})
        final = carry.particles
        metrics = dict(pb.metrics(final, float(carry.t), pb.params)) if (pb.metrics and failure is None) else {}
        summary = io.make_summary(
            case=pb.case, scheme=dataclasses.asdict(pb.scheme), n_particles=int(final.n),
            n_steps=int(carry.step), t_final=float(carry.t), wall_time_s=wall, compile_time_s=compile_time,
            status=status, metrics=metrics, conservation=_conservation(totals0, conserved_totals(final), final),
            dt_last=float(carry.dt_last),
            particle_updates_per_s=float(int(final.n) * int(carry.step) / max(wall - compile_time, 1e-12)),
        )
        if pb.scheme.limiter == "mood":
            summary["mood"] = mood_summary(carry)
        if series:
            summary["timeseries"] = {k: [row[k] for row in series] for k in series[0]}
            if out is not None:
                io.write_timeseries(out, series)
        if steady is not None:
            summary["steady_state"] = steady
        if writer:
            writer.close()
            io.write_summary(out, summary)
            if plots and pb.plot is not None and failure is None:
                pb.plot(out, final, float(carry.t), pb.params)
        if failure is not None:
            raise failure
        return Result(final, summary, out)

    def _regrow(self, p: Particles):
        """Grow the neighbour capacity after an overflow (the failing step was not committed).

        The last good state may still fit the old capacity, so every regrowth enlarges the row
        capacity, the cell capacity and (for moving particles) the cell size by at least 30 %;
        after ``MAX_REGROWTHS`` attempts the run stops with NeighborOverflowError.
        """
        self._regrowths += 1
        if self._regrowths > MAX_REGROWTHS:
            raise NeighborOverflowError(
                f"neighbour list overflowed {MAX_REGROWTHS} times in one run (capacity={self.nspec.capacity}, "
                f"cell_capacity={self.nspec.cell_capacity}); raise scheme.neighbor_headroom")
        old = self.nspec
        xa = np.asarray(p.x)
        h = self.problem.scheme.beta * np.asarray(p.vol) ** (1.0 / p.dim)
        counts, occ = nb.measure(xa, h, old)
        # how close the last good state is to each limit; grow those within 20 % of it
        use = {"capacity": counts.max() / old.capacity, "cell_capacity": occ / old.cell_capacity,
               "cell_size": old.support * h.max() / old.cell_size}
        grow_all = max(use.values()) < 0.8
        changes = {}
        for key, ratio in use.items():
            if grow_all or ratio >= 0.8:
                cur = getattr(old, key)
                changes[key] = cur * 1.3 if key == "cell_size" else math.ceil(cur * 1.3)
        new = nb.grow(dataclasses.replace(old, cell_size=changes.get("cell_size", old.cell_size)), xa, h,
                      headroom=self.headroom)
        self.nspec = dataclasses.replace(
            new, capacity=max(new.capacity, changes.get("capacity", 0)),
            cell_capacity=max(new.cell_capacity, changes.get("cell_capacity", 0)))
        self._build()

    def _failure(self, st: Status, carry: Carry) -> SimulationError:
        i = int(carry.bad_particle)
        where = ""
        if i >= 0:
            x = np.asarray(carry.particles.x[i])
            where = f", particle {i} at x={np.array2string(x, precision=6)}"
        return SimulationError(
            f"simulation stopped: {st.describe()} in step {int(carry.step) + 1} starting at "
            f"t={float(carry.t):.6g}{where}; the last good state (t={float(carry.t):.6g}) is the "
            "final snapshot", step=int(carry.step) + 1, time=float(carry.t), particle=i if i >= 0 else None)


def _velocity(p: Particles) -> np.ndarray:
    """Fluid velocities (host copy) for the steady-state test."""
    fluid = np.asarray(p.kind) == int(Kind.FLUID)
    q = np.asarray(p.q)
    return q[fluid, 1:1 + p.dim] / q[fluid, :1]


def mood_summary(carry: Carry) -> dict[str, float]:
    """MOOD statistics of a run: largest and mean fraction of fluid particles demoted per step
    (in any of its three stages), mean right-hand-side evaluations per stage (1 = nothing
    flagged) and the number of stages whose flags were not resolved within mood_max_iter."""
    st = dict(zip(MOOD_STATS, np.asarray(carry.mood).tolist(), strict=True))
    steps = max(int(carry.step), 1)
    return {"flagged_fraction_max": st["flagged_fraction_max"],
            "flagged_fraction_mean": st["flagged_fraction_sum"] / steps,
            "rhs_evaluations_per_stage": st["rhs_evaluations"] / (3 * steps),
            "unresolved_stages": int(st["unresolved_stages"])}


def _conservation(tot0: np.ndarray, tot1: np.ndarray, p: Particles) -> dict[str, float]:
    """Relative drift of total mass, momentum (per component) and energy.

    Drift = (final - initial) / scale with scale = |initial total| for mass and energy and
    sum_i |V_i U_i| (initial magnitude of the component) for momentum, which may total zero.
    """
    d = p.dim
    q = np.abs(np.asarray(p.q))
    out = {"mass": float((tot1[0] - tot0[0]) / abs(tot0[0]))}
    for a, name in zip(range(d), "xyz", strict=False):
        scale = max(float(q[:, 1 + a].sum()), float(np.abs(np.asarray(p.q[:, 0])).sum()) * 1e-300, 1e-300)
        out[f"momentum_{name}"] = float((tot1[1 + a] - tot0[1 + a]) / scale)
    if tot0.shape[0] == d + 2:
        out["energy"] = float((tot1[-1] - tot0[-1]) / abs(tot0[-1]))
    return out


class _progress:
    """tqdm bar over simulated time (steps/s shown); a no-op when disabled."""

    def __init__(self, t_end: float, enabled: bool):
        self.bar = None
        self.t_end = t_end
        self.last = 0.0
        if enabled:
            from tqdm.auto import tqdm

            self.bar = tqdm(total=t_end, unit="s(sim)", unit_scale=True, dynamic_ncols=True,
                            bar_format="{l_bar}{bar}| t={n:.4g}/{total:.4g} [{elapsed}<{remaining}{postfix}]")
            self.t0 = time.perf_counter()

    def update(self, t: float, step: int):
        if self.bar is None:
            return
        self.bar.update(t - self.last)
        self.last = t
        el = time.perf_counter() - self.t0
        self.bar.set_postfix(step=step, steps_per_s=f"{step / max(el, 1e-9):.1f}")

    def close(self):
        if self.bar is not None:
            self.bar.close()


def run_problem(problem: Problem, cfg: Mapping | None = None, out_dir=None, quiet: bool = False) -> Result:
    """Run a problem with the ``[time]``/``[output]`` settings of a resolved config."""
    tcfg = (cfg or {}).get("time", {})
    ocfg = (cfg or {}).get("output", {})
    sim = Simulation(problem, cfl=tcfg.get("cfl", 0.3), dt=tcfg.get("dt", 0.0), chunk=tcfg.get("chunk", 50),
                     max_steps=tcfg.get("max_steps", 1_000_000), dt_min=tcfg.get("dt_min", 1e-14),
                     headroom=(cfg or {}).get("scheme", {}).get("neighbor_headroom", 1.3),
                     cfl_viscous=tcfg.get("cfl_viscous", 0.125))
    return sim.run(out_dir, snapshots=ocfg.get("snapshots", 10), progress=ocfg.get("progress", True) and not quiet,
                   plots=ocfg.get("plots", True))


