"""Run output: HDF5 snapshots, an XDMF index for ParaView, ``summary.json`` and ``config.toml``.

The output contract (other tools rely on it; keep it stable)::

    OUT/fields.h5     /snapshots/00000, /snapshots/00001, ...  (5 digits, from 00000)
                      each group: attribute "t" (float) and datasets
                        x [N,d], vol [N], rho [N], vel [N,d], p [N], kind [N]   (always)
                        e [N], ppd [N], area_degree [N], fit_degree [N], ...    (optional)
                        xyz [N,3]  x zero-padded to 3 components, only when d < 3 (for XDMF)
                      root attributes: "dim", "format" = "mlsph_jax.snapshots", "version"
    OUT/fields.xmf    XDMF 3 temporal collection of Polyvertex grids over fields.h5
                      (referenced by relative name)
    OUT/summary.json  run summary (keys: SUMMARY_KEYS, plus anything else)
    OUT/config.toml   the resolved configuration

Crash safety: :class:`SnapshotWriter` opens ``fields.h5`` only while writing one snapshot and
closes it before returning (closing flushes data and metadata), then rewrites ``fields.xmf``
atomically.  A crash, or a kill, between snapshots therefore leaves a complete file holding
every snapshot written so far, and other programs (ParaView, a plot script) can read the file
while the run goes on.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from pathlib import Path

import h5py
import numpy as np

from .errors import InputError
from .state import Kind

__all__ = [
    "REQUIRED_FIELDS",
    "SUMMARY_KEYS",
    "SnapshotWriter",
    "make_summary",
    "read_snapshots",
    "write_config",
    "write_summary",
    "write_xdmf",
]

FORMAT = "mlsph_jax.snapshots"
FORMAT_VERSION = 1
#: Datasets every snapshot holds.
REQUIRED_FIELDS = ("x", "vol", "rho", "vel", "p", "kind")
#: Keys every ``summary.json`` holds.
SUMMARY_KEYS = ("case", "scheme", "n_particles", "n_steps", "t_final", "wall_time_s",
                "compile_time_s", "status", "metrics", "conservation")
_VECTOR_FIELDS = ("x", "vel")
_PADDED = "xyz"
_CONNECTIVITY = "connectivity"
#: Particle kinds as written in the ``kind`` dataset (:class:`mlsph_jax.state.Kind`; also the root
#: attribute ``kind_codes`` of fields.h5 and an attribute of every ``kind`` dataset).
KIND_CODES = {k.name.lower(): int(k) for k in Kind}
_KIND_TEXT = ", ".join(f"{v} = {k}" for k, v in KIND_CODES.items())


def _atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file and a rename (never half-written)."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        os.chmod(tmp, 0o644)  # mkstemp creates 0600
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


class SnapshotWriter:
    """Appends snapshots to ``out_dir/fields.h5`` and keeps ``out_dir/fields.xmf`` current.

    Use as a context manager or call :meth:`close`.  ``dim`` is the space dimension (1..3);
    ``x`` and ``vel`` must have shape ``(N, dim)``.  An existing ``fields.h5`` is replaced,
    unless ``keep`` is given: then the existing file is continued after its first ``keep``
    snapshots (a restart; snapshots after those, written after the checkpoint the run resumes
    from, are removed) and a file that is not a readable snapshot file of ``dim`` with at least
    ``keep`` snapshots is refused (:class:`InputError`).
    """

    def __init__(self, out_dir: str | Path, dim: int, keep: int | None = None):
        if isinstance(dim, bool) or not isinstance(dim, int | np.integer) or dim not in (1, 2, 3):
            raise InputError(f"invalid dim={dim!r}; allowed: 1, 2 or 3")
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.dim = int(dim)
        self.h5_path = self.out_dir / "fields.h5"
        self.xmf_path = self.out_dir / "fields.xmf"
        self.count = 0
        self._closed = False
        if keep is not None:
            self._continue(int(keep))
            return
        with h5py.File(self.h5_path, "w") as f:
            f.attrs["dim"] = self.dim
            f.attrs["format"] = FORMAT
            f.attrs["version"] = FORMAT_VERSION
            f.attrs["kind_codes"] = _KIND_TEXT
            f.create_group("snapshots")
        write_xdmf(self.h5_path, self.xmf_path)

    def _continue(self, keep: int) -> None:
        """Open an existing file for appending after its first ``keep`` snapshots."""
        where = f"{str(self.h5_path)!r}"
        if not self.h5_path.is_file():
            raise InputError(f"invalid restart: {where} does not exist; allowed: the fields.h5 of the run")
        try:
            with h5py.File(self.h5_path, "a", locking=False) as f:   # as in write(): readers do not block
                if f.attrs.get("format") != FORMAT or int(f.attrs.get("dim", -1)) != self.dim:
                    raise InputError(f"invalid restart: {where} is not a {self.dim}D {FORMAT} file (format "
                                     f"{f.attrs.get('format')!r}, dim {f.attrs.get('dim')!r})")
                names = sorted(f["snapshots"])
                if len(names) < keep or names[:keep] != [f"{i:05d}" for i in range(keep)]:
                    raise InputError(f"invalid restart: {where} holds {len(names)} snapshots, the checkpoint "
                                     f"needs {keep} (the file is truncated or from another run)")
                for name in names[keep:]:
                    del f["snapshots"][name]
                for name in names[:keep]:   # read every kept snapshot: a corrupt file fails here
                    g = f["snapshots"][name]
                    for k in g:
                        g[k][()]
        except InputError:
            raise
        except (OSError, KeyError, ValueError, RuntimeError) as e:
            raise InputError(f"invalid restart: {where} is unreadable (truncated or corrupt: {e}); allowed: an "
                             "intact fields.h5 (restart from a copy, or rerun with --overwrite)") from None
        self.count = keep
        write_xdmf(self.h5_path, self.xmf_path)

    def snapshot_attrs(self, index: int) -> dict:
        """Attributes (``t``, ``step``, ...) of snapshot ``index``."""
        with h5py.File(self.h5_path, "r") as f:
            return dict(f["snapshots"][f"{index:05d}"].attrs)

    def write(self, t: float, fields: Mapping[str, object],
              attrs: Mapping[str, object] | None = None) -> None:
        """Append snapshot ``/snapshots/NNNNN`` with attribute ``t`` (and optional scalar
        ``attrs``, e.g. ``{"step": 120}``) and one dataset per field.

        Raises :class:`InputError` for a missing required field, a wrong shape, unequal first
        dimensions or non-finite floating-point values (a snapshot on disk is always good).
        """
        if self._closed:
            raise InputError(f"invalid write to closed SnapshotWriter({str(self.out_dir)!r})")
        meta = {"t": float(_finite_scalar("t", t))}
        for k, v in (attrs or {}).items():
            if not isinstance(k, str) or k in meta:
                raise InputError(f"invalid attrs key {k!r}; allowed: a str other than 't'")
            meta[k] = v if isinstance(v, str) else _finite_scalar(f"attrs[{k!r}]", v)
        data = self._check_fields(fields)
        name = f"{self.count:05d}"
        # no file lock: a user (another process) reading fields.h5 while the run writes must not stop
        # the run (HDF5 would refuse the append with "unable to lock file"); the reader may then see
        # the snapshot being written half done, the file itself stays whole
        with h5py.File(self.h5_path, "a", locking=False) as f:
            n = data["x"].shape[0]
            if _CONNECTIVITY not in f or f[_CONNECTIVITY].shape[0] != n:   # the Polyvertex topology
                if _CONNECTIVITY in f:
                    del f[_CONNECTIVITY]
                f.create_dataset(_CONNECTIVITY, data=np.arange(n, dtype=np.int64)[:, None])
            g = f["snapshots"].create_group(name)
            g.attrs.update(meta)
            for k, a in data.items():
                ds = g.create_dataset(k, data=a)
                if k == "kind":
                    ds.attrs["codes"] = _KIND_TEXT
            if self.dim < 3:
                xyz = np.zeros((data["x"].shape[0], 3), dtype=np.float64)
                xyz[:, : self.dim] = data["x"]
                g.create_dataset(_PADDED, data=xyz)
        self.count += 1
        write_xdmf(self.h5_path, self.xmf_path)

    def _check_fields(self, fields: Mapping[str, object]) -> dict[str, np.ndarray]:
        if not isinstance(fields, Mapping):
            raise InputError(f"invalid fields of type {type(fields).__name__}; allowed: a dict of "
                             "name -> array")
        missing = [k for k in REQUIRED_FIELDS if k not in fields]
        if missing:
            raise InputError(f"invalid fields: missing {', '.join(missing)}; allowed: a dict with "
                             f"at least {', '.join(REQUIRED_FIELDS)}")
        data = {}
        for k, v in fields.items():
            if not isinstance(k, str) or not k or "/" in k or k == _PADDED or k.startswith("."):
                raise InputError(f"invalid field name {k!r}; allowed: a non-empty name without '/',"
                                 f" other than {_PADDED!r}")
            a = np.asarray(v)
            if a.dtype == np.bool_:
                a = a.astype(np.uint8)
            if a.dtype.kind not in "fiu":
                raise InputError(f"invalid field {k} of dtype {a.dtype}; allowed: numeric arrays")
            if a.ndim == 0:
                raise InputError(f"invalid field {k} of shape (); allowed: one row per particle")
            data[k] = a
        n = data["x"].shape[0]
        if data["x"].ndim == 1 and self.dim == 1:
            data["x"] = data["x"][:, None]
        for k in _VECTOR_FIELDS:
            if data[k].shape != (n, self.dim):
                if data[k].ndim == 1 and self.dim == 1 and data[k].shape == (n,):
                    data[k] = data[k][:, None]
                    continue
                raise InputError(f"invalid field {k} with shape {data[k].shape}; allowed: shape "
                                 f"({n}, {self.dim}) (N particles, dim = {self.dim})")
        bad = {k: a.shape for k, a in data.items() if a.shape[0] != n}
        if bad:
            raise InputError("invalid fields: first dimensions differ: "
                             + ", ".join(f"{k} {s}" for k, s in bad.items())
                             + f"; allowed: {n} rows (as x) in every field")
        for k, a in data.items():
            if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
                rows = np.flatnonzero(~np.isfinite(a).reshape(n, -1).all(axis=1))
                raise InputError(f"invalid field {k}: non-finite value at particle {int(rows[0])} "
                                 f"({rows.size} particles); allowed: finite values")
        return data

    def close(self) -> None:
        """Finish the output (the file is already complete after every :meth:`write`)."""
        self._closed = True

    def __enter__(self) -> SnapshotWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _finite_scalar(name: str, v) -> float | int:
    a = np.asarray(v)
    if a.ndim != 0 or a.dtype.kind not in "fiub":
        raise InputError(f"invalid {name}={v!r}; allowed: a finite number")
    x = a.item()
    if isinstance(x, float) and not math.isfinite(x):
        raise InputError(f"invalid {name}={v!r}; allowed: a finite number")
    return x


# --------------------------------------------------------------------------------------------
# XDMF
# --------------------------------------------------------------------------------------------


def _number_type(dtype: np.dtype) -> tuple[str, int]:
    kind = dtype.kind
    if kind == "f":
        return "Float", dtype.itemsize
    if kind == "i":
        return ("Char" if dtype.itemsize == 1 else "Int"), dtype.itemsize
    if kind == "u":
        return ("UChar" if dtype.itemsize == 1 else "UInt"), dtype.itemsize
    raise InputError(f"invalid dataset dtype {dtype}; allowed: numeric")


def _data_item(parent: ET.Element, h5_name: str, path: str, ds: h5py.Dataset) -> None:
    number, precision = _number_type(ds.dtype)
    item = ET.SubElement(parent, "DataItem", {
        "Dimensions": " ".join(str(s) for s in ds.shape), "NumberType": number,
        "Precision": str(precision), "Format": "HDF"})
    item.text = f"{h5_name}:{path}"


def write_xdmf(h5_path: str | Path, xmf_path: str | Path) -> None:
    """Write an XDMF 3 index of the snapshots of ``h5_path`` to ``xmf_path`` (atomically).

    One temporal collection; each snapshot is a Polyvertex grid with its time, its topology (the
    vertex list ``/connectivity``), the particle positions as XYZ geometry (``xyz`` when
    present, else ``x``) and every other dataset as a node attribute (``Scalar`` for [N] and
    [N, 1], ``Vector`` for [N,2] and [N,3], ``Matrix`` otherwise).  ParaView, VTK's XDMF readers
    and meshio read it.
    The HDF5 file is referenced by its path relative to the XDMF file.
    """
    h5_path, xmf_path = Path(h5_path), Path(xmf_path)
    h5_name = Path(os.path.relpath(h5_path.resolve(), xmf_path.resolve().parent)).as_posix()
    root = ET.Element("Xdmf", {"Version": "3.0"})
    domain = ET.SubElement(root, "Domain")
    series = ET.SubElement(domain, "Grid", {"Name": "particles", "GridType": "Collection",
                                            "CollectionType": "Temporal"})
    with h5py.File(h5_path, "r") as f:
        snaps = f.get("snapshots")
        for name in sorted(snaps) if snaps is not None else []:
            g = snaps[name]
            base = f"/snapshots/{name}"
            geo = _PADDED if _PADDED in g else "x"
            n = g[geo].shape[0]
            grid = ET.SubElement(series, "Grid", {"Name": f"snapshot_{name}",
                                                  "GridType": "Uniform"})
            ET.SubElement(grid, "Time", {"Value": repr(float(g.attrs["t"]))})
            topo = ET.SubElement(grid, "Topology", {"TopologyType": "Polyvertex",
                                                    "NumberOfElements": str(n), "NodesPerElement": "1"})
            if _CONNECTIVITY in f and f[_CONNECTIVITY].shape[0] == n:
                _data_item(topo, h5_name, f"/{_CONNECTIVITY}", f[_CONNECTIVITY])
            geometry = ET.SubElement(grid, "Geometry", {"GeometryType": "XYZ"})
            _data_item(geometry, h5_name, f"{base}/{geo}", g[geo])
            for k in sorted(g):
                if k in ("x", _PADDED):
                    continue
                ds = g[k]
                if ds.ndim == 1 or (ds.ndim == 2 and ds.shape[1] == 1):   # [N, 1]: 1D vectors are scalars
                    atype = "Scalar"
                elif ds.ndim == 2 and ds.shape[1] in (2, 3):
                    atype = "Vector"
                else:
                    atype = "Matrix"
                attr = ET.SubElement(grid, "Attribute", {"Name": k, "AttributeType": atype,
                                                         "Center": "Node"})
                _data_item(attr, h5_name, f"{base}/{k}", ds)
    ET.indent(root)
    _atomic_write_text(xmf_path, '<?xml version="1.0" ?>\n'
                       + ET.tostring(root, encoding="unicode") + "\n")


def read_snapshots(path: str | Path) -> list[tuple[float, dict[str, np.ndarray]]]:
    """Read every snapshot of ``fields.h5`` (or of an output directory holding it), in order.

    Returns ``[(t, {name: array}), ...]``; the derived ``xyz`` dataset is left out.
    """
    p = Path(path)
    if p.is_dir():
        p = p / "fields.h5"
    if not p.is_file():
        raise InputError(f"invalid path={str(path)!r}: no such file; allowed: a fields.h5 file "
                         "or an output directory holding one")
    out = []
    with h5py.File(p, "r") as f:
        snaps = f.get("snapshots")
        if snaps is None:
            raise InputError(f"invalid path={str(path)!r}: no /snapshots group; allowed: a "
                             "fields.h5 written by SnapshotWriter")
        for name in sorted(snaps):
            g = snaps[name]
            out.append((float(g.attrs["t"]), {k: g[k][()] for k in g if k != _PADDED}))
    return out


# --------------------------------------------------------------------------------------------
# Summary and config
# --------------------------------------------------------------------------------------------


def _jsonable(v, where: str):
    """Convert numpy/jax scalars and arrays, tuples and paths to JSON types; NaN/inf → None."""
    if v is None or isinstance(v, bool | str):
        return v
    if isinstance(v, np.bool_):
        return bool(v)
    if isinstance(v, int | np.integer):
        return int(v)
    if isinstance(v, float | np.floating):
        f = float(v)
        return f if math.isfinite(f) else None
    if isinstance(v, Mapping):
        return {str(k): _jsonable(x, f"{where}.{k}") for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_jsonable(x, f"{where}[{i}]") for i, x in enumerate(v)]
    if isinstance(v, os.PathLike):
        return os.fspath(v)
    if hasattr(v, "__array__"):  # numpy and jax arrays (and 0-d arrays)
        a = np.asarray(v)
        if a.dtype.kind in "biuf":
            return _jsonable(a.item() if a.ndim == 0 else a.tolist(), where)
    raise InputError(f"invalid {where} of type {type(v).__name__}; allowed: numbers, strings, "
                     "bools, None, lists, dicts and numeric arrays")


def make_summary(*, case: str, scheme: Mapping, n_particles: int, n_steps: int, t_final: float,
                 wall_time_s: float, compile_time_s: float, status: str,
                 metrics: Mapping | None = None, conservation: Mapping | None = None,
                 **extra) -> dict:
    """Build a summary dict with every key of :data:`SUMMARY_KEYS` (plus ``extra`` keys).

    ``status`` is e.g. ``"ok"`` or the failure (``"nan"``, ``"dt_underflow"``, ...);
    ``metrics`` maps names to numbers (errors, forces, ...); ``conservation`` holds the
    drifts of the conserved totals.
    """
    return {"case": case, "scheme": dict(scheme), "n_particles": n_particles, "n_steps": n_steps,
            "t_final": t_final, "wall_time_s": wall_time_s, "compile_time_s": compile_time_s,
            "status": status, "metrics": dict(metrics or {}),
            "conservation": dict(conservation or {}), **extra}


def write_timeseries(out_dir: str | Path, rows) -> Path:
    """Write ``out_dir/timeseries.csv``: one row per output time, columns ``t`` and the case's
    diagnostics (e.g. kinetic energy)."""
    path = Path(out_dir) / "timeseries.csv"
    keys = list(rows[0])
    lines = [",".join(keys)] + [",".join(repr(float(r[k])) for k in keys) for r in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def write_summary(out_dir: str | Path, summary: Mapping) -> Path:
    """Write ``out_dir/summary.json`` (pretty printed, atomically) and return its path.

    ``summary`` must hold every key of :data:`SUMMARY_KEYS`.  numpy/jax scalars and arrays are
    converted to Python numbers and lists.  Non-finite numbers (NaN, inf) anywhere, including
    ``metrics``, are written as ``null``; ``status`` is written as given (a failed run says so
    there).  The file is therefore always strict JSON.
    """
    if not isinstance(summary, Mapping):
        raise InputError(f"invalid summary of type {type(summary).__name__}; allowed: a dict")
    missing = [k for k in SUMMARY_KEYS if k not in summary]
    if missing:
        raise InputError(f"invalid summary: missing {', '.join(missing)}; allowed: a dict with "
                         f"at least {', '.join(SUMMARY_KEYS)}")
    for k in ("metrics", "conservation"):
        if not isinstance(summary[k], Mapping):
            raise InputError(f"invalid summary[{k!r}] of type {type(summary[k]).__name__}; "
                             "allowed: a dict")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    data = _jsonable(summary, "summary")
    path = out_dir / "summary.json"
    _atomic_write_text(path, json.dumps(data, indent=2, allow_nan=False) + "\n")
    return path


def write_config(out_dir: str | Path, cfg: Mapping) -> Path:
    """Write the resolved configuration to ``out_dir/config.toml`` and return its path."""
    from .config import dumps

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "config.toml"
    _atomic_write_text(path, dumps(cfg))
    return path
