"""Runs sharded over several devices (``run.devices``, :mod:`mlsph_jax.sharding`) compute the
one-device numbers.

XLA_FLAGS must be set before jax is imported, so the multi-device runs happen in subprocesses
with two forced host devices (and, for :func:`jax.distributed.initialize`, two processes with
one device each talking through JAX's CPU collectives on localhost).
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

import mlsph_jax
from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.errors import ConfigError, InputError
from mlsph_jax.simulation import Simulation, run_problem

ROOT = Path(mlsph_jax.__file__).resolve().parents[1]

#: A short Taylor-Green run, 12 x 12 = 144 particles, in the frame given as the script's last
#: argument (ale_shift: lists rebuilt every stage, particles wander across the domain while the
#: shards are index ranges).
CASE = """
import dataclasses, json, sys
import numpy as np
from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.simulation import Simulation, run_problem

TEXT = '[case]\\nname = "taylor_green_2d"\\nn = 12\\n[output]\\nplots = false\\nprogress = false\\n'
OVER = [f"scheme.frame={sys.argv[-1]}", "time.t_end=0.02", "time.chunk=4"]

def run(devices, capacity=None, precision="float64", decomposition="index"):
    cfg = config.loads(TEXT, [*OVER, f"run.devices={devices}", f"run.precision={precision}",
                              f"run.decomposition={decomposition}"])
    pb = build_problem(cfg)
    if capacity is None:
        return run_problem(pb, cfg, quiet=True), []
    sim = Simulation(pb, chunk=4, devices=devices, precision=precision)
    sim.setup = dataclasses.replace(sim.setup, nspec=dataclasses.replace(sim.nspec, capacity=capacity))
    sim._build()
    return sim.run(progress=False), sim.regrowth_log

def fields(res):
    return {k: np.asarray(getattr(res.particles, k)).tolist() for k in ("x", "vol", "q")} | {
        "n_steps": res.summary["n_steps"], "t": res.summary["t_final"], "devices": res.summary["devices"],
        "metrics": res.summary["metrics"], "decomposition": res.summary.get("decomposition"),
        "conservation": res.summary["conservation"]}
"""

TWO_DEVICES = CASE + """
out = {}
runs = (("one", 1, None, "float64"), ("two", 2, None, "float64"))
if sys.argv[-1] != "eulerian":
    runs += (("two_overflow", 2, 3, "float64"), ("one_f32", 1, None, "float32"), ("two_f32", 2, None, "float32"))
for name, devices, cap, precision in runs:
    res, log = run(devices, cap, precision)
    out[name] = fields(res) | {"regrowths": [e["causes"] for e in log]}
if sys.argv[-1] == "eulerian":   # the spatial decomposition (mlsph_jax.spatial)
    out["spatial"] = fields(run(2, decomposition="spatial")[0])
try:
    from mlsph_jax.sharding import particle_sharding
    particle_sharding(2, 145)
except Exception as e:
    out["odd_error"] = f"{type(e).__name__}: {e}"
print("RESULT" + json.dumps(out))
"""

DISTRIBUTED = """
import sys, jax
jax.distributed.initialize(coordinator_address="127.0.0.1:" + sys.argv[2], num_processes=2,
                           process_id=int(sys.argv[1]))
assert len(jax.devices()) == 2 and len(jax.local_devices()) == 1
""" + CASE + """
res, _ = run(2, decomposition=sys.argv[-2])
print("RESULT" + json.dumps(fields(res)))
"""


def _python(code: str, *args: str, devices: int = 1, background: bool = False):
    env = {**os.environ, "PYTHONPATH": str(ROOT), "JAX_PLATFORMS": "cpu",
           # the test run's other flags (tests/conftest.py: its fusion emitters) plus the devices
           "XLA_FLAGS": f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count={devices}".strip()}
    cmd = [sys.executable, "-c", code, *args]
    if background:
        return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
    return _result(proc.returncode, proc.stdout, proc.stderr)


def _result(rc: int, stdout: str, stderr: str) -> dict:
    assert rc == 0, stderr[-3000:]
    line = [s for s in stdout.splitlines() if s.startswith("RESULT")]
    assert line, stdout[-2000:] + stderr[-2000:]
    return json.loads(line[-1][len("RESULT"):])


def _assert_same(a: dict, b: dict):
    """Equal to round-off: step count, final time, and x, vol, q within 1e-13 of their scale."""
    import numpy as np

    assert (a["n_steps"], a["t"]) == (b["n_steps"], b["t"]) and a["n_steps"] > 1
    for k in ("x", "vol", "q"):
        x, y = np.asarray(a[k]), np.asarray(b[k])
        assert x.shape == y.shape
        np.testing.assert_allclose(x, y, rtol=0, atol=1e-13 * np.abs(x).max(), err_msg=k)


@pytest.fixture(scope="module")
def two_devices() -> dict:
    """Eulerian (the geometry computed once, sharded; the neighbour gathers cross the shards)."""
    return _python(TWO_DEVICES, "eulerian", devices=2)


@pytest.fixture(scope="module")
def two_devices_moving() -> dict:
    return _python(TWO_DEVICES, "ale_shift", devices=2)


def _check_two_devices(out: dict):
    one, two = out["one"], out["two"]
    assert (one["devices"], two["devices"]) == (1, 2)
    _assert_same(one, two)
    for k, v in one["metrics"].items():
        assert two["metrics"][k] == pytest.approx(v, rel=1e-12, abs=1e-15), k


def test_two_host_devices_give_the_one_device_numbers(two_devices):
    _check_two_devices(two_devices)


@pytest.mark.slow
def test_two_host_devices_give_the_one_device_numbers_for_moving_particles(two_devices_moving):
    _check_two_devices(two_devices_moving)


def test_spatial_decomposition_gives_the_one_device_numbers(two_devices):
    """run.decomposition = "spatial": Morton-ordered shards, a two-stencil halo exchanged by
    ppermute in shard_map; the final state (back in the original particle order), step count,
    metrics and conservation equal the one-device run's to round-off."""
    one, sp = two_devices["one"], two_devices["spatial"]
    assert sp["devices"] == 2 and sp["decomposition"]["kind"] == "spatial"
    assert min(sp["decomposition"]["halo"]) > 0        # the shards do exchange
    _assert_same(one, sp)
    for k, v in one["metrics"].items():
        assert sp["metrics"][k] == pytest.approx(v, rel=1e-12, abs=1e-15), k
    for k, v in one["conservation"].items():
        assert sp["conservation"][k] == pytest.approx(v, abs=1e-13), k


@pytest.mark.slow
def test_overflow_on_two_devices_regrows_and_gives_the_same_numbers(two_devices_moving):
    """A row capacity of 3 overflows in the first step; the sharded driver grows it (one
    recompilation) and finishes with the numbers of the run sized right on one device."""
    out = two_devices_moving["two_overflow"]
    assert out["regrowths"] and "NEIGHBOR_OVERFLOW_ROW" in out["regrowths"][0]
    _assert_same(two_devices_moving["one"], out)


@pytest.mark.slow
def test_float32_on_two_devices_gives_the_float32_one_device_numbers(two_devices_moving):
    """run.precision and run.devices together: the sharded float32 run ends with the float32
    one-device state to float32 round-off grown over 20 steps (the partitioned program may fuse
    and order operations differently): within 1e-5 of the scale (measured 1.5e-6, ~12 ulp)."""
    import numpy as np

    one, two = two_devices_moving["one_f32"], two_devices_moving["two_f32"]
    assert (one["n_steps"], one["t"]) == (two["n_steps"], two["t"])
    for k in ("x", "vol", "q"):
        x, y = np.asarray(one[k]), np.asarray(two[k])
        np.testing.assert_allclose(x, y, rtol=0, atol=1e-5 * np.abs(x).max(), err_msg=k)


def test_particle_count_not_divisible_by_the_devices_is_refused(two_devices):
    msg = two_devices["odd_error"]
    assert msg.startswith("InputError") and "run.devices=2" in msg and "145 particles" in msg
    assert msg.endswith("allowed here: 1")  # the divisors of 145 up to the 2 devices


def test_more_devices_than_available_is_refused():
    cfg = config.loads('[case]\nname = "taylor_green_2d"\nn = 8\n', ["run.devices=64"])
    with pytest.raises(InputError, match=r"run\.devices=64: only 1 device\(s\) available.*allowed: 1\.\.1"):
        run_problem(build_problem(cfg), cfg, quiet=True)
    with pytest.raises(InputError, match=r"invalid run\.devices=-1; allowed: an int >= 0"):
        Simulation(build_problem(cfg), devices=-1)


def test_more_shards_than_particles_is_refused_by_the_spatial_layout():
    """Issue 15 bad input "more devices than the domain decomposition allows": the spatial
    decomposition gives every shard at least one particle; one shard more than particles is an
    InputError naming run.devices, the value and the largest allowed count (host side, so it
    is checked here without that many devices)."""
    import numpy as np

    from mlsph_jax.run import setup_run
    from mlsph_jax.spatial import build_layout

    pb = build_problem(config.loads('[case]\nname = "taylor_green_2d"\nn = 8\n'))
    nl = setup_run(pb).nl
    x, idx, mask = (np.asarray(a) for a in (pb.particles.x, nl.idx, nl.mask))
    build_layout(x, idx, mask, pb.particles.n)     # one particle per shard is allowed
    with pytest.raises(InputError, match=r"invalid run\.devices=65: shard 64 would own no particle .*at most 64"):
        build_layout(x, idx, mask, pb.particles.n + 1)


def test_negative_device_count_is_a_config_error():
    with pytest.raises(ConfigError, match=r"run\.devices"):
        config.loads('[case]\nname = "taylor_green_2d"\nn = 8\n', ["run.devices=-1"])


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_two_processes_with_jax_distributed_give_the_one_device_numbers(two_devices):
    """Two processes on localhost, one CPU device each, joined by jax.distributed.initialize
    (cross-process collectives: gloo); both end with the whole state of the one-device run."""
    for out in _distributed("index"):
        assert out["devices"] == 2
        _assert_same(two_devices["one"], out)


def _distributed(decomposition: str) -> list[dict]:
    port = str(_free_port())
    procs = [_python(DISTRIBUTED, str(i), port, decomposition, "eulerian", background=True) for i in range(2)]
    outs = []
    for p in procs:
        stdout, stderr = p.communicate(timeout=600)
        outs.append(_result(p.returncode, stdout, stderr))
    return outs


@pytest.mark.slow
def test_two_processes_with_the_spatial_decomposition_give_the_one_device_numbers(two_devices):
    """The spatial decomposition across two processes (jax.distributed, one CPU device each):
    the halo ppermute crosses the processes; both end with the whole one-device state in the
    original particle order."""
    for out in _distributed("spatial"):
        assert out["devices"] == 2 and out["decomposition"]["kind"] == "spatial"
        _assert_same(two_devices["one"], out)


@pytest.mark.slow
def test_mlsph_run_distributed_on_two_processes_gives_the_one_process_numbers(tmp_path):
    """`mlsph run --coordinator --num-processes --process-id` (the CLI's jax.distributed launch,
    docs/performance.md "Launch"): two processes on localhost, one CPU device each, the same
    command with run.devices=0; process 0 writes the outputs, whose metrics and conservation
    equal a one-process run's to round-off (the sharded partitioner may sum in another order)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "JAX_PLATFORMS": "cpu",
           "XLA_FLAGS": f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count=1".strip()}
    common = [sys.executable, "-m", "mlsph_jax.cli", "run", "taylor_green_2d", "--quiet",
              "--set", "case.n=8", "time.t_end=0.05", "output.snapshots=1", "output.plots=false"]
    port = str(_free_port())
    procs = [subprocess.Popen([*common, "run.devices=0", "--out", str(tmp_path / "two"), "--coordinator",
                               f"127.0.0.1:{port}", "--num-processes", "2", "--process-id", str(k)],
                              env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for k in range(2)]
    for p in procs:
        _, err = p.communicate(timeout=600)
        assert p.returncode == 0, err[-3000:]
    one = subprocess.run([*common, "--out", str(tmp_path / "one")], env=env, capture_output=True, text=True,
                         timeout=600)
    assert one.returncode == 0, one.stderr[-3000:]
    a = json.loads((tmp_path / "one" / "summary.json").read_text())
    b = json.loads((tmp_path / "two" / "summary.json").read_text())
    assert (a["devices"], b["devices"]) == (1, 2) and a["n_steps"] == b["n_steps"] > 1
    for group in ("metrics", "conservation"):
        for k, v in a[group].items():
            assert b[group][k] == pytest.approx(v, rel=1e-12, abs=1e-13), (group, k)


def test_mlsph_run_distributed_options_are_checked_first(monkeypatch, capsys, tmp_path):
    """The launch options come together and are checked before JAX is initialised (exit 2, naming
    the option, the value and what is allowed; jax.distributed.initialize is never reached)."""
    import jax

    from mlsph_jax.cli import main

    def never(**kwargs):
        raise AssertionError(f"jax.distributed.initialize({kwargs}) reached")

    monkeypatch.setattr(jax.distributed, "initialize", never)
    for opts, words in [(["--coordinator", "127.0.0.1:1234"], ["--coordinator 127.0.0.1:1234 without "
                                                                "--num-processes, --process-id", "allowed: all three"]),
                        (["--coordinator", "nohost", "--num-processes", "2", "--process-id", "0"],
                         ["invalid --coordinator 'nohost'", "HOST:PORT"]),
                        (["--coordinator", "h:1", "--num-processes", "2", "--process-id", "2"],
                         ["invalid --process-id 2", "allowed: 0..1"]),
                        (["--distributed", "--restart", str(tmp_path)], ["invalid --restart", "one process"])]:
        assert main(["run", *opts]) == 2, opts
        err = capsys.readouterr().err
        for w in words:
            assert w in err, (w, err)


# --------------------------------------------------------------------------------------------
# spatial decomposition (run.decomposition = "spatial", mlsph_jax.spatial)
# --------------------------------------------------------------------------------------------

#: The lid-driven cavity (mirror-ghost walls with corner ghosts: the ghosts a shard regenerates
#: must have their parents on it), 10 x 10 fluid particles, on one device and spatially on two.
CAVITY = """
import json
import numpy as np
from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.simulation import run_problem

TEXT = '[case]\\nname = "lid_driven_cavity"\\nn = 10\\n[output]\\nplots = false\\nprogress = false\\n'
out = {}
for name, devices, dec in (("one", 1, "index"), ("spatial", 2, "spatial")):
    cfg = config.loads(TEXT, ["time.t_end=0.02", "time.chunk=8", f"run.devices={devices}",
                              f"run.decomposition={dec}"])
    res = run_problem(build_problem(cfg), cfg, quiet=True)
    out[name] = {k: np.asarray(getattr(res.particles, k)).tolist() for k in ("x", "vol", "q")} | {
        "n_steps": res.summary["n_steps"], "t": res.summary["t_final"], "metrics": res.summary["metrics"],
        "decomposition": res.summary.get("decomposition")}
print("RESULT" + json.dumps(out))
"""


def test_spatial_decomposition_with_mirror_walls_gives_the_one_device_numbers():
    out = _python(CAVITY, devices=2)
    one, sp = out["one"], out["spatial"]
    assert sp["decomposition"]["kind"] == "spatial" and min(sp["decomposition"]["halo"]) > 0
    _assert_same(one, sp)
    for k, v in one["metrics"].items():
        assert sp["metrics"][k] == pytest.approx(v, rel=1e-11, abs=1e-14), k


def _layout_case(text: str, devices: int):
    import numpy as np

    from mlsph_jax.run import setup_run
    from mlsph_jax.spatial import build_layout

    pb = build_problem(config.loads(text))
    nl = setup_run(pb).nl
    idx, mask = np.asarray(nl.idx), np.asarray(nl.mask)
    b = pb.boundary
    ghost, parent = (None, None) if b is None else (np.asarray(b.ghost), np.asarray(b.parent))
    return pb, idx, mask, ghost, parent, build_layout(np.asarray(pb.particles.x), idx, mask, devices, ghost, parent)


@pytest.mark.parametrize("text,devices", [
    ('[case]\nname = "taylor_green_2d"\nn = 16\n', 2),
    ('[case]\nname = "taylor_green_2d"\nn = 16\n', 3),
    ('[case]\nname = "lid_driven_cavity"\nn = 12\n', 2),
    ('[case]\nname = "lid_driven_cavity"\nn = 12\n', 5),
])
def test_spatial_halo_covers_every_stencil(text, devices):
    """Host-side layout of the spatial decomposition (no devices needed): every particle is
    owned by exactly one shard; every neighbour of an owned row and of a first-ring halo row is
    a row of the shard (two stencil hops: the reverse pair's midpoint state is the neighbour's
    fit); every owned ghost's parent is owned by the same shard; and the exchange tables bring
    every halo row the particle it stands for (the ppermute of each shift emulated here)."""
    import numpy as np

    pb, idx, mask, ghost, parent, lay = _layout_case(text, devices)
    n, D = pb.particles.n, devices
    owned = [lay.rows[k, :lay.n_owned[k]] for k in range(D)]
    assert np.array_equal(np.sort(np.concatenate(owned)), np.arange(n))
    assert np.array_equal(lay.rows.reshape(-1)[lay.pos], np.arange(n))
    real = np.ones(n, bool)
    if ghost is not None:
        real[ghost] = False
    sizes = np.bincount(lay.owner[real], minlength=D)
    assert sizes.max() - sizes.min() <= 1              # equal blocks of the curve (ghosts follow parents)
    for k in range(D):
        local = set(lay.rows[k, :lay.n_local[k]].tolist())
        nbr1 = set(idx[owned[k]][mask[owned[k]]].tolist())
        assert nbr1 <= local
        ring1 = np.fromiter(nbr1, int)
        assert set(idx[ring1][mask[ring1]].tolist()) <= local
        if ghost is not None:
            mine = lay.owner[ghost] == k
            assert np.all(lay.owner[parent[mine]] == k)
    # the exchange: recv buffer of shard m = concatenation over shifts s of shard (m - s)'s send rows
    for m in range(D):
        recv = np.concatenate([lay.rows[(m - s) % D][send[(m - s) % D]]
                               for s, send in zip(lay.shifts, lay.send, strict=True)])
        nh = lay.n_local[m] - lay.n_owned[m]
        got = recv[lay.halo_src[m, :nh]]
        assert np.array_equal(got, lay.rows[m, lay.halo_rows[m, :nh]])
        assert np.all(lay.owner[got] != m)


def test_spatial_geometry_rows_keep_their_neighbours():
    """The local geometry of every owned row, its neighbour indices mapped back through the
    layout, is the global row: same neighbours in the same slots (so the reverse slots stay
    valid), same area vectors and fit; padding slots stay masked."""
    import jax
    import numpy as np

    from mlsph_jax.integrate import static_geometry
    from mlsph_jax.run import setup_run
    from mlsph_jax.spatial import SpatialSharding, build_layout

    pb = build_problem(config.loads('[case]\nname = "taylor_green_2d"\nn = 12\n'))
    nl = setup_run(pb).nl
    geom = static_geometry(pb.particles, nl, pb.scheme, pb.domain)
    D = 2
    lay = build_layout(np.asarray(pb.particles.x), np.asarray(nl.idx), np.asarray(nl.mask), D)
    # the host tables only: one device holds both shards' rows here
    sh = SpatialSharding(jax.sharding.Mesh(np.asarray(jax.devices()[:1]), ("particles",)), pb.particles.n, lay, b"")
    g = sh.place_geometry(geom).geom
    L, K = lay.width, nl.idx.shape[1]
    idx, mask = np.asarray(g.idx).reshape(D, L, K), np.asarray(g.mask).reshape(D, L, K)
    for k in range(D):
        r = lay.rows[k, :lay.n_owned[k]]
        assert np.array_equal(mask[k, :r.size], np.asarray(geom.mask)[r])
        back = np.where(mask[k, :r.size], lay.rows[k][np.minimum(idx[k, :r.size], L - 1)], -1)
        assert np.array_equal(back, np.where(np.asarray(geom.mask)[r], np.asarray(geom.idx)[r], -1))
        for f in ("rev", "A", "coeffs", "pair_mask"):
            a = np.asarray(getattr(g, f)).reshape(D, L, *np.shape(getattr(geom, f))[1:])
            assert np.array_equal(a[k, :r.size], np.asarray(getattr(geom, f))[r]), f


def test_spatial_decomposition_refuses_what_it_does_not_support():
    base = '[case]\nname = "taylor_green_2d"\nn = 8\n'
    cases = [
        (base, ["scheme.frame=ale_shift"], r'scheme\.frame=.ale_shift. with run\.decomposition="spatial".*allowed'),
        (base, ["scheme.limiter=mood"], r'scheme\.limiter=.mood. with run\.decomposition="spatial".*allowed'),
        (base, ["time.local_time_stepping=true"], r"time\.local_time_stepping=true with run\.decomposition"),
        ('[case]\nname = "lid_driven_cavity"\nn = 8\n', ["scheme.ghost_shear_dissipation=false"],
         r'scheme\.ghost_shear_dissipation=false with run\.decomposition="spatial".*allowed'),
        ('[case]\nname = "lid_driven_cavity"\nn = 8\n', ["case.walls=boundary_integral"],
         r'invalid boundary-integral walls \(case\.walls="boundary_integral".* with run\.decomposition="spatial".*'
         r'case\.walls="mirror_ghosts"'),
        (base, ["run.devices=64"], r"run\.devices=64: only 1 device\(s\) available"),
    ]
    for text, over, msg in cases:
        cfg = config.loads(text, ["run.decomposition=spatial", *over])
        with pytest.raises(InputError, match=msg):
            run_problem(build_problem(cfg), cfg, quiet=True)
    pb = build_problem(config.loads(base, ["run.decomposition=spatial"]))
    from mlsph_jax.differentiable import make_simulate
    from mlsph_jax.diffrax_path import make_solve

    for build in (make_simulate, make_solve):   # the one-device run paths
        with pytest.raises(InputError, match=r"invalid run\.decomposition='spatial' for the d.*allowed: 'index'"):
            build(pb, n_steps=2)
    with pytest.raises(ConfigError, match=r"run\.decomposition"):
        config.loads(base, ["run.decomposition=slabs"])
    with pytest.raises(InputError, match=r"invalid run\.decomposition='slabs'; allowed: 'index', 'spatial'"):
        Simulation(build_problem(config.loads(base)), decomposition="slabs")


#: Sod's tube (1D; FROZEN transmissive ends) in the Eulerian frame without MOOD: first order to
#: t = 0.02 on one device and spatially on two, then the unlimited quadratic reconstruction,
#: which blows up in the first step: both runs must name the same step and particle.
SOD = """
import json
import numpy as np
from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.errors import SimulationError
from mlsph_jax.simulation import run_problem

TEXT = open(sys.argv[1]).read()
out = {}
for name, devices, dec in (("one", 1, "index"), ("spatial", 2, "spatial")):
    over = ["time.t_end=0.02", "scheme.frame=eulerian", "scheme.limiter=none", f"run.devices={devices}",
            f"run.decomposition={dec}", "output.plots=false", "output.progress=false"]
    cfg = config.loads(TEXT, [*over, "scheme.reconstruction_degree=0"])
    res = run_problem(build_problem(cfg), cfg, quiet=True)
    out[name] = {k: np.asarray(getattr(res.particles, k)).tolist() for k in ("x", "vol", "q", "kind")} | {
        "n_steps": res.summary["n_steps"], "t": res.summary["t_final"]}
    cfg = config.loads(TEXT, over)
    try:
        run_problem(build_problem(cfg), cfg, quiet=True)
    except SimulationError as e:
        out[name]["failure"] = [str(e), e.step, e.particle]
print("RESULT" + json.dumps(out))
"""


THREE_SHARDS = """
import dataclasses, json
import numpy as np
from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.errors import SimulationError
from mlsph_jax.simulation import Simulation
pb = build_problem(config.loads('[case]\\nname = "taylor_green_2d"\\nn = 16\\n', ["time.t_end=0.01"]))
p = pb.particles
graded = dataclasses.replace(pb, particles=p.replace(vol=p.vol.at[0].multiply(0.6), q=p.q.at[0].multiply(0.6)))
out = {}
for dec, dev in (("index", 1), ("spatial", 3)):
    r = Simulation(graded, devices=dev, decomposition=dec, chunk=4).run(None, snapshots=1, progress=False, plots=False)
    out[dec] = [r.summary["n_steps"], r.summary["dt_last"], np.asarray(r.particles.q).tolist(),
                min(r.summary["decomposition"]["halo"]) if dec == "spatial" else 0,
                max(r.summary["decomposition"]["halo"]) if dec == "spatial" else 0]
    try:
        Simulation(pb, devices=dev, decomposition=dec, chunk=4, dt_min=0.5).run(None, snapshots=1, progress=False,
                                                                                plots=False)
    except SimulationError as e:
        out[dec + "_failure"] = [e.step, e.particle]
print("RESULT" + json.dumps(out))
"""


def test_spatial_shards_with_unequal_halos_and_a_tie_for_the_limiting_particle():
    """Three shards of a 16 x 16 Taylor-Green vortex (unequal halos: the shorter ones padded).
    With particle 0 graded (0.6 V, same density) the spatial run takes the one-device steps and
    ends in its state (a padding row that received another particle's q once shortened the step:
    29 steps instead of 8); a run stopped by time.dt_min names the particle a one-device run
    names, the first of the tied CFL-limiting particles (not each shard's own first)."""
    import numpy as np

    out = _python(THREE_SHARDS, devices=3)
    one, sp = out["index"], out["spatial"]
    assert sp[3] < sp[4]                                   # the halos differ: some shard is padded
    # the same steps; the end time to round-off (the shards' programs have other shapes, so the
    # compiler may contract the CFL reduction's multiply-adds differently: 1 ulp seen)
    assert sp[0] == one[0] and one[0] > 1 and sp[1] == pytest.approx(one[1], rel=1e-14, abs=0)
    q1, q3 = np.asarray(one[2]), np.asarray(sp[2])
    np.testing.assert_allclose(q3, q1, rtol=0, atol=1e-13 * np.abs(q1).max())
    assert out["spatial_failure"] == out["index_failure"] and out["index_failure"][1] >= 0


def test_spatial_decomposition_with_frozen_ends_and_a_failure_in_1d():
    """1D, FROZEN particles beyond both ends: the spatial run ends with the one-device state,
    and a run that fails reports the same step and the same (original) particle index."""
    out = _python("import sys\n" + SOD, str(ROOT / "configs" / "sod_ideal_gas.toml"), devices=2)
    one, sp = out["one"], out["spatial"]
    assert 3 in one["kind"]   # Kind.FROZEN
    _assert_same(one, sp)
    assert one["failure"][1:] == sp["failure"][1:] and one["failure"][2] >= 0
    assert one["failure"][0] == sp["failure"][0]
