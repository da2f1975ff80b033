"""Host-side driver: runs a :class:`Problem` chunk by chunk, writes outputs, stops loudly.

The time loop is a sequence of jitted ``lax.scan`` chunks (:mod:`mlsph_jax.integrate`); between
chunks the host reads the carry's status (one synchronisation per chunk), writes snapshots at
the output times, updates the progress bar and handles neighbour-list overflow by growing
the limit its cause names (row capacity, cell capacity or cell size: the bits of the status
word, :class:`~mlsph_jax.status.Status`) and resuming from the last good state (the failing
step was never committed).  Any other failure (NaN, inadmissible state, non-positive density or
volume, time step underflow or a fixed step above the CFL limit, MOOD flags left unresolved)
raises :class:`~mlsph_jax.errors.SimulationError` naming the step, time, particle and cause,
after the last good state has been written as a snapshot and ``summary.json`` records the
failure.  Neighbour sizing, geometry reuse and chunk compilation come from the run layer
(:mod:`mlsph_jax.run`).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Mapping
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from . import io
from .eos import get_eos, to_primitive
from .errors import NeighborOverflowError, SimulationError
from .integrate import MOOD_STATS, Carry, StepControl, initial_carry
from .run import RunSetup, setup_run
from .scheme import Scheme
from .sharding import particle_sharding
from .state import Domain, Kind, Params, Particles, with_precision
from .status import Status
from .status import failure as status_failure


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
                 cfl_viscous: float = 0.125, devices: int = 1, precision: str = "float64"):
        #: precision of the state, parameters and geometry (``run.precision``): the problem is
        #: cast once here, so the chunk traces (and the result holds) that precision
        self.precision = precision
        problem = dataclasses.replace(problem, particles=with_precision(problem.particles, precision),
                                      params=with_precision(problem.params, precision))
        self.problem = problem
        #: particle-axis sharding over ``devices`` devices (``None``: one device; see
        #: :mod:`mlsph_jax.sharding`, the ``run.devices`` setting)
        self.sharding = particle_sharding(devices, problem.particles.n)
        self.control = StepControl(cfl=cfl, cfl_viscous=cfl_viscous, dt_fixed=dt, dt_min=dt_min * problem.t_end)
        self.chunk_steps = int(chunk)
        self.max_steps = int(max_steps)
        self.headroom = headroom
        self._regrowths = 0
        #: one entry per neighbour regrowth: the cause and the limits before and after
        self.regrowth_log: list[dict] = []
        self.setup: RunSetup = setup_run(problem, headroom=headroom, min_moving_headroom=True)
        self._build()

    @property
    def nspec(self):
        return self.setup.nspec

    @property
    def nl(self):
        return self.setup.nl

    def _build(self):
        self._chunk = self.setup.make_chunk(self.control, self.chunk_steps, sharding=self.sharding)
        self._compiled = None

    def _geom(self, p: Particles):
        self.setup, geom = self.setup.host_geometry(self._host(p))
        return self._place(geom)

    def _place(self, tree):
        """``tree`` on the run's devices (sharded over the particle axis on several)."""
        return tree if self.sharding is None else self.sharding.place(tree)

    def _host(self, p):
        """``p`` as ordinary single-device arrays for the host-side work between chunks
        (snapshots, diagnostics, regrowth); every process gathers the whole state."""
        return p if self.sharding is None else self.sharding.gather(p)

    def run(self, out_dir: str | Path | None = None, snapshots: int = 10, progress: bool = True,
            plots: bool = True) -> Result:
        pb = self.problem
        # several processes (jax.distributed): every process runs the same loop, process 0 writes
        out = Path(out_dir) if out_dir is not None and jax.process_index() == 0 else None
        writer = io.SnapshotWriter(out, pb.particles.dim) if out is not None else None
        if out is not None and pb.config is not None:
            io.write_config(out, pb.config)
        carry = self._place(initial_carry(pb.particles))
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
        params = self._place(pb.params)
        compile_time = chunk_time = 0.0
        memory = {}
        bar = _progress(pb.t_end, progress)
        status, failure = "ok", None
        try:
            for target in targets:
                while True:
                    if self._compiled is None:
                        tc = time.perf_counter()
                        tgt = self._place(jnp.asarray(target))
                        self._compiled = self._chunk.lower(carry, params, geom, tgt).compile()
                        compile_time += time.perf_counter() - tc
                        memory = _chunk_memory(self._compiled)
                    tc = time.perf_counter()
                    carry = self._compiled(carry, params, geom, self._place(jnp.asarray(target)))
                    st = Status(int(carry.status))  # one host sync per chunk
                    chunk_time += time.perf_counter() - tc
                    t = float(carry.t)
                    bar.update(t, int(carry.step))
                    if st & Status.NEIGHBOR_OVERFLOW:  # (other bits may be its consequences)
                        try:
                            self._regrow(dataclasses.replace(carry, particles=self._host(carry.particles)), st)
                        except NeighborOverflowError as e:
                            failure = e
                            break
                        carry = dataclasses.replace(carry, status=jnp.asarray(0, jnp.int32),
                                                    bad_particle=jnp.asarray(-1, jnp.int32))
                        geom = self._geom(carry.particles)
                        continue
                    if st != Status.OK:
                        failure = self._failure(st, dataclasses.replace(carry, particles=self._host(carry.particles)))
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
                host = self._host(carry.particles)
                if writer:
                    writer.write(float(carry.t), snapshot_fields(host, pb.params, pb.scheme),
                                 attrs={"step": int(carry.step)})
                t = float(carry.t)
                if pb.diagnostics is not None:
                    series.append({"t": t, **pb.diagnostics(host, t, pb.params)})
                if pb.steady_tol > 0:
                    vel = _velocity(host)
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
        final = self._host(carry.particles)
        if failure is not None and writer:  # the carry holds the last good state
            writer.write(float(carry.t), snapshot_fields(final, pb.params, pb.scheme),
                         attrs={"step": int(carry.step)})
        metrics = dict(pb.metrics(final, float(carry.t), pb.params)) if (pb.metrics and failure is None) else {}
        summary = io.make_summary(
            case=pb.case, scheme=dataclasses.asdict(pb.scheme), n_particles=int(final.n),
            n_steps=int(carry.step), t_final=float(carry.t), wall_time_s=wall, compile_time_s=compile_time,
            status=status, metrics=metrics, conservation=_conservation(totals0, conserved_totals(final), final),
            dt_last=float(carry.dt_last),
            particle_updates_per_s=float(int(final.n) * int(carry.step) / max(wall - compile_time, 1e-12)),
            devices=1 if self.sharding is None else self.sharding.devices, chunk_memory_bytes=memory,
            chunk_time_s=chunk_time, precision=self.precision,
        )
        if pb.scheme.component("limiter").summary_key == "mood":
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

    def _regrow(self, carry: Carry, status: Status):
        """Grow the neighbour limits named by the overflow bits of ``status`` (the failing step
        was not committed; :meth:`mlsph_jax.run.RunSetup.regrow`) and recompile.  After
        ``MAX_REGROWTHS`` regrowths the run stops with NeighborOverflowError (naming every cause
        of the last failing step)."""
        self._regrowths += 1
        old = self.nspec
        if self._regrowths > MAX_REGROWTHS:
            err = self._failure(status, carry)
            raise NeighborOverflowError(
                f"{err}; the neighbour list overflowed {MAX_REGROWTHS} times in one run (capacity={old.capacity}, "
                f"cell_capacity={old.cell_capacity}, cell_size={old.cell_size:.6g}); raise "
                "scheme.neighbor_headroom", step=err.step, time=err.time, particle=err.particle, status=status)
        self.setup = self.setup.regrow(carry.particles, status)
        new = self.nspec
        self.regrowth_log.append({
            "step": int(carry.step) + 1, "t": float(carry.t),
            "causes": [c.name for c in (status & Status.NEIGHBOR_OVERFLOW).causes],
            **{k: (getattr(old, k), getattr(new, k)) for k in ("capacity", "cell_capacity", "cell_size")}})
        self._build()

    def _failure(self, st: Status, carry: Carry) -> SimulationError:
        i = int(carry.bad_particle)
        x = np.asarray(carry.particles.x[i]) if i >= 0 else None
        t = float(carry.t)
        return status_failure(st, step=int(carry.step) + 1, time=t, particle=i, x=x,
                       last_good=f"the last good state (t={t:.6g}) is the final snapshot")


def _chunk_memory(compiled) -> dict[str, int]:
    """XLA's memory analysis of a compiled chunk (bytes per device: arguments, outputs,
    temporaries), or ``{}`` where the backend gives none."""
    try:
        m = compiled.memory_analysis()
        return {k: int(getattr(m, f"{k}_size_in_bytes")) for k in ("argument", "output", "temp")}
    except Exception:  # noqa: BLE001 - an optional statistic, not a result
        return {}


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
                     cfl_viscous=tcfg.get("cfl_viscous", 0.125), devices=(cfg or {}).get("run", {}).get("devices", 1),
                     precision=(cfg or {}).get("run", {}).get("precision", "float64"))
    return sim.run(out_dir, snapshots=ocfg.get("snapshots", 10), progress=ocfg.get("progress", True) and not quiet,
                   plots=ocfg.get("plots", True))


