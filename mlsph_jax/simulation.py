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
import json
import math
import re
import signal
import threading
import time
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from . import compilation_cache, fallback, io
from . import neighbors as nb
from .checkpoint import (
    RESTART_MAY_CHANGE,
    Checkpoint,
    compare_settings,
    prepare_out_dir,
    read_checkpoint,
    restart_added_keys,
    write_checkpoint,
)
from .config.tables import (
    LOCAL_TIME_STEPPING_ALLOWED,
    local_time_stepping_conflict,
    series_allowed,
    series_per_output,
)
from .eos import get_eos, to_primitive
from .errors import DegreeFallbackWarning, InputError, NeighborOverflowError, RunInterrupted, SimulationError
from .integrate import MOOD_STATS, Carry, StepControl, initial_carry
from .run import RunSetup, setup_run
from .scheme import Scheme
from .sharding import check_devices, particle_sharding
from .spatial import DECOMPOSITIONS, check_spatial, list_key, spatial_sharding
from .state import Domain, Kind, Params, Particles, with_precision
from .status import Status
from .status import failure as status_failure


@dataclasses.dataclass
class Problem:
    """A ready-to-run simulation: initial particles, parameters, scheme, domain and end time,
    plus the case's metrics (``metrics(particles, t, params) -> dict``) and plotting hook
    (``plot(out_dir, particles, t, params)``), an optional ``boundary`` (ghost regeneration,
    :class:`mlsph_jax.boundaries.MirrorWalls`), ``diagnostics(particles, t, params) -> dict``
    recorded at every output time or at the finer sample times of ``output.series_interval``
    (:meth:`Simulation.run`; the ``timeseries`` of the summary and ``timeseries.csv``) and
    ``steady_tol``: when > 0 the run stops early once the velocity changes by less than
    ``steady_tol`` (relative to its maximum, per unit of time) between two output times.
    ``differentiable_diagnostics`` / ``differentiable_metrics``: jnp versions recorded by
    :func:`mlsph_jax.differentiable.make_simulate` (time series) and offered as objectives by
    :mod:`mlsph_jax.sensitivity`.  ``particles_at(params) -> Particles``: the initial particles
    as a jnp function of the parameters, for a layout that follows them (the cylinder's
    body-fitted layout of an elliptic body, decision 65); ``None``: ``particles`` for any
    parameters.  ``series_statistics(series) -> dict``: statistics of the recorded time series
    (``series`` maps each diagnostic and ``t`` to its array over the sample times), computed once
    at the end of a run; written to ``summary.json`` under ``series_statistics``, the finite numbers
    of its ``metrics`` entry also among the run's metrics (the cylinder's Strouhal number and
    whole-period means, :mod:`mlsph_jax.periodic`; none when the run is too short for them)."""

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
    particles_at: Callable[[Params], Particles] | None = None
    series_statistics: Callable[[Mapping[str, np.ndarray]], dict] | None = None


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
    """Runs a :class:`Problem` with SSP-RK3 in jitted chunks (one compilation per case).

    ``devices``/``decomposition`` (``run.devices``, ``run.decomposition``): several devices as
    index ranges (:mod:`mlsph_jax.sharding`, ``"index"``, the default) or, for Eulerian runs, as
    Morton-ordered regions with a halo exchanged inside ``jax.shard_map`` (:mod:`mlsph_jax.spatial`,
    ``"spatial"``); either way the results are in the original particle order."""

    def __init__(self, problem: Problem, *, cfl: float = 0.3, dt: float = 0.0, chunk: int = 50,
                 max_steps: int = 1_000_000, dt_min: float = 1e-14, headroom: float = 1.3,
                 cfl_viscous: float = 0.125, devices: int = 1, precision: str = "float64",
                 local_time_stepping: bool = False, local_step_ratio: float = 4.0,
                 moving_headroom: float = 0.0, decomposition: str = "index"):
        #: precision of the state, parameters and geometry (``run.precision``): the problem is
        #: cast once here, so the chunk traces (and the result holds) that precision
        self.precision = precision
        problem = dataclasses.replace(problem, particles=with_precision(problem.particles, precision),
                                      params=with_precision(problem.params, precision))
        self.problem = problem
        if decomposition not in DECOMPOSITIONS:
            raise InputError(f"invalid run.decomposition={decomposition!r}; allowed: "
                             + ", ".join(map(repr, DECOMPOSITIONS)))
        #: ``run.decomposition``: "index" (index ranges, the partitioner communicates) or "spatial"
        #: (:mod:`mlsph_jax.spatial`: Morton-ordered shards with halos, Eulerian runs)
        self.decomposition = decomposition
        self.spatial = decomposition == "spatial"
        if self.spatial:
            check_spatial(problem.scheme, problem.boundary, local_time_stepping=local_time_stepping)
            self._devices = devices
            check_devices(devices)
        #: particle-axis sharding over ``devices`` devices (``None``: one device; see
        #: :mod:`mlsph_jax.sharding`, the ``run.devices`` setting); the spatial decomposition's
        #: (:class:`mlsph_jax.spatial.SpatialSharding`) is made with the neighbour list below
        self.sharding = None if self.spatial else particle_sharding(devices, problem.particles.n)
        why = local_time_stepping_conflict(dt, problem.scheme.frame)
        if local_time_stepping and why:
            raise InputError(f"invalid time.local_time_stepping=true: {why}; allowed: {LOCAL_TIME_STEPPING_ALLOWED}")
        if local_time_stepping and problem.scheme.conservation_projection:
            raise InputError("invalid time.local_time_stepping=true with scheme.conservation_projection=true: each "
                             "particle advances with its own step, so a global balance of the rates is not one of "
                             "the totals; allowed: time.local_time_stepping=false, or "
                             "scheme.conservation_projection=false")
        if isinstance(local_step_ratio, bool) or not (isinstance(local_step_ratio, int | float)
                                                       and math.isfinite(local_step_ratio) and local_step_ratio >= 1):
            raise InputError(f"invalid time.local_step_ratio={local_step_ratio!r}; allowed: a finite number >= 1")
        self.control = StepControl(cfl=cfl, cfl_viscous=cfl_viscous, dt_fixed=dt, dt_min=dt_min * problem.t_end,
                                   local=bool(local_time_stepping), local_ratio=float(local_step_ratio))
        self.chunk_steps = int(chunk)
        self.max_steps = int(max_steps)
        self.headroom = headroom
        if moving_headroom != 0 and not moving_headroom >= 1.0:
            raise InputError(f"invalid scheme.moving_neighbor_headroom={moving_headroom!r}; allowed: 0 (automatic: "
                             "2.0 in 1D, 1.3 in 2D/3D, decision 84) or a number >= 1.0")
        #: the driver's lower bound on the neighbour headroom of moving particles (True: automatic,
        #: :func:`mlsph_jax.run.moving_min_headroom`; ``scheme.moving_neighbor_headroom``)
        self.moving_headroom = float(moving_headroom) if moving_headroom else True
        self._regrowths = 0
        #: one entry per neighbour regrowth: the cause and the limits before and after
        self.regrowth_log: list[dict] = []
        self.setup: RunSetup = setup_run(problem, headroom=headroom, min_moving_headroom=self.moving_headroom)
        if self.spatial:
            self.sharding = spatial_sharding(devices, np.asarray(problem.particles.x), self.setup.nl, problem.boundary)
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
        if not self.spatial or self.sharding is None:
            return self._place(geom)
        if list_key(self.setup.nl) != self.sharding.idx_key:    # a regrown list: a new layout
            self.sharding = spatial_sharding(self._devices, np.asarray(p.x), self.setup.nl, self.problem.boundary)
            self._build()
        return self.sharding.place_geometry(geom, self.problem.boundary)

    def _relayout(self, carry: Carry) -> Carry:
        """The spatial decomposition's carry in its local layout (original order in, see
        :meth:`mlsph_jax.spatial.SpatialSharding.place`); unchanged otherwise."""
        return self.sharding.place(carry) if self.spatial and self.sharding is not None else carry

    def _place(self, tree):
        """``tree`` on the run's devices (sharded over the particle axis on several)."""
        return tree if self.sharding is None else self.sharding.place(tree)

    def _host(self, p):
        """``p`` as ordinary single-device arrays for the host-side work between chunks
        (snapshots, diagnostics, regrowth); every process gathers the whole state."""
        return p if self.sharding is None else self.sharding.gather(p)

    def _settings(self, snapshots: int, per_output: int = 1) -> dict:
        """Driver settings a restart must share with the run it continues (the numbers of the
        steps depend on them; :data:`~mlsph_jax.checkpoint.RESTART_MAY_CHANGE` may change)."""
        c = self.control
        return {"case": self.problem.case, "t_end": float(self.problem.t_end), "snapshots": int(snapshots),
                **({"series_per_output": int(per_output)} if per_output > 1 else {}),
                # (absent when the series is sampled at the output times: older checkpoints restart)
                "chunk": self.chunk_steps, "cfl": c.cfl, "cfl_viscous": c.cfl_viscous, "dt": c.dt_fixed,
                "dt_min": c.dt_min, "neighbor_headroom": float(self.headroom),
                **({"local_time_stepping": True, "local_step_ratio": c.local_ratio} if c.local else {}),
                # (absent without local steps: checkpoints from before the setting restart)
                "n_particles": int(self.problem.particles.n),
                "scheme": dataclasses.asdict(self.problem.scheme)}

    def run(self, out_dir: str | Path | None = None, snapshots: int = 10, progress: bool = True,
            plots: bool = True, *, overwrite: bool = False, restart: bool = False,
            degree_fallback_warn: float = fallback.DEFAULT_WARN, series_interval: float = 0.0) -> Result:
        """Run to ``t_end`` writing ``snapshots`` output times (plus the initial state) to ``out_dir``.

        The problem's ``diagnostics`` (the time series: ``timeseries.csv``, summary.json
        ``timeseries`` and ``series_statistics``) are recorded at t = 0 and at every output time, or,
        with ``series_interval`` > 0 (``output.series_interval``; a whole fraction t_end /
        (snapshots m) of the output interval), at the m-times finer uniform times k t_end /
        (snapshots m), which include the output times; a sample time that is not an output time
        records the diagnostics and writes nothing else (no snapshot, checkpoint or steady-state
        test).  Every sample time is a target of the step control like an output time, so the steps
        are bit for bit those of the run with ``snapshots m`` outputs (the same targets), without
        their snapshots; the steady-state stop tests only the outputs, so with ``steady_tol`` > 0
        the two can stop at different times.

        ``out_dir`` must not hold a run (``summary.json``, ``fields.h5`` or ``checkpoint.h5``) unless
        ``overwrite`` (its old outputs are removed first) or ``restart``: continue the run of
        ``out_dir`` from its ``checkpoint.h5`` (the last output time, interruption or failure),
        bit for bit as if it had not stopped; the problem and driver settings must be those of
        that run (:class:`InputError` naming what differs; the settings of
        :data:`~mlsph_jax.checkpoint.RESTART_MAY_CHANGE` may change, a steady-state tolerance only
        to a smaller one, which also continues a run its steady-state test stopped).  Snapshots
        are appended to its ``fields.h5`` and ``config.toml`` holds the settings it goes on with.

        SIGINT (Ctrl-C) or SIGTERM finish the current chunk, write the last good state (snapshot
        and checkpoint), ``summary.json`` with ``status = "interrupted"``, ``timeseries.csv`` and the
        plots, then raise :class:`~mlsph_jax.errors.RunInterrupted`; a second Ctrl-C stops at once.

        Reduced approximation degree (:mod:`mlsph_jax.fallback`): each snapshot holds the
        per-particle ``area_degree``/``fit_degree``, ``summary.json`` the ``degree_fallback``
        fractions, and a :class:`~mlsph_jax.errors.DegreeFallbackWarning` is issued (at the output
        time it is first seen) when a fraction of fluid particles exceeds ``degree_fallback_warn``
        (``output.degree_fallback_warn``).
        """
        pb = self.problem
        thr = degree_fallback_warn
        if isinstance(thr, bool) or not isinstance(thr, int | float) or not 0.0 <= thr <= 1.0:
            raise InputError(f"invalid degree_fallback_warn={thr!r} ({fallback.WARN_KEY}); allowed: a fraction in "
                             "[0, 1] (1 = never warn)")
        # several processes (jax.distributed): every process runs the same loop, process 0 writes
        out = Path(out_dir) if out_dir is not None and jax.process_index() == 0 else None
        if restart and overwrite:
            raise InputError("invalid overwrite=True with restart=True (--overwrite with --restart): overwriting "
                             "deletes the run a restart continues; allowed: one of them")
        if restart and jax.process_count() > 1:
            raise InputError(f"invalid restart=True (--restart) with {jax.process_count()} processes: the checkpoint "
                             "is written and read by process 0 only; allowed: a restart in one process")
        if restart and out is None:
            raise InputError("invalid restart=True without out_dir; allowed: the output folder of the run to "
                             "continue")
        per_output, why = series_per_output(pb.t_end, snapshots, series_interval)
        if why:
            raise InputError(f"invalid series_interval={series_interval!r} (output.series_interval): {why}; "
                             f"allowed: {series_allowed(pb.t_end, snapshots, series_interval)}")
        # the step targets: the sample times of the series, every per_output-th an output time (with
        # per_output = 1 the output times themselves, as a run without a finer series)
        targets = list(np.linspace(0.0, pb.t_end, snapshots * per_output + 1)[1:])
        targets[-1] = pb.t_end
        totals0 = conserved_totals(pb.particles)
        settings = self._settings(snapshots, per_output)
        config = None if pb.config is None else json.loads(json.dumps(pb.config, default=str))
        steady = None
        wall_before = compile_before = 0.0

        def residual_column(rate: float) -> dict:
            """The steady-state residual as a column of the time series (``velocity_change_rate``:
            0 at t = 0, nan between outputs) when the run has a steady-state test; its history is
            in the checkpoint (vel_prev, t_prev), so a restarted series is the uninterrupted one."""
            return {"velocity_change_rate": rate} if pb.steady_tol > 0 else {}
        restarted_from = None
        if restart:
            ck = self._resume_checkpoint(out, settings, config)
            writer = io.SnapshotWriter(out, pb.particles.dim, keep=ck.n_snapshots)
            last = writer.snapshot_attrs(ck.n_snapshots - 1)
            if float(last.get("t", np.nan)) != float(ck.t) or int(last.get("step", -1)) != int(ck.step):
                raise InputError(f"invalid restart folder {str(out)!r}: the last snapshot of fields.h5 (t = "
                                 f"{last.get('t')}, step {last.get('step')}) is not the checkpoint's (t = "
                                 f"{float(ck.t)}, step {int(ck.step)}); allowed: the folder as the run left it")
            carry = Carry(ck.particles, jnp.asarray(ck.t), jnp.asarray(ck.step), jnp.asarray(Status.OK, jnp.int32),
                          jnp.asarray(-1, jnp.int32), jnp.asarray(ck.dt_last), jnp.asarray(ck.mood),
                          fallback.initial_degrees(ck.particles.n) if ck.degree is None else jnp.asarray(ck.degree),
                          fallback.initial_stats() if ck.fallback is None else jnp.asarray(ck.fallback))
            series, vel_prev, t_prev, first = list(ck.series), np.asarray(ck.vel_prev), ck.t_prev, ck.next_target
            steady = ck.steady
            if ck.status == "ok":     # a steady-stopped run going on to a smaller tolerance
                steady = {**ck.steady, "converged": False, "tolerance": pb.steady_tol}
            if out is not None and pb.config is not None:
                io.write_config(out, pb.config)     # the settings it goes on with (e.g. case.steady_tol)
            wall_before, compile_before = ck.wall_time_s, ck.compile_time_s
            restarted_from = {"t": float(ck.t), "step": int(ck.step), "status": ck.status}
            geom_src = ck.geom_source
        else:
            if out is not None:
                prepare_out_dir(out, overwrite=overwrite)
            writer = io.SnapshotWriter(out, pb.particles.dim) if out is not None else None
            if out is not None and pb.config is not None:
                io.write_config(out, pb.config)
            p0 = pb.particles
            if self.spatial and getattr(pb.boundary, "apply", None) is not None:
                # ghosts regenerated once before the state is split: a halo copy of a ghost is
                # only ever refreshed in q, so its x and vol must already be its owner's
                p0 = pb.boundary.apply(p0, pb.params)
            carry = initial_carry(p0)
            series = []
            if pb.diagnostics is not None:
                series.append({"t": 0.0, **pb.diagnostics(pb.particles, 0.0, pb.params), **residual_column(0.0)})
            vel_prev, t_prev, first = _velocity(pb.particles), 0.0, 0
            geom_src = None if pb.scheme.moving else (np.asarray(pb.particles.x), np.asarray(pb.particles.vol))

        t_wall0 = time.perf_counter()
        if geom_src is not None:
            geom = self._geom(carry.particles.replace(x=jnp.asarray(geom_src[0]), vol=jnp.asarray(geom_src[1])))
        else:
            geom = self._geom(carry.particles)
        carry = self._relayout(carry)
        # several processes with an output folder (the same out_dir on every process): a gather is a
        # collective, so every process takes part in the ones whose result process 0 writes (the
        # snapshots, the checkpoints); the others skip the writing
        multi = jax.process_count() > 1 and out_dir is not None
        if (writer or multi) and not restart:   # degrees at t = 0: the Eulerian geometry's (moving: -1, no step yet)
            deg0 = carry.degree if geom is None else self._host(geom.degree)
            if writer:
                writer.write(0.0, {**snapshot_fields(pb.particles, pb.params, pb.scheme),
                                   **fallback.snapshot_fields(deg0, pb.scheme)}, attrs={"step": 0})
        last_snapshot = [int(carry.step)]     # the step of the last snapshot (t = 0, or the checkpoint's)
        params = pb.params if self.sharding is None else self.sharding.replicate(pb.params)
        compile_time = chunk_time = 0.0
        memory = {}
        step_stop = self._place(jnp.asarray(self.max_steps, jnp.int32))

        def checkpoint(next_target: int, status: str):
            if out is None and not multi:
                return
            host_p, host_deg = self._host(carry.particles), self._host(carry.degree)   # every process
            if out is None:
                return
            write_checkpoint(out, Checkpoint(
                particles=host_p, t=np.asarray(carry.t), step=np.asarray(carry.step),
                dt_last=np.asarray(carry.dt_last), mood=np.asarray(carry.mood), next_target=next_target,
                n_snapshots=writer.count, nspec=dataclasses.asdict(self.nspec), geom_source=geom_src,
                regrowths=self._regrowths, regrowth_log=self.regrowth_log, series=series, vel_prev=vel_prev,
                t_prev=t_prev, steady=steady, settings=settings, config=config, case=pb.case, status=status,
                wall_time_s=wall_before + time.perf_counter() - t_wall0,
                compile_time_s=compile_before + compile_time, degree=np.asarray(host_deg),
                fallback=np.asarray(carry.fallback)))

        def snapshot():
            step = int(carry.step)
            if step == last_snapshot[0] or not (writer or multi):
                return
            host_p, host_deg = self._host(carry.particles), self._host(carry.degree)   # every process
            if writer:
                writer.write(float(carry.t), {**snapshot_fields(host_p, pb.params, pb.scheme),
                                              **fallback.snapshot_fields(host_deg, pb.scheme)}, attrs={"step": step})
            last_snapshot[0] = step

        warned = set()

        def warn_fallback():   # once per statistic, at the output time it first exceeds the threshold
            for key, msg in fallback.exceeded(np.asarray(carry.fallback), pb.scheme, thr):
                if key not in warned:
                    warned.add(key)
                    warnings.warn(DegreeFallbackWarning(f"{msg} (by t = {float(carry.t):.6g})"), stacklevel=3)

        bar = _progress(pb.t_end, progress, t0=float(carry.t))
        status, failure, interrupted = "ok", None, None
        index = first
        try:
            with _Interrupts() as signals:
                for index in range(first, len(targets)):
                    target = targets[index]
                    while True:
                        if signals.signum is not None:
                            interrupted = signals.signum
                            break
                        if self._compiled is None:
                            tc = time.perf_counter()
                            self._compiled = self._chunk.lower(carry, params, geom, self._place(jnp.asarray(target)),
                                                               step_stop).compile()
                            compile_time += time.perf_counter() - tc
                            memory = _chunk_memory(self._compiled)
                        tc = time.perf_counter()
                        carry = self._compiled(carry, params, geom, self._place(jnp.asarray(target)), step_stop)
                        st = Status(int(carry.status))  # one host sync per chunk
                        chunk_time += time.perf_counter() - tc
                        t = float(carry.t)
                        bar.update(t, int(carry.step))
                        if st & Status.NEIGHBOR_OVERFLOW:  # (other bits may be its consequences)
                            if self.spatial:
                                carry = self._host(carry)
                            try:
                                self._regrow(dataclasses.replace(carry, particles=self._host(carry.particles)), st)
                            except NeighborOverflowError as e:
                                failure = e
                                break
                            carry = dataclasses.replace(carry, status=jnp.asarray(0, jnp.int32),
                                                        bad_particle=jnp.asarray(-1, jnp.int32))
                            if not pb.scheme.moving:
                                geom_src = (np.asarray(carry.particles.x), np.asarray(carry.particles.vol))
                            geom = self._geom(carry.particles)
                            carry = self._relayout(carry)
                            continue
                        if st != Status.OK:
                            host_carry = dataclasses.replace(carry, particles=self._host(carry.particles))
                            failure = self._failure(st, host_carry)
                            break
                        if int(carry.step) >= self.max_steps and t < target:
                            failure = SimulationError(
                                f"maximum number of steps time.max_steps={self.max_steps} reached at "
                                f"t={t:.6g} < t_end={pb.t_end:.6g}", step=int(carry.step), time=t)
                            break
                        if t >= target:
                            break
                    if failure is not None:
                        status = "failed: " + str(failure)
                        break
                    if interrupted is not None:
                        status = "interrupted"
                        break
                    t = float(carry.t)
                    host = self._host(carry.particles)
                    at_output = not (index + 1) % per_output
                    done, rate = False, float("nan")
                    if at_output and pb.steady_tol > 0:
                        vel = _velocity(host)
                        scale = max(float(np.abs(vel).max()), 1e-300)
                        rate = float(np.abs(vel - vel_prev).max()) / scale / max(t - t_prev, 1e-300)
                        vel_prev, t_prev = vel, t
                        done = rate < pb.steady_tol
                        steady = {"converged": done, "t": t, "residual": rate, "tolerance": pb.steady_tol}
                    if pb.diagnostics is not None:
                        series.append({"t": t, **pb.diagnostics(host, t, pb.params), **residual_column(rate)})
                    if not at_output:   # a sample time between two outputs: the series only
                        continue
                    snapshot()
                    warn_fallback()
                    checkpoint(index + 1, "ok" if done or index + 1 == len(targets) else "running")
                    if done:
                        break
        finally:
            bar.close()
        wall = time.perf_counter() - t_wall0
        if failure is not None or interrupted is not None:   # the carry holds the last good state
            snapshot()
            checkpoint(index, status)
            warn_fallback()
        final = self._host(carry.particles)
        metrics = dict(pb.metrics(final, float(carry.t), pb.params)) if (pb.metrics and failure is None) else {}
        wall_total, compile_total = wall_before + wall, compile_before + compile_time
        conservation, conservation_info = _conservation(totals0, conserved_totals(final), pb.particles, final,
                                                        walls=getattr(pb.boundary, "wall_terms", None) is not None)
        if pb.params is not None and "physics.body_force" in pb.params and \
                np.any(np.asarray(pb.params["physics.body_force"]) != 0):
            conservation_info["label"] = "change (boundary fluxes, body force)"
        summary = io.make_summary(
            case=pb.case, scheme=dataclasses.asdict(pb.scheme), n_particles=int(final.n),
            n_steps=int(carry.step), t_final=float(carry.t), wall_time_s=wall_total, compile_time_s=compile_total,
            status=status, metrics=metrics, conservation=conservation,
            dt_last=float(carry.dt_last),
            particle_updates_per_s=float(int(final.n) * int(carry.step) / max(wall_total - compile_total, 1e-12)),
            conservation_info=conservation_info,
            devices=1 if self.sharding is None else self.sharding.devices, chunk_memory_bytes=memory,
            chunk_time_s=chunk_time, precision=self.precision,
        )
        if restarted_from is not None:
            summary["restarted_from"] = restarted_from
        cache = compilation_cache.active()
        if cache:   # compile_time_s may be a load from JAX's persistent cache (mlsph_jax.compilation_cache)
            summary["compilation_cache"] = cache
        if self.spatial and self.sharding is not None:
            summary["decomposition"] = self.sharding.info()
        if pb.scheme.component("limiter").summary_key == "mood":
            summary["mood"] = mood_summary(carry)
        if any(d is not None for d in fallback.nominal_degrees(pb.scheme)):
            summary["degree_fallback"] = fallback.summary(carry.fallback, pb.scheme, thr)
        if series:
            summary["timeseries"] = {k: [row[k] for row in series] for k in series[0]}
            if pb.series_statistics is not None and failure is not None:
                summary["series_statistics"] = {"note": f"the run failed at t = {float(carry.t):g}: no statistics"}
            elif pb.series_statistics is not None:
                try:   # a statistics error must not cost the run its summary and time series
                    stats = pb.series_statistics({k: np.asarray(v, float) for k, v in summary["timeseries"].items()})
                except Exception as e:  # noqa: BLE001
                    stats = {"note": f"the statistics failed: {type(e).__name__}: {e}"}
                summary["series_statistics"] = stats
                summary["metrics"].update({k: float(v) for k, v in stats.get("metrics", {}).items()
                                           if math.isfinite(v)})
            if out is not None:
                io.write_timeseries(out, series)
        if steady is not None:
            summary["steady_state"] = steady
        if writer:
            writer.close()
            io.write_summary(out, summary)
            if plots and pb.plot is not None and failure is None:
                pb.plot(out, final, float(carry.t), pb.params)
        result = Result(final, summary, out)
        if failure is not None:
            raise failure
        if interrupted is not None:
            name = signal.Signals(interrupted).name
            raise RunInterrupted(
                f"interrupted by {name} at t = {float(carry.t):.6g} (step {int(carry.step)})"
                + (f"; outputs in {out}/, continue with: mlsph run --restart {out}" if out else ""),
                result=result, signal=interrupted)
        return result

    def _resume_checkpoint(self, out: Path, settings: dict, config: dict | None) -> Checkpoint:
        """The checkpoint of ``out``, refused (:class:`InputError` naming every difference) if it
        belongs to another case or was run with other settings, or is complete."""
        ck = read_checkpoint(out)
        where = f"invalid restart folder {str(out)!r}"
        if ck.case != self.problem.case:
            raise InputError(f"{where}: it holds a run of case {ck.case!r}, not {self.problem.case!r}; allowed: the "
                             f"folder of a {self.problem.case!r} run (or restart {ck.case!r} from its own config)")
        diffs = compare_settings(ck.settings, settings, where="")
        if config is not None and ck.config is not None:
            diffs += compare_settings(ck.config, config, where="", may_change=RESTART_MAY_CHANGE,
                                      added=restart_added_keys(self.problem.case))
        if diffs:
            raise InputError(f"{where}: the run was made with other settings: " + "; ".join(diffs)
                             + f"; allowed: the run's own settings (only {', '.join(RESTART_MAY_CHANGE)} may change)")
        saved = (ck.config or {}).get("case", {}).get("steady_tol")
        now = self.problem.steady_tol
        if saved is not None and float(saved) != now and not 0.0 < now < float(saved):
            raise InputError(f"{where}: case.steady_tol={now:g}, the run's {float(saved):g}; allowed: a smaller "
                             "positive tolerance (the run would have stopped at the same outputs or gone on; a "
                             "larger one, or 0, could have stopped it earlier or drops its residual series), or "
                             "the run's own")
        if ck.status == "ok" and not self._tighter_steady_stop(ck):
            more = ""
            if ck.steady and ck.steady.get("converged") and float(ck.t) < self.problem.t_end:
                more = (f", or this steady-stopped run with a smaller steady-state tolerance (case.steady_tol < "
                        f"{ck.steady['residual']:.6g}, its residual at the stop; now {self.problem.steady_tol:g})")
            raise InputError(f"{where}: the run is complete (t = {float(ck.t):.6g}, step {int(ck.step)}); allowed: "
                             f"an interrupted or failed run{more}")
        if int(ck.particles.n) != int(self.problem.particles.n):
            raise InputError(f"{where}: {int(ck.particles.n)} particles in the run, {self.problem.particles.n} now")
        spec = _spec(ck.nspec)
        rebuild = spec != self.nspec
        self.setup = setup_run(self.problem, headroom=self.headroom, min_moving_headroom=self.moving_headroom,
                               particles=ck.particles, nspec=spec)
        self._regrowths, self.regrowth_log = ck.regrowths, list(ck.regrowth_log)
        if rebuild:   # the run had regrown its neighbour limits: compile for those
            self._build()
        return ck

    def _tighter_steady_stop(self, ck: Checkpoint) -> bool:
        """Whether a run that stopped on its steady-state test (before t_end) continues: the
        tolerance is now below the residual it stopped at, so an uninterrupted run with this
        tolerance would have gone on from the same state (the steps do not depend on the
        tolerance, so the continuation is bit for bit that run)."""
        st = ck.steady or {}
        return (bool(st.get("converged")) and float(ck.t) < self.problem.t_end
                and 0.0 < self.problem.steady_tol < float(st.get("residual", 0.0)))

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


_ERROR_METRIC = re.compile(r"^(l1|l2|linf)_|error|_dev$")


def split_metrics(metrics: Mapping[str, float]) -> tuple[dict, dict]:
    """``(errors, other results)`` of a case's metrics: errors against the reference are the
    norms ``l1_*``, ``l2_*``, ``linf_*``, the ``*error*`` and the ``*_dev`` (deviation from
    tabulated data) entries; the others (``ke``, ``ke_exact``, ``n_fluid``, ``rho_max``,
    overshoots, ...) are results, not errors."""
    errors = {k: v for k, v in metrics.items() if _ERROR_METRIC.search(k)}
    return errors, {k: v for k, v in metrics.items() if k not in errors}


def _spec(d: dict) -> nb.NeighborSpec:
    """A :class:`~mlsph_jax.neighbors.NeighborSpec` from its JSON form (lists back to tuples)."""
    return nb.NeighborSpec(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})


class _Interrupts:
    """Context manager: SIGINT and SIGTERM set ``signum`` (the driver stops after the chunk it is
    in) instead of raising; a second SIGINT raises ``KeyboardInterrupt`` at once.  Handlers are
    installed only in the main thread (Python allows no other) and restored on exit."""

    def __init__(self):
        self.signum = None
        self._old = {}

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for s in (signal.SIGINT, signal.SIGTERM):
                self._old[s] = signal.signal(s, self._handle)
        return self

    def _handle(self, signum, frame):
        if self.signum is not None and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.signum = signum

    def __exit__(self, *exc):
        for s, h in self._old.items():
            signal.signal(s, h)


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


def _conservation(tot0: np.ndarray, tot1: np.ndarray, p0: Particles, p1: Particles,
                  walls: bool = False) -> tuple[dict, dict]:
    """Relative change of total mass, momentum (per component) and energy, and how it reads.

    ``(final - initial) / scale`` with scale = |initial total| for mass and energy; for a
    momentum component the initial total when it is not ~0 (above 1e-8 of the flow's momentum
    scale), else the flow's momentum scale M U (M the total mass, U the largest fluid speed at the
    start or the end, 1 m/s if the fluid never moved), so that a total that is zero by symmetry
    is never round-off divided by round-off.  The second dict (``summary["conservation_info"]``)
    holds the scales and the label: ``"drift"`` in a closed (periodic) domain, where any change
    is an error of the scheme, ``"change (boundary fluxes)"`` when walls, ghosts, frozen ends or
    boundary particles exchange mass, momentum or energy with the fluid, or a body force acts
    (``walls``: boundary-integral walls, which need no particles, do too).
    """
    d = p1.dim
    mass0 = abs(float(tot0[0]))
    speed = max(float(np.abs(_velocity(p0)).max(initial=0.0)), float(np.abs(_velocity(p1)).max(initial=0.0)))
    flow = mass0 * (speed if speed > 0 else 1.0)
    scales = {"mass": mass0}
    for a, name in zip(range(d), "xyz", strict=False):
        total = abs(float(tot0[1 + a]))
        scales[f"momentum_{name}"] = total if total > 1e-8 * flow else flow
    if tot0.shape[0] == d + 2:
        scales["energy"] = abs(float(tot0[-1]))
    idx = {"mass": 0, **{f"momentum_{n}": 1 + a for a, n in zip(range(d), "xyz", strict=False)}, "energy": d + 1}
    out = {k: float((tot1[idx[k]] - tot0[idx[k]]) / max(sc, 1e-300)) for k, sc in scales.items()}
    open_ = walls or bool(np.any(np.asarray(p0.kind) != int(Kind.FLUID)))
    return out, {"label": "change (boundary fluxes)" if open_ else "drift", "scales": scales}


class _progress:
    """tqdm bar over simulated time (steps/s shown); a no-op when disabled."""

    def __init__(self, t_end: float, enabled: bool, t0: float = 0.0):
        self.bar = None
        self.t_end = t_end
        self.last = t0
        if enabled:
            from tqdm.auto import tqdm

            self.bar = tqdm(total=t_end, initial=t0, unit="s(sim)", unit_scale=True, dynamic_ncols=True,
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


def run_problem(problem: Problem, cfg: Mapping | None = None, out_dir=None, quiet: bool = False, *,
                overwrite: bool = False, restart: bool = False) -> Result:
    """Run a problem with the ``[time]``/``[output]`` settings of a resolved config
    (``overwrite``/``restart``: see :meth:`Simulation.run`)."""
    ocfg = (cfg or {}).get("output", {})
    sim = make_simulation(problem, cfg)
    return sim.run(out_dir, snapshots=ocfg.get("snapshots", 10), progress=ocfg.get("progress", True) and not quiet,
                   plots=ocfg.get("plots", True), overwrite=overwrite, restart=restart,
                   degree_fallback_warn=ocfg.get("degree_fallback_warn", fallback.DEFAULT_WARN),
                   series_interval=ocfg.get("series_interval", 0.0))


def make_simulation(problem: Problem, cfg: Mapping | None = None) -> Simulation:
    """The :class:`Simulation` of ``problem`` with the ``[time]``/``[scheme]``/``[run]`` driver
    settings of a resolved config (what :func:`run_problem` runs; also used by the benchmarks)."""
    tcfg = (cfg or {}).get("time", {})
    return Simulation(problem, cfl=tcfg.get("cfl", 0.3), dt=tcfg.get("dt", 0.0), chunk=tcfg.get("chunk", 50),
                      max_steps=tcfg.get("max_steps", 1_000_000), dt_min=tcfg.get("dt_min", 1e-14),
                      headroom=(cfg or {}).get("scheme", {}).get("neighbor_headroom", 1.3),
                      cfl_viscous=tcfg.get("cfl_viscous", 0.125), devices=(cfg or {}).get("run", {}).get("devices", 1),
                      precision=(cfg or {}).get("run", {}).get("precision", "float64"),
                      local_time_stepping=tcfg.get("local_time_stepping", False),
                      local_step_ratio=tcfg.get("local_step_ratio", 4.0),
                      moving_headroom=(cfg or {}).get("scheme", {}).get("moving_neighbor_headroom", 0.0),
                      decomposition=(cfg or {}).get("run", {}).get("decomposition", "index"))


def restart(out_dir, overrides=(), quiet: bool = False) -> Result:
    """Continue the run of ``out_dir`` (interrupted, failed, or stopped by its steady-state test and
    given a smaller ``case.steady_tol``) from its checkpoint with the
    configuration it saved (``out_dir/config.toml``; ``overrides`` may change only
    :data:`~mlsph_jax.checkpoint.RESTART_MAY_CHANGE`): the Python form of ``mlsph run --restart
    DIR``.  The final state is bit for bit that of the uninterrupted run."""
    from . import config as config_mod
    from .cases import build_problem
    from .checkpoint import read_checkpoint as _read

    out = Path(out_dir)
    _read(out)   # a clear error for a missing folder or checkpoint before reading config.toml
    cfg = config_mod.load(out / "config.toml", overrides)
    return run_problem(build_problem(cfg), cfg, out_dir=out, quiet=quiet, restart=True)


