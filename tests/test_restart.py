"""Interrupts, restarts and output folders (issue 16): a run stopped by Ctrl-C/SIGTERM, a failure or
``time.max_steps`` writes its last good state and continues with ``restart`` bit for bit as if it
had never stopped; an output folder holding a run is never silently mixed with another.

The default-suite tests use the 40-particle Lagrangian Sod tube (moving particles, first order);
the MOOD (R1, quadratic) and ``ale_shift`` Taylor-Green restarts and the subprocess SIGINT test
are in the slow suite (their compilations take tens of seconds on 2 cores).
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.checkpoint import CHECKPOINT, read_checkpoint
from mlsph_jax.cli import DEFAULT_CONFIG, main
from mlsph_jax.errors import InputError, RunInterrupted, SimulationError
from mlsph_jax.simulation import Simulation, restart, run_problem

ROOT = Path(__file__).resolve().parents[1]
SMALL = ["case.n=40", "time.t_end=0.05", "output.snapshots=2", "time.chunk=2", "output.progress=false"]


def sod(*sets):
    cfg = config.loads(DEFAULT_CONFIG, [*SMALL, *sets])
    return cfg, build_problem(cfg)


def assert_same_state(a, b):
    for k in ("x", "vol", "q", "kind", "ppd"):
        x, y = np.asarray(getattr(a, k)), np.asarray(getattr(b, k))
        assert x.dtype == y.dtype and np.array_equal(x, y), f"{k} differs by {np.abs(x - y).max()}"


TRIGGER = {"t": None, "signal": signal.SIGINT}


def _diagnostics(p, t, params):
    """Recorded at every output time; raises TRIGGER["signal"] at the output time TRIGGER["t"]."""
    if TRIGGER["t"] is not None and t >= TRIGGER["t"]:
        TRIGGER["t"] = None
        signal.raise_signal(TRIGGER["signal"])
    return {"mass": float(np.asarray(p.q[:, 0]).sum())}


@pytest.fixture(scope="module")
def sim():
    """One driver for the in-process runs: a stopped run and its restart reuse the compiled
    chunk (``max_steps`` is an argument of the chunk, not a constant), as a user continuing
    with the same Simulation object does."""
    cfg, pb = sod()
    return Simulation(dataclasses.replace(pb, diagnostics=_diagnostics), chunk=2)


@pytest.fixture(scope="module")
def full(sim, tmp_path_factory):
    """The uninterrupted run."""
    return sim.run(tmp_path_factory.mktemp("full"), snapshots=2, progress=False)


def snapshot_bytes(out: Path) -> dict:
    with h5py.File(out / "fields.h5") as f:
        return {name: {k: g[k][()].tobytes() for k in g} for name, g in f["snapshots"].items()}


def test_max_steps_is_exact_and_a_failed_run_restarts_bitwise(sim, full, tmp_path):
    sim.max_steps = 7       # 7 = three chunks of 2 and one step of the fourth
    try:
        with pytest.raises(SimulationError, match="time.max_steps=7"):
            sim.run(tmp_path, snapshots=2, progress=False)
    finally:
        sim.max_steps = 1_000_000
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["n_steps"] == 7 and s["status"].startswith("failed: maximum number of steps")
    ck = read_checkpoint(tmp_path)
    assert int(ck.step) == 7 and 0 < float(ck.t) < 0.05
    before = snapshot_bytes(tmp_path)
    res = sim.run(tmp_path, snapshots=2, progress=False, restart=True)
    assert_same_state(res.particles, full.particles)
    assert res.summary["n_steps"] == full.summary["n_steps"] and res.summary["t_final"] == full.summary["t_final"]
    assert res.summary["status"] == "ok" and res.summary["restarted_from"]["step"] == 7
    assert res.summary["conservation"] == full.summary["conservation"]
    assert res.summary["timeseries"] == full.summary["timeseries"]
    after = snapshot_bytes(tmp_path)
    assert all(after[k] == v for k, v in before.items())    # the snapshots it resumed from are untouched
    assert len(after) == 1 + 2 + 1    # initial, 2 output times and the state at the stop


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_writes_the_last_good_state_and_restart_is_bitwise(sim, full, tmp_path, signum):
    """A real SIGINT/SIGTERM (raised at the first output time): the chunk finishes, the outputs
    are written, RunInterrupted is raised, the handlers are restored; the restart matches."""
    handlers = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    TRIGGER.update(t=0.02, signal=signum)
    with pytest.raises(RunInterrupted, match=signal.Signals(signum).name) as err:
        sim.run(tmp_path, snapshots=2, progress=False)
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == handlers
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["status"] == "interrupted" and s["t_final"] == pytest.approx(0.025)
    assert err.value.result.summary["status"] == "interrupted" and err.value.signal == signum
    assert {"timeseries.csv", "profiles.png", CHECKPOINT, "fields.xmf"} <= set(os.listdir(tmp_path))
    assert (tmp_path / "timeseries.csv").read_text().count("\n") == 3    # header, t = 0, t = 0.025
    res = sim.run(tmp_path, snapshots=2, progress=False, restart=True)
    assert_same_state(res.particles, full.particles)
    assert res.summary["status"] == "ok" and res.summary["timeseries"] == full.summary["timeseries"]


def test_a_finer_series_restarts_bitwise_from_between_two_outputs(sim, tmp_path):
    """``output.series_interval`` (issue 17): four samples per output interval.  A SIGTERM raised at
    the sample t = 0.0125, between two outputs, stops the run there: the checkpoint holds the
    samples so far and the index of the next sample (not of the next output); the restart records
    the rest of the series and reaches the final state bit for bit as the uninterrupted run, and
    fields.h5 holds the outputs and the state at the stop, no sample.  A restart with another
    series_interval (other step targets, other numbers) is refused, naming it."""
    full = sim.run(tmp_path / "full", snapshots=2, progress=False, series_interval=0.00625)
    assert full.summary["timeseries"]["t"] == [0.0, *np.linspace(0.0, 0.05, 9)[1:]]
    out = tmp_path / "run"
    TRIGGER.update(t=0.0125, signal=signal.SIGTERM)
    with pytest.raises(RunInterrupted):
        sim.run(out, snapshots=2, progress=False, series_interval=0.00625)
    ck = read_checkpoint(out)
    assert float(ck.t) == 0.0125 and ck.next_target == 2 and ck.status == "interrupted"
    assert [row["t"] for row in ck.series] == [0.0, 0.00625, 0.0125]
    with pytest.raises(InputError, match=r"series_per_output: 4 in the run, '<absent>' now"):
        sim.run(out, snapshots=2, progress=False, restart=True)
    with pytest.raises(InputError, match=r"series_per_output: 4 in the run, 2 now"):
        sim.run(out, snapshots=2, progress=False, restart=True, series_interval=0.0125)
    res = sim.run(out, snapshots=2, progress=False, restart=True, series_interval=0.00625)
    assert_same_state(res.particles, full.particles)
    assert res.summary["timeseries"] == full.summary["timeseries"] and res.summary["n_steps"] == full.summary["n_steps"]
    assert (out / "timeseries.csv").read_text() == (full.out_dir / "timeseries.csv").read_text()
    with h5py.File(out / "fields.h5") as f:
        assert [float(g.attrs["t"]) for _, g in sorted(f["snapshots"].items())] == [0.0, 0.0125, 0.025, 0.05]


def test_cli_interrupted_run_exits_130_with_one_line(monkeypatch, capsys, tmp_path):
    from mlsph_jax import simulation

    def interrupted(*a, **k):
        raise RunInterrupted("interrupted by SIGINT at t = 0.1 (step 9); outputs in o/, continue with: "
                             "mlsph run --restart o", signal=signal.SIGINT)

    monkeypatch.setattr(simulation, "run_problem", interrupted)
    assert main(["run", "--out", str(tmp_path / "o"), "--quiet"]) == 130
    err = capsys.readouterr().err
    assert err == "mlsph: interrupted by SIGINT at t = 0.1 (step 9); outputs in o/, continue with: " \
                  "mlsph run --restart o\n"


def test_output_folder_holding_a_run_is_refused_unless_overwrite(sim, full, tmp_path):
    out = tmp_path / "o"
    shutil.copytree(full.out_dir, out)
    (out / "decay.png").write_bytes(b"old plot of another case")
    (out / "notes.txt").write_text("mine")
    cfg, pb = sod()
    with pytest.raises(InputError, match=r"already holds a run \(summary.json, fields.h5, checkpoint.h5\).*"
                                         "--overwrite.*--restart"):
        run_problem(pb, cfg, out_dir=out, quiet=True)
    assert main(["run", "--out", str(out), "--quiet", "--set", *SMALL]) == 2
    assert main(["run", "--out", str(out), "--quiet", "--overwrite", "--restart", str(out)]) == 2
    with pytest.raises(InputError, match="overwrite=True with restart=True"):
        run_problem(pb, cfg, out_dir=out, quiet=True, overwrite=True, restart=True)
    sim.run(out, snapshots=2, progress=False, overwrite=True)
    assert not (out / "decay.png").exists() and (out / "notes.txt").read_text() == "mine"
    assert (out / "profiles.png").exists() and json.loads((out / "summary.json").read_text())["status"] == "ok"


def _copy_stopped(sim, full, tmp_path) -> Path:
    """A copy of a run stopped at max_steps (made once per test module)."""
    cache = Path(str(full.out_dir) + "_stopped")
    if not cache.exists():
        sim.max_steps = 4
        try:
            with pytest.raises(SimulationError):
                sim.run(cache, snapshots=2, progress=False)
        finally:
            sim.max_steps = 1_000_000
    out = tmp_path / "stopped"
    shutil.copytree(cache, out)
    return out


def test_restart_refusals_name_what_is_wrong(sim, full, tmp_path):
    with pytest.raises(InputError, match="no such folder"):
        restart(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="holds no checkpoint.h5"):
        restart(tmp_path / "empty")
    with pytest.raises(InputError, match="the run is complete"):
        restart(full.out_dir)
    out = _copy_stopped(sim, full, tmp_path)
    cfg, pb = sod("eos.gamma=1.3", "time.max_steps=100")
    with pytest.raises(InputError, match=r"eos.gamma: 1.4 in the run, 1.3 now"):
        run_problem(pb, cfg, out_dir=out, quiet=True, restart=True)
    cfg, pb = sod("case.n=41")
    with pytest.raises(InputError, match=r"case.n: 40 in the run, 41 now"):
        run_problem(pb, cfg, out_dir=out, quiet=True, restart=True)
    tg = config.load(ROOT / "configs/taylor_green_2d.toml", ["case.n=12"])
    with pytest.raises(InputError, match="run of case 'riemann_1d', not 'taylor_green_2d'"):
        run_problem(build_problem(tg), tg, out_dir=out, quiet=True, restart=True)
    assert main(["run", "--restart", str(tmp_path / "missing")]) == 2
    # a truncated fields.h5 (a kill while the file was copied, a full disk)
    data = (out / "fields.h5").read_bytes()
    (out / "fields.h5").write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="fields.h5.*(unreadable|truncated)"):
        restart(out, ["time.max_steps=100"])
    assert (out / "fields.h5").stat().st_size == len(data) // 2   # nothing rewritten


def test_a_steady_stopped_run_continues_with_a_tighter_tolerance(full, tmp_path):
    """A run stopped by its steady-state test (here a tolerance so loose that the first output
    stops it) continues from that checkpoint with a smaller tolerance, bit for bit as the run
    that never stopped (the steps do not depend on the tolerance); the same or a looser
    tolerance is refused as complete, naming the residual to go below."""
    _, pb = sod()
    loose = Simulation(dataclasses.replace(pb, diagnostics=_diagnostics, steady_tol=1e6), chunk=2)
    stopped = loose.run(tmp_path, snapshots=2, progress=False)
    st = stopped.summary["steady_state"]
    assert st["converged"] and stopped.summary["t_final"] < 0.05, st
    with pytest.raises(InputError, match=r"the run is complete .*case\.steady_tol < .*its residual at the stop"):
        loose.run(tmp_path, snapshots=2, progress=False, restart=True)
    tight = Simulation(dataclasses.replace(pb, diagnostics=_diagnostics, steady_tol=1e-30), chunk=2)
    res = tight.run(tmp_path, snapshots=2, progress=False, restart=True)
    assert_same_state(res.particles, full.particles)
    assert res.summary["n_steps"] == full.summary["n_steps"] and res.summary["t_final"] == full.summary["t_final"]
    ts = res.summary["timeseries"]       # plus the residual column of a run with a steady test
    assert {k: ts[k] for k in full.summary["timeseries"]} == full.summary["timeseries"]
    assert not res.summary["steady_state"]["converged"]


def test_a_cavity_goes_on_to_a_tighter_steady_tolerance_and_keeps_it(tmp_path):
    """The coarse cavity (12 x 12) stopped by case.steady_tol = 2e-2 continues through the command
    line with 1e-2: config.toml then holds 1e-2 (a later plain --restart keeps it) and the run
    stops later, its residual column continued; a larger tolerance or 0 is refused naming the
    key (either could have stopped the run earlier)."""
    over = ["case.n=12", "time.t_end=10", "output.snapshots=20", "time.cfl=0.6", "output.progress=false",
            "output.plots=false"]
    cfg = config.load(ROOT / "configs/lid_driven_cavity.toml", [*over, "case.steady_tol=2e-2"])
    out = tmp_path / "cav"
    first = run_problem(build_problem(cfg), cfg, out_dir=out, quiet=True).summary
    assert first["steady_state"]["converged"] and first["t_final"] < 10.0
    for bad in ("0.05", "0"):
        with pytest.raises(InputError, match=rf"case.steady_tol={float(bad):g}, the run's 0.02; allowed: a smaller"):
            restart(out, [f"case.steady_tol={bad}"])
    res = restart(out, ["case.steady_tol=1e-2"]).summary
    assert config.load(out / "config.toml")["case"]["steady_tol"] == 1e-2
    st = res["steady_state"]
    assert res["t_final"] > first["t_final"] and st["tolerance"] == 1e-2
    rate = res["timeseries"]["velocity_change_rate"]
    assert len(rate) == len(res["timeseries"]["t"]) and rate[:len(first["timeseries"]["t"])] == \
        first["timeseries"]["velocity_change_rate"]
    assert all(r >= 1e-2 for r in rate[1:-1]) and (rate[-1] < 1e-2) == st["converged"]


def test_the_steady_residual_series_restarts_bitwise(tmp_path):
    """With a steady-state test the run records its residual as the series column
    ``velocity_change_rate`` (0 at t = 0, then the value compared with the tolerance at every
    output, nan at samples between outputs); its history is in the checkpoint, so a run stopped
    by time.max_steps and restarted has the uninterrupted run's series, value for value (a
    residual kept by a case's own diagnostics started again from zero after a restart)."""
    _, pb = sod()
    pb = dataclasses.replace(pb, diagnostics=_diagnostics, steady_tol=1e-30)
    kw = {"snapshots": 2, "progress": False, "series_interval": 0.0125}
    full = Simulation(pb, chunk=2).run(tmp_path / "full", **kw)
    rate = full.summary["timeseries"]["velocity_change_rate"]
    assert rate[0] == 0.0 and all(r > 0 for r in rate[1:] if r is not None and np.isfinite(r)), rate
    assert sum(r is None or not np.isfinite(r) for r in rate) > 0     # samples between outputs
    stopped = Simulation(pb, chunk=2)
    stopped.max_steps = 7
    with pytest.raises(SimulationError, match="time.max_steps=7"):
        stopped.run(tmp_path / "part", **kw)
    stopped.max_steps = 1_000_000
    res = stopped.run(tmp_path / "part", restart=True, **kw)
    np.testing.assert_array_equal(np.asarray(res.summary["timeseries"]["velocity_change_rate"], float),
                                  np.asarray(rate, float))
    assert_same_state(res.particles, full.particles)


def test_a_checkpoint_from_before_series_interval_restarts(sim, full, tmp_path):
    """A run checkpointed before ``output.series_interval`` existed (its saved config lacks the key)
    restarts when the key is at its default, 0 (the same targets), and is refused with another
    value, naming the key."""
    out = _copy_stopped(sim, full, tmp_path)
    with h5py.File(out / CHECKPOINT, "r+") as f:
        meta = json.loads(f.attrs["meta"])
        del meta["config"]["output"]["series_interval"]
        f.attrs["meta"] = json.dumps(meta)
    cfg, pb = sod("output.series_interval=0.0125")
    with pytest.raises(InputError, match=r"output.series_interval: 0.0 in the run, 0.0125 now"):
        run_problem(pb, cfg, out_dir=out, quiet=True, restart=True)
    cfg, pb = sod()
    res = run_problem(pb, cfg, out_dir=out, quiet=True, restart=True)
    assert_same_state(res.particles, full.particles)


def test_cylinder_configs_from_before_the_heat_and_graded_keys_still_match():
    """A cylinder run saved before ``case.prandtl`` / ``case.wall_temperature`` (decision 102), the
    layout, body, trigger and far-field keys existed (the first runs, 2026-11-25) matches today's
    config at the values of those runs (so it restarts), a changed value is named, and the
    cylinder's added keys do not leak into other cases' comparisons (``case.layout`` is also a
    Taylor-Green key)."""
    from mlsph_jax.checkpoint import compare_settings, restart_added_keys

    cyl = config.load(ROOT / "configs/cylinder.toml", [])
    old = json.loads(json.dumps(cyl, default=str))
    added = restart_added_keys("cylinder")
    # the first runs' case keys: every key added since must be in the table (a key added without
    # an entry would make every earlier cylinder run refuse --restart)
    first = {"mach", "n_theta", "name", "r_far", "radius", "re", "steady_tol"}
    old["case"] = {k: v for k, v in old["case"].items() if k in first}
    assert compare_settings(old, cyl, where="", added=added) == []
    hot = config.load(ROOT / "configs/cylinder.toml", ["case.prandtl=0.72", "case.wall_temperature=1.1"])
    assert compare_settings(old, hot, where="", added=added) == [
        "case.prandtl: 0.0 in the run, 0.72 now", "case.wall_temperature: 0.0 in the run, 1.1 now"]
    assert compare_settings(old, cyl, where="", added={}) != []          # the table is what makes it match
    # a case's added keys apply to that case only: the Taylor-Green config also has case.layout
    tg = config.load(ROOT / "configs/taylor_green_2d.toml", [])
    old_tg = json.loads(json.dumps(tg, default=str))
    del old_tg["case"]["layout"]
    assert compare_settings(old_tg, tg, where="", added=restart_added_keys("taylor_green_2d")) == [
        f"case.layout: '<absent>' in the run, {tg['case']['layout']!r} now"]
    assert "case.layout" in added and restart_added_keys("riemann_1d") == {"output.series_interval": 0.0}


# --------------------------------------------------------------------------------------------
# slow: MOOD, ale_shift and a real SIGINT to the command line
# --------------------------------------------------------------------------------------------

def _stop_and_restart(cfg_path, sets, stop_at, tmp_path):
    cfg = config.load(cfg_path, sets)
    full = run_problem(build_problem(cfg), cfg, out_dir=tmp_path / "full", quiet=True)
    cfg2 = config.load(cfg_path, [*sets, f"time.max_steps={stop_at}"])
    with pytest.raises(SimulationError):
        run_problem(build_problem(cfg2), cfg2, out_dir=tmp_path / "part", quiet=True)
    return full, tmp_path / "part"


@pytest.mark.slow
def test_mood_r1_restart_is_bitwise(tmp_path):
    full, part = _stop_and_restart(ROOT / "configs/riemann_r1_tait.toml",
                                   ["case.n=60", "output.snapshots=4", "time.chunk=5"], 13, tmp_path)
    assert full.summary["mood"]["flagged_fraction_max"] > 0     # MOOD did act
    res = restart(part, ["time.max_steps=1000000"], quiet=True)
    assert_same_state(res.particles, full.particles)
    assert res.summary["mood"] == full.summary["mood"]


@pytest.mark.slow
def test_ale_shift_taylor_green_cli_restart_is_bitwise(tmp_path):
    sets = ["case.n=10", "output.snapshots=2", "time.chunk=4", "time.t_end=0.05",
            "scheme.reconstruction_degree=1"]
    full, part = _stop_and_restart(ROOT / "configs/taylor_green_2d_mlsph.toml", sets, 3, tmp_path)
    assert main(["run", "--restart", str(part), "--quiet", "--set", "time.max_steps=1000000"]) == 0
    assert_same_state(read_checkpoint(part).particles, full.particles)
    assert (part / "timeseries.csv").read_text() == (full.out_dir / "timeseries.csv").read_text()


@pytest.mark.slow
def test_sigint_to_the_command_line(tmp_path):
    out = tmp_path / "run"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    args = [sys.executable, "-m", "mlsph_jax.cli", "run", "--out", str(out), "--quiet", "--set", "case.n=40",
            "time.t_end=5.0", "output.snapshots=500", "time.chunk=2"]
    p = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        time.sleep(0.2)
        try:
            with h5py.File(out / "fields.h5", "r") as f:
                if len(f["snapshots"]) >= 3:
                    break
        except (OSError, KeyError):
            pass
    p.send_signal(signal.SIGINT)
    stdout, stderr = p.communicate(timeout=120)
    assert p.returncode == 130, stderr
    assert stderr.count("\n") == 1 and "interrupted by SIGINT" in stderr and "Traceback" not in stderr
    s = json.loads((out / "summary.json").read_text())
    assert s["status"] == "interrupted" and 0 < s["t_final"] < 5.0
    assert read_checkpoint(out).status == "interrupted"


@pytest.mark.slow
def test_sigterm_between_outputs_then_cli_restart(tmp_path, capsys, monkeypatch):
    """SIGTERM at the end of a chunk in the middle of an output interval: the carry after that
    chunk is the checkpoint; `mlsph run --restart DIR` continues it exactly."""
    from mlsph_jax import simulation

    cfg, pb = sod()
    (tmp_path / "config.toml").write_text(config.dumps(cfg))
    full = run_problem(pb, cfg, out_dir=tmp_path / "full", quiet=True)
    real, sent = simulation._progress.update, []

    def update(self, t, step):          # called after every chunk
        if not sent and abs(t / 0.025 - round(t / 0.025)) > 1e-6:   # between two output times
            sent.append(step)
            signal.raise_signal(signal.SIGTERM)
        real(self, t, step)

    out = tmp_path / "run"
    monkeypatch.setattr(simulation._progress, "update", update)
    rc = main(["run", str(tmp_path / "config.toml"), "--out", str(out), "--quiet"])
    monkeypatch.undo()
    err = capsys.readouterr().err
    assert rc == 130 and err.count("\n") == 1 and "SIGTERM" in err and "--restart" in err
    ck = read_checkpoint(out)
    assert int(ck.step) == sent[0] and ck.status == "interrupted"
    assert main(["run", "--restart", str(out), "--quiet"]) == 0
    assert_same_state(read_checkpoint(out).particles, full.particles)
    with h5py.File(out / "fields.h5") as f:   # initial, interrupted and 2 output times
        assert [int(g.attrs["step"]) for _, g in sorted(f["snapshots"].items())][:2] == [0, sent[0]]
        assert len(f["snapshots"]) == 4
