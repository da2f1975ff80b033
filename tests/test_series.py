"""The time series between outputs (``output.series_interval``, issue 17): the diagnostics are
sampled at uniform times finer than the snapshots, without writing the fields.

Every sample time is a step target like an output time, so a run with ``snapshots = N`` and
``series_interval = t_end / (N m)`` takes exactly the steps of a run with ``N m`` snapshots and
records the same series bit for bit; absent (0), the series is recorded at the output times as
before.  The restart of a run with a finer series is in tests/test_restart.py.
"""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from mlsph_jax import config as config_mod
from mlsph_jax.cases import build_problem
from mlsph_jax.cli import DEFAULT_CONFIG
from mlsph_jax.errors import ConfigError, InputError
from mlsph_jax.simulation import make_simulation
from mlsph_jax.testing import CONFIG_DIR

#: the shipped Re = 100 shedding config (cubic reconstruction, trigger on) on the reduced layout of
#: its fingerprint, to t = 0.4 (about 45 steps)
CYL = ("case.n_theta=32", "case.r_far=4.0", "time.t_end=0.4", "output.snapshots=2", "output.series_interval=0")


def n_snapshots(out) -> int:
    with h5py.File(out / "fields.h5") as f:
        return len(f["snapshots"])


@pytest.fixture(scope="module")
def cylinder(tmp_path_factory):
    """One driver (one compilation) for the three runs of the reduced Re = 100 cylinder: 8 outputs
    (the former way of sampling C_L finely), 2 outputs with the series every 0.05 (the same
    sample times), and 2 outputs with no series_interval."""
    cfg = config_mod.load(CONFIG_DIR / "cylinder_re100.toml", list(CYL))
    sim = make_simulation(build_problem(cfg), cfg)
    base = tmp_path_factory.mktemp("series")
    quiet = {"progress": False, "plots": False, "degree_fallback_warn": 0.05}   # (the reduced layout's 3.1 %)
    runs = {"outputs": sim.run(base / "outputs", snapshots=8, **quiet),
            "series": sim.run(base / "series", snapshots=2, series_interval=0.05, **quiet),
            "absent": sim.run(base / "absent", snapshots=2, **quiet)}
    return runs


def test_series_between_outputs_is_the_run_with_outputs_at_those_times(cylinder):
    """Samples at the 8 uniform times k 0.05 (plus t = 0) of a 2-output run: the step count, the
    final state and every recorded C_D, C_L, C_p are bit for bit those of the 8-output run,
    while fields.h5 holds 3 snapshots instead of 9 (the point of the key: configs/cylinder_re100.toml
    samples every 0.25 with 30 outputs instead of 600).  The sample times are arguments of the
    compiled chunk: the second run compiles nothing."""
    a, b = cylinder["outputs"], cylinder["series"]
    sa, sb = a.summary, b.summary
    assert sb["status"] == "ok" and sb["n_steps"] == sa["n_steps"] and sb["t_final"] == sa["t_final"] == 0.4
    assert sb["timeseries"] == sa["timeseries"]                        # every column, bit for bit
    assert sb["timeseries"]["t"] == [0.0, *np.linspace(0.0, 0.4, 9)[1:]]
    assert abs(np.ptp(sb["timeseries"]["cl"])) > 1e-3      # the trigger's lift changes: not a constant
    for k in ("x", "vol", "q", "kind", "ppd"):
        assert np.array_equal(np.asarray(getattr(a.particles, k)), np.asarray(getattr(b.particles, k)))
    assert sb["metrics"] == sa["metrics"] and sb["conservation"] == sa["conservation"]
    assert sa["compile_time_s"] > 0 and sb["compile_time_s"] == 0.0    # the sample times need no new program
    assert n_snapshots(b.out_dir) == 3 and n_snapshots(a.out_dir) == 9
    rows = (b.out_dir / "timeseries.csv").read_text().splitlines()
    assert len(rows) == 1 + 9 and rows[0].startswith("t,")


def test_without_series_interval_the_series_is_at_the_output_times(cylinder):
    """Absent (0): the samples are t = 0 and the output times, as before the key; the run then
    takes other steps than the finer one (fewer targets to clip the step at), so its numbers are
    not those of the 8-output run (the fingerprints recorded before the key hold them)."""
    s = cylinder["absent"].summary
    assert s["timeseries"]["t"] == [0.0, 0.2, 0.4]
    assert n_snapshots(cylinder["absent"].out_dir) == 3
    assert s["n_steps"] != cylinder["series"].summary["n_steps"] or \
        s["timeseries"]["cl"][-1] != cylinder["series"].summary["timeseries"]["cl"][-1]


def _sod(*sets):
    cfg = config_mod.loads(DEFAULT_CONFIG, ["case.n=40", "time.t_end=0.05", "output.snapshots=2", *sets])
    return cfg, build_problem(cfg)


def test_interval_equal_to_the_output_interval_is_the_default():
    """series_interval = t_end / snapshots samples at the output times: the same driver settings
    and the same targets as 0 (a restart still compares the config, so changing the key's value
    between a run and its restart is refused like any other key)."""
    cfg0, pb = _sod()
    cfg1, _ = _sod("output.series_interval=0.025")
    assert cfg0["output"]["series_interval"] == 0.0 and cfg1["output"]["series_interval"] == 0.025
    sim = make_simulation(pb, cfg0)
    assert sim._settings(2, 1) == sim._settings(2)
    assert "series_per_output" in sim._settings(2, 4)


@pytest.mark.parametrize("value, words", [
    ("-0.01", ["output.series_interval=-0.01", ">= 0.0"]),
    ("inf", ["output.series_interval", "finite"]),
    ("nan", ["output.series_interval", "finite"]),
    ("0.03", ["output.series_interval=0.03", "whole fraction", "0.025", "divided by a whole number"]),
    ("0.01", ["output.series_interval=0.01", "whole fraction", "0.025", "output.snapshots"]),
])
def test_bad_series_interval_names_the_key_the_value_and_what_is_allowed(value, words):
    with pytest.raises(ConfigError) as err:
        _sod(f"output.series_interval={value}")
    assert all(w in str(err.value) for w in words), str(err.value)


def test_series_interval_errors_offer_values_that_work():
    """The suggested intervals (printed at full precision) validate, the suggested output counts
    validate, and a sample count beyond the cap is refused before any run (decision 70)."""
    from mlsph_jax.config.tables import MAX_SERIES_SAMPLES

    with pytest.raises(ConfigError) as err:         # output interval 0.05 / 3: 0.025 does not divide it
        _sod("output.snapshots=3", "output.series_interval=0.025")
    msg = str(err.value)
    half = repr(0.05 / 3 / 2)
    assert half in msg and "divisor of time.t_end / output.series_interval = 2" in msg, msg
    _sod("output.snapshots=3", f"output.series_interval={half}")
    _sod("output.snapshots=1", "output.series_interval=0.025")
    tiny = 0.05 / (2 * MAX_SERIES_SAMPLES)
    with pytest.raises(ConfigError, match=rf"output.series_interval=.*{2 * MAX_SERIES_SAMPLES} samples"):
        _sod(f"output.series_interval={tiny!r}")


def test_bad_series_interval_of_the_python_driver():
    """Simulation.run checks the argument itself (an InputError naming it) before running."""
    cfg, pb = _sod()
    sim = make_simulation(pb, cfg)
    for value in (-1.0, float("nan"), float("inf"), 0.03, 0.01, True):
        with pytest.raises(InputError, match=r"series_interval=.*output\.series_interval.*allowed: 0"):
            sim.run(None, snapshots=2, progress=False, plots=False, series_interval=value)
