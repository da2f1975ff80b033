"""Output contract: HDF5 snapshots, XDMF index, summary.json, config.toml."""

from __future__ import annotations

import json
import subprocess
import sys
import xml.etree.ElementTree as ET

import h5py
import numpy as np
import pytest

from mlsph_jax import InputError
from mlsph_jax import io as mio


def _fields(n: int, d: int, seed: float = 0.0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(int(seed * 1000) + n + d)
    return {
        "x": rng.random((n, d)),
        "vol": np.full(n, 1.0 / n),
        "rho": 1.0 + rng.random(n),
        "vel": rng.standard_normal((n, d)),
        "p": rng.random(n),
        "kind": np.zeros(n, np.int32),
        "e": rng.random(n) + seed,
    }


@pytest.mark.parametrize("d", [1, 2, 3])
def test_three_snapshots_round_trip(tmp_path, d):
    n = 7
    written = [(0.1 * k, _fields(n, d, seed=k)) for k in range(3)]
    with mio.SnapshotWriter(tmp_path, dim=d) as w:
        for t, f in written:
            w.write(t, f, attrs={"step": 10 * int(round(10 * t))})
    snaps = mio.read_snapshots(tmp_path / "fields.h5")
    assert [t for t, _ in snaps] == pytest.approx([t for t, _ in written])
    for (_, got), (_, want) in zip(snaps, written, strict=True):
        assert set(got) == set(want)  # the derived xyz dataset is not returned
        for k in want:
            np.testing.assert_array_equal(got[k], want[k])
        assert got["kind"].dtype == np.int32
    with h5py.File(tmp_path / "fields.h5", "r") as f:
        assert sorted(f["snapshots"]) == ["00000", "00001", "00002"]
        assert f.attrs["dim"] == d
        g = f["snapshots/00002"]
        assert g.attrs["t"] == pytest.approx(0.2)
        assert g.attrs["step"] == 20
        if d < 3:
            xyz = g["xyz"][()]
            assert xyz.shape == (n, 3)
            np.testing.assert_array_equal(xyz[:, :d], written[2][1]["x"])
            assert np.all(xyz[:, d:] == 0.0)
        else:
            assert "xyz" not in g


@pytest.mark.parametrize("d", [1, 2])
def test_xdmf_is_valid_and_points_at_fields_h5(tmp_path, d):
    n = 5
    with mio.SnapshotWriter(tmp_path, dim=d) as w:
        for k in range(3):
            w.write(0.5 * k, _fields(n, d, seed=k))
    text = (tmp_path / "fields.xmf").read_text()
    assert "fields.h5" in text
    assert str(tmp_path) not in text  # relative reference
    root = ET.fromstring(text)
    assert root.tag == "Xdmf" and root.get("Version") == "3.0"
    series = root.find("Domain/Grid")
    assert series.get("GridType") == "Collection" and series.get("CollectionType") == "Temporal"
    grids = series.findall("Grid")
    assert [float(g.find("Time").get("Value")) for g in grids] == [0.0, 0.5, 1.0]
    for i, g in enumerate(grids):
        topo = g.find("Topology")
        assert topo.get("TopologyType") == "Polyvertex" and topo.get("NumberOfElements") == str(n)
        geo = g.find("Geometry")
        assert geo.get("GeometryType") == "XYZ"
        item = geo.find("DataItem")
        assert item.text == f"fields.h5:/snapshots/{i:05d}/xyz"
        assert item.get("Dimensions") == f"{n} 3"
        attrs = {a.get("Name"): a for a in g.findall("Attribute")}
        assert set(attrs) == {"vol", "rho", "vel", "p", "kind", "e"}
        assert attrs["rho"].get("AttributeType") == "Scalar"
        assert attrs["vel"].find("DataItem").get("Dimensions") == f"{n} {d}"
        assert attrs["kind"].find("DataItem").get("NumberType") == "Int"
        assert attrs["p"].find("DataItem").get("Precision") == "8"
        # every referenced dataset exists with the declared shape
        with h5py.File(tmp_path / "fields.h5", "r") as f:
            for it in g.iter("DataItem"):
                path = it.text.split(":", 1)[1]
                assert " ".join(map(str, f[path].shape)) == it.get("Dimensions")


def test_snapshots_survive_without_close(tmp_path):
    """Two snapshots written, writer never closed: another handle and another process read both."""
    w = mio.SnapshotWriter(tmp_path, dim=2)
    f0, f1 = _fields(4, 2, 0), _fields(4, 2, 1)
    w.write(0.0, f0)
    w.write(1.0, f1)
    snaps = mio.read_snapshots(tmp_path)
    assert [t for t, _ in snaps] == [0.0, 1.0]
    np.testing.assert_array_equal(snaps[1][1]["rho"], f1["rho"])
    code = ("import h5py, sys; f = h5py.File(sys.argv[1], 'r'); "
            "print(sorted(f['snapshots']), [float(f['snapshots'][k].attrs['t']) for k in "
            "sorted(f['snapshots'])], f['snapshots/00001/rho'][()].sum())")
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path / "fields.h5")],
                         capture_output=True, text=True, check=True).stdout
    assert "['00000', '00001'] [0.0, 1.0]" in out
    assert float(out.split("]")[-1]) == pytest.approx(f1["rho"].sum())
    assert ET.parse(tmp_path / "fields.xmf").getroot().find("Domain/Grid").findall("Grid")
    w.write(2.0, _fields(4, 2, 2))  # the writer keeps working
    assert len(mio.read_snapshots(tmp_path)) == 3


def test_mismatched_first_dimension_raises(tmp_path):
    w = mio.SnapshotWriter(tmp_path, dim=2)
    f = _fields(6, 2)
    f["p"] = f["p"][:5]
    with pytest.raises(InputError, match=r"first dimensions differ: p \(5,\)"):
        w.write(0.0, f)
    # nothing half-written: the next snapshot is still 00000
    w.write(0.0, _fields(6, 2))
    with h5py.File(tmp_path / "fields.h5", "r") as h:
        assert sorted(h["snapshots"]) == ["00000"]


@pytest.mark.parametrize("change, message", [
    (lambda f: f.pop("kind"), "missing kind"),
    (lambda f: f.__setitem__("vel", f["vel"][:, :1]), r"vel with shape \(6, 1\)"),
    (lambda f: f.__setitem__("x", np.zeros((6, 3))), r"x with shape \(6, 3\)"),
    (lambda f: f["rho"].__setitem__(3, np.nan), "non-finite value at particle 3"),
    (lambda f: f.__setitem__("xyz", np.zeros((6, 3))), "invalid field name 'xyz'"),
])
def test_bad_fields_raise(tmp_path, change, message):
    f = _fields(6, 2)
    change(f)
    with pytest.raises(InputError, match=message):
        mio.SnapshotWriter(tmp_path, dim=2).write(0.0, f)


def test_bad_dim_and_closed_writer(tmp_path):
    with pytest.raises(InputError, match="dim=4"):
        mio.SnapshotWriter(tmp_path, dim=4)
    w = mio.SnapshotWriter(tmp_path, dim=1)
    w.close()
    with pytest.raises(InputError, match="closed"):
        w.write(0.0, _fields(3, 1))


def test_1d_flat_arrays_accepted(tmp_path):
    f = _fields(5, 1)
    f["x"], f["vel"] = f["x"][:, 0], f["vel"][:, 0]
    with mio.SnapshotWriter(tmp_path, dim=1) as w:
        w.write(0.0, f)
    (_, got), = mio.read_snapshots(tmp_path)
    assert got["x"].shape == (5, 1) and got["vel"].shape == (5, 1)


def test_summary_json(tmp_path):
    s = mio.make_summary(
        case="riemann_1d", scheme={"method": "mlsph_ale", "degree": np.int64(2)},
        n_particles=np.int32(100), n_steps=42, t_final=np.float64(1e-5), wall_time_s=1.5,
        compile_time_s=0.5, status="ok",
        metrics={"l1_rho": np.float32(0.25), "bad": float("nan"), "inf": np.inf,
                 "profile": np.array([1.0, np.nan])},
        conservation={"mass": 1e-16}, extra_key=(1, 2))
    path = mio.write_summary(tmp_path / "out", s)
    assert path == tmp_path / "out" / "summary.json"
    text = path.read_text()
    assert "NaN" not in text and "Infinity" not in text
    data = json.loads(text)
    assert set(mio.SUMMARY_KEYS) <= set(data)
    assert data["n_particles"] == 100 and data["scheme"]["degree"] == 2
    assert data["t_final"] == 1e-5 and data["status"] == "ok"
    assert data["metrics"] == {"l1_rho": 0.25, "bad": None, "inf": None, "profile": [1.0, None]}
    assert data["extra_key"] == [1, 2]
    assert text.startswith("{\n  ")  # pretty printed


def test_summary_requires_contract_keys(tmp_path):
    with pytest.raises(InputError, match="missing .*compile_time_s"):
        mio.write_summary(tmp_path, {"case": "x", "scheme": {}, "n_particles": 1, "n_steps": 0,
                                     "t_final": 0.0, "wall_time_s": 0.0, "status": "ok",
                                     "metrics": {}, "conservation": {}})
    with pytest.raises(InputError, match="type object"):
        mio.write_summary(tmp_path, mio.make_summary(
            case="x", scheme={}, n_particles=1, n_steps=0, t_final=0.0, wall_time_s=0.0,
            compile_time_s=0.0, status="ok", metrics={"m": object()}))


def test_write_config_round_trip(tmp_path):
    from mlsph_jax import config

    cfg = config.load(None, case="riemann_1d", overrides=[
        "time.t_end=1e-5", "case.left={rho=1.0, u=0.0, p=1.0}",
        "case.right={rho=0.125, u=0.0, p=0.1}", "case.x_interface=0.5", "case.domain=[0, 1]",
        "case.n=100"])
    path = mio.write_config(tmp_path, cfg)
    assert config.load(path) == cfg


@pytest.mark.parametrize("d", [1, 2, 3])
def test_meshio_reads_every_time_step_with_attributes_of_the_right_shape(tmp_path, d):
    """fields.xmf is standard XDMF: meshio (a third-party reader) gets the vertex topology, the
    positions and every attribute of every snapshot; 1D vectors are [N, 1] scalars, not one tuple
    of N components; the kind codes are documented in the file."""
    meshio = pytest.importorskip("meshio", reason="meshio is in the test extras")
    n, rng = 9, np.random.default_rng(d)
    with mio.SnapshotWriter(tmp_path, d) as w:
        for k in range(3):
            w.write(0.25 * k, {"x": rng.uniform(size=(n, d)), "vol": np.full(n, 0.1), "rho": np.full(n, 1.0 + k),
                               "vel": np.full((n, d), 2.0), "p": np.zeros(n), "kind": np.zeros(n, np.int32)})
    with meshio.xdmf.TimeSeriesReader(tmp_path / "fields.xmf") as r:
        points, cells = r.read_points_cells()
        assert points.shape == (n, 3) and cells[0].type == "vertex" and len(cells[0].data) == n
        assert r.num_steps == 3
        for k in range(3):
            t, point_data, _ = r.read_data(k)
            assert t == pytest.approx(0.25 * k)
            assert point_data["rho"].shape == (n,) and np.all(point_data["rho"] == 1.0 + k)
            assert point_data["vel"].shape == (n, d)
    with h5py.File(tmp_path / "fields.h5") as f:
        assert "0 = fluid" in f.attrs["kind_codes"] and "1 = ghost" in f.attrs["kind_codes"]
        assert f["snapshots/00000/kind"].attrs["codes"] == f.attrs["kind_codes"]
    xmf = (tmp_path / "fields.xmf").read_text()
    assert 'Name="vel" AttributeType="Matrix"' not in xmf


def test_a_reader_in_another_process_does_not_stop_the_writer(tmp_path):
    """Looking at fields.h5 (h5py, ParaView) while a run writes it must not stop the run: HDF5's
    file lock refused the append ("unable to lock file") before the writer opened without it."""
    w = mio.SnapshotWriter(tmp_path, 2)
    w.write(0.0, _fields(5, 2))
    reader = subprocess.Popen(
        [sys.executable, "-c", f"import h5py, time; f = h5py.File({str(w.h5_path)!r}, 'r'); print('open', flush=True); "
                               "time.sleep(60)"], stdout=subprocess.PIPE, text=True)
    try:
        assert reader.stdout.readline().strip() == "open"
        w.write(0.1, _fields(5, 2, seed=1.0))
    finally:
        reader.kill()
        reader.wait()
    w.close()
    with h5py.File(w.h5_path, "r") as f:
        assert sorted(f["snapshots"]) == ["00000", "00001"]
        np.testing.assert_array_equal(f["snapshots/00001/rho"][()], _fields(5, 2, seed=1.0)["rho"])
