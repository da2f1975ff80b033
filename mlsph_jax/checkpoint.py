"""Exact restart state of a run (``OUT/checkpoint.h5``) and the output-folder policy.

The snapshots in ``fields.h5`` hold primitive fields for plotting and ParaView; a run can not be
continued bit for bit from them (``rho u`` recomputed from ``rho`` and ``u`` is not the carried
``V U``).  :class:`~mlsph_jax.simulation.Simulation` therefore also writes ``checkpoint.h5``
at every output time, when it is interrupted and when it fails: the scan carry (particles
``x, vol, q, kind, ppd``, time, step count, last ``dt``, MOOD statistics, the last step's
approximation degrees and the reduced-degree statistics), the neighbour spec
the run has grown to, the particles the Eulerian geometry was computed from, the diagnostics
time series so far (sampled at the output times or at the finer ``output.series_interval``), the
steady-state test's previous velocities, the index of the next step target (a sample or output
time), the driver settings and the resolved configuration.  The file is replaced atomically
(written to a temporary file, then renamed): a kill leaves the previous checkpoint intact.

Every step of the driver is a function of the carry alone (the step size is the CFL step of the
carried state, clipped to the next sample or output time), so a run resumed from a checkpoint
(:meth:`Simulation.run` with ``restart=True``, ``mlsph run --restart DIR``) reproduces the
uninterrupted run bit for bit, whatever chunk the interruption fell in.

:func:`prepare_out_dir` is the output-folder policy: a folder holding a run is refused unless the
caller asks to overwrite it (its old outputs are then removed, so no plot of another case
lingers) or to restart it.
"""

from __future__ import annotations

import dataclasses
import json
import os
import tempfile
from collections.abc import Mapping
from pathlib import Path

import h5py
import jax.numpy as jnp
import numpy as np

from .errors import InputError
from .state import Particles

__all__ = ["CHECKPOINT", "RESTART_ADDED_CASE_KEYS", "RESTART_ADDED_KEYS", "RUN_FILES", "Checkpoint", "compare_settings",
           "holds_run", "prepare_out_dir", "read_checkpoint", "restart_added_keys", "write_checkpoint"]

CHECKPOINT = "checkpoint.h5"
FORMAT = "mlsph_jax.checkpoint"
FORMAT_VERSION = 1
#: Files a run writes at the top of its output folder (plus the case's ``*.png`` plots).
RUN_FILES = ("summary.json", "fields.h5", "fields.xmf", "config.toml", "timeseries.csv", CHECKPOINT)
#: Files whose presence means: this folder holds a run.
_RUN_MARKERS = ("summary.json", "fields.h5", CHECKPOINT)
#: Settings a restart may change (they do not change the numbers of the steps; a smaller
#: ``case.steady_tol`` also continues a run its steady-state test stopped).
RESTART_MAY_CHANGE = ("time.max_steps", "output.progress", "output.plots", "output.degree_fallback_warn",
                      "case.steady_tol")
#: Config keys added after checkpoints were first written, with the value that reproduces the runs
#: made before them: a run's config without the key restarts when the key has that value now
#: (:func:`restart_added_keys`; the current config must have the key).
RESTART_ADDED_KEYS = {"output.series_interval": 0.0}
#: The same for one case's own keys (``case.*`` keys mean different things in different cases).
RESTART_ADDED_CASE_KEYS = {
    # cylinder keys added after its first runs (2026-11-25), at the values of those runs: layouts
    # (decisions 72, 90), elliptic body (65), shedding trigger and statistics (69), far-field
    # options (68), isothermal body (102), bodies given by points (103), offset layout (105),
    # Euler flow (107)
    "cylinder": {"case.layout": "polar", "case.lattice_ratio": 1.0, "case.blend_radius": 2.0,
                 "case.wake_spacing": 0.1, "case.wake_length": 6.0, "case.wake_grading": 0.16,
                 "case.body": "circle", "case.aspect": 1.0, "case.alpha": 0.0, "case.perturbation": 0.0,
                 "case.perturbation_x": 1.5, "case.perturbation_core": 0.5, "case.transient": 50.0,
                 "case.far_field": "frozen", "case.prandtl": 0.0, "case.wall_temperature": 0.0,
                 "case.body_points": [], "case.offset_rows": 3, "case.inviscid": False},
}


def restart_added_keys(case: str) -> dict:
    """The keys a restart of a ``case`` run takes at these values when its saved config lacks them."""
    return {**RESTART_ADDED_KEYS, **RESTART_ADDED_CASE_KEYS.get(case, {})}

_CARRY_SCALARS = ("t", "step", "dt_last")
_PARTICLE_FIELDS = ("x", "vol", "q", "kind", "ppd")


@dataclasses.dataclass
class Checkpoint:
    """Everything :class:`~mlsph_jax.simulation.Simulation` needs to continue a run exactly."""

    particles: Particles
    t: np.ndarray           # float64 scalar
    step: np.ndarray        # int32 scalar
    dt_last: np.ndarray     # float64 scalar
    mood: np.ndarray        # MOOD statistics (integrate.MOOD_STATS)
    next_target: int        # index of the next step target (a sample time of the series or an output time)
    n_snapshots: int        # snapshots in fields.h5 when the checkpoint was written
    nspec: dict             # NeighborSpec fields
    geom_source: tuple[np.ndarray, np.ndarray] | None  # (x, vol) of the Eulerian geometry
    regrowths: int
    regrowth_log: list
    series: list            # diagnostics rows so far
    vel_prev: np.ndarray
    t_prev: float
    steady: dict | None     # last steady-state test
    settings: dict          # driver settings (cfl, chunk, snapshots, ...)
    config: dict | None     # resolved configuration
    case: str
    status: str
    wall_time_s: float
    compile_time_s: float
    degree: np.ndarray | None = None     # [N, 2] degrees of the last step (mlsph_jax.fallback)
    fallback: np.ndarray | None = None   # reduced-degree statistics (fallback.STATS, max and last)


def write_checkpoint(out_dir: str | Path, ck: Checkpoint) -> Path:
    """Write ``out_dir/checkpoint.h5`` atomically and return its path."""
    out_dir = Path(out_dir)
    path = out_dir / CHECKPOINT
    fd, tmp = tempfile.mkstemp(dir=out_dir, prefix=f".{CHECKPOINT}.", suffix=".tmp")
    os.close(fd)
    try:
        with h5py.File(tmp, "w") as f:
            f.attrs["format"] = FORMAT
            f.attrs["version"] = FORMAT_VERSION
            g = f.create_group("particles")
            for k in _PARTICLE_FIELDS:
                g.create_dataset(k, data=np.asarray(getattr(ck.particles, k)))
            for k in _CARRY_SCALARS:
                f.create_dataset(k, data=np.asarray(getattr(ck, k)))
            f.create_dataset("mood", data=np.asarray(ck.mood))
            for k in ("degree", "fallback"):
                if getattr(ck, k) is not None:
                    f.create_dataset(k, data=np.asarray(getattr(ck, k)))
            f.create_dataset("vel_prev", data=np.asarray(ck.vel_prev))
            if ck.geom_source is not None:
                f.create_dataset("geom_source/x", data=np.asarray(ck.geom_source[0]))
                f.create_dataset("geom_source/vol", data=np.asarray(ck.geom_source[1]))
            meta = {"next_target": ck.next_target, "n_snapshots": ck.n_snapshots, "nspec": ck.nspec,
                    "regrowths": ck.regrowths, "regrowth_log": ck.regrowth_log, "series": ck.series,
                    "t_prev": ck.t_prev, "steady": ck.steady, "settings": ck.settings, "config": ck.config,
                    "case": ck.case,
                    "status": ck.status, "wall_time_s": ck.wall_time_s, "compile_time_s": ck.compile_time_s}
            f.attrs["meta"] = json.dumps(meta, default=_json_default)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def _json_default(v):
    if isinstance(v, np.generic | np.ndarray) or hasattr(v, "__array__"):
        return np.asarray(v).tolist()
    raise TypeError(f"not JSON serialisable: {type(v).__name__}")


def read_checkpoint(out_dir: str | Path) -> Checkpoint:
    """Read ``out_dir/checkpoint.h5``; :class:`InputError` naming the folder and the problem
    when the folder, the file or its content is missing or unreadable."""
    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        raise InputError(f"invalid restart folder {str(out_dir)!r}: no such folder; allowed: the output folder "
                         "of an earlier run")
    path = out_dir / CHECKPOINT
    if not path.is_file():
        raise InputError(f"invalid restart folder {str(out_dir)!r}: it holds no {CHECKPOINT} (written at every "
                         "output time by mlsph-jax >= 0.1 runs); allowed: the output folder of an earlier run")
    try:
        with h5py.File(path, "r") as f:
            if f.attrs.get("format") != FORMAT or int(f.attrs.get("version", -1)) != FORMAT_VERSION:
                raise InputError(f"invalid restart file {str(path)!r}: format {f.attrs.get('format')!r} version "
                                 f"{f.attrs.get('version')!r}; allowed: {FORMAT!r} version {FORMAT_VERSION}")
            meta = json.loads(f.attrs["meta"])
            g = f["particles"]
            arrays = {k: g[k][()] for k in _PARTICLE_FIELDS}
            scalars = {k: f[k][()] for k in _CARRY_SCALARS}
            mood = f["mood"][()]
            extra = {k: f[k][()] for k in ("degree", "fallback") if k in f}   # absent: an older checkpoint
            vel_prev = f["vel_prev"][()]
            geom = (f["geom_source/x"][()], f["geom_source/vol"][()]) if "geom_source" in f else None
    except InputError:
        raise
    except (OSError, KeyError, ValueError) as e:
        raise InputError(f"invalid restart file {str(path)!r}: unreadable or incomplete ({e}); allowed: a "
                         f"{CHECKPOINT} written by an mlsph-jax run") from None
    particles = Particles(**{k: jnp.asarray(v) for k, v in arrays.items()})
    return Checkpoint(particles=particles, mood=mood, vel_prev=vel_prev, geom_source=geom, **scalars, **extra,
                      next_target=int(meta["next_target"]), n_snapshots=int(meta["n_snapshots"]),
                      nspec=meta["nspec"], regrowths=int(meta["regrowths"]), regrowth_log=meta["regrowth_log"],
                      series=meta["series"], t_prev=float(meta["t_prev"]), steady=meta["steady"],
                      settings=meta["settings"],
                      config=meta["config"], case=meta["case"], status=meta["status"],
                      wall_time_s=float(meta["wall_time_s"]), compile_time_s=float(meta["compile_time_s"]))


def _flatten(d: Mapping | None, prefix: str = "") -> dict:
    out = {}
    for k, v in (d or {}).items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(_flatten(v, key + "."))
        else:
            out[key] = list(v) if isinstance(v, tuple) else v
    return out


def compare_settings(saved: Mapping, current: Mapping, *, where: str, may_change=(),
                     added: Mapping | None = None) -> list[str]:
    """``"<where>key: <saved> in the run, <current> now"`` for every (dotted) key whose value differs,
    except ``may_change``;
    a key of ``added`` that ``current`` has and ``saved`` lacks is taken as its value there (a key
    added later)."""
    a, b = _flatten(json.loads(json.dumps(saved, default=_json_default))), \
        _flatten(json.loads(json.dumps(current, default=_json_default)))
    a = {**{k: v for k, v in (added or {}).items() if k in b}, **a}
    diffs = []
    for k in sorted(set(a) | set(b)):
        if k in may_change:
            continue
        if a.get(k, "<absent>") != b.get(k, "<absent>"):
            diffs.append(f"{where}{k}: {a.get(k, '<absent>')!r} in the run, {b.get(k, '<absent>')!r} now")
    return diffs


def holds_run(out_dir: str | Path) -> list[str]:
    """Names of the run files (summary.json, fields.h5, checkpoint.h5) present in ``out_dir``."""
    out_dir = Path(out_dir)
    return [m for m in _RUN_MARKERS if (out_dir / m).exists()]


def prepare_out_dir(out_dir: str | Path, *, overwrite: bool = False) -> None:
    """Refuse an output folder that holds a run (:class:`InputError` naming the files found)
    unless ``overwrite``; with ``overwrite`` remove the old run's files (:data:`RUN_FILES` and
    every ``*.png`` at the top of the folder) so that nothing of the old run lingers."""
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"invalid output folder {str(out_dir)!r}: it is a file; allowed: a folder")
    found = holds_run(out_dir) if out_dir.is_dir() else []
    if not found:
        return
    if not overwrite:
        raise InputError(
            f"invalid output folder {str(out_dir)!r}: it already holds a run ({', '.join(found)}); allowed: a new "
            f"folder, --overwrite (Python: overwrite=True) to replace that run, or --restart {out_dir} (Python: "
            "restart=True) to continue it")
    for name in RUN_FILES:
        (out_dir / name).unlink(missing_ok=True)
    for png in out_dir.glob("*.png"):
        png.unlink()
