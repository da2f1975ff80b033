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

def run(devices, capacity=None, precision="float64"):
    cfg = config.loads(TEXT, [*OVER, f"run.devices={devices}", f"run.precision={precision}"])
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
        "metrics": res.summary["metrics"]}
"""

TWO_DEVICES = CASE + """
out = {}
runs = (("one", 1, None, "float64"), ("two", 2, None, "float64"))
if sys.argv[-1] != "eulerian":
    runs += (("two_overflow", 2, 3, "float64"), ("one_f32", 1, None, "float32"), ("two_f32", 2, None, "float32"))
for name, devices, cap, precision in runs:
    res, log = run(devices, cap, precision)
    out[name] = fields(res) | {"regrowths": [e["causes"] for e in log]}
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
res, _ = run(2)
print("RESULT" + json.dumps(fields(res)))
"""


def _python(code: str, *args: str, devices: int = 1, background: bool = False):
    env = {**os.environ, "PYTHONPATH": str(ROOT), "JAX_PLATFORMS": "cpu",
           "XLA_FLAGS": f"--xla_force_host_platform_device_count={devices}"}
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
    port = str(_free_port())
    procs = [_python(DISTRIBUTED, str(i), port, "eulerian", background=True) for i in range(2)]
    outs = []
    for p in procs:
        stdout, stderr = p.communicate(timeout=600)
        outs.append(_result(p.returncode, stdout, stderr))
    for out in outs:
        assert out["devices"] == 2
        _assert_same(two_devices["one"], out)
