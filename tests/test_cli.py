"""The `mlsph` command line: exit codes, clear errors, and the output contract."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from mlsph_jax import config
from mlsph_jax.cli import main

ROOT = Path(__file__).resolve().parents[1]


def test_validate_ok(capsys):
    assert main(["validate", str(ROOT / "configs/sod_ideal_gas.toml")]) == 0
    assert "ok" in capsys.readouterr().out


@pytest.mark.parametrize("override, needle", [
    ("scheme.reconstruction_degree=7", "scheme.reconstruction_degree"),
    ("scheme.metod=sph_ale", "did you mean"),
    ("case.n=1.5", "case.n"),
    ("eos.gamma=abc", "eos.gamma"),
])
def test_bad_overrides_exit_2_and_name_the_key(override, needle, capsys):
    rc = main(["validate", str(ROOT / "configs/sod_ideal_gas.toml"), "--set", override])
    assert rc == 2
    assert needle in capsys.readouterr().err


def test_missing_config_file(capsys):
    assert main(["run", "does/not/exist.toml"]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_cases_lists_cases_and_builtin_configs_from_any_folder(capsys, monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    assert main(["cases"]) == 0
    out = capsys.readouterr().out
    assert "  riemann_1d: " in out
    configs = sorted(p.stem for p in (ROOT / "configs").glob("*.toml"))
    lines = {ln.split(":")[0].strip(): ln for ln in out.splitlines() if ln.startswith("  ")}
    for name in configs:
        assert name in lines
        assert lines[name].rstrip().endswith((".", ")")), lines[name]   # whole sentences, never cut
    assert "SPEC" not in out
    assert "four decaying vortices in the periodic unit square" in lines["taylor_green_2d"]


def test_builtin_config_by_name_and_set_before_the_config(capsys, monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    assert main(["validate", "couette"]) == 0
    assert main(["validate", "--set", "case.n=50", str(ROOT / "configs/sod_ideal_gas.toml")]) == 0
    assert main(["validate", str(ROOT / "configs/sod_ideal_gas.toml"), "--set", "case.n=50"]) == 0
    assert main(["validate", "--set", "case.n=50", "sod_ideal_gas.toml"]) == 0
    capsys.readouterr()
    assert main(["validate", "--set", "case.n=50", "nope"]) == 2
    err = capsys.readouterr().err
    assert "'nope' does not exist and is not a built-in config" in err and "couette" in err
    assert main(["validate", "couette", "--set", "case.ny=10", "oops"]) == 2
    assert "invalid --set value 'oops'; allowed: KEY=VALUE" in capsys.readouterr().err


def test_init_writes_an_editable_config(capsys, monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    assert main(["init", "couette"]) == 0
    assert (tmp_path / "couette.toml").read_text() == (ROOT / "configs/couette.toml").read_text()
    assert main(["init", "couette"]) == 2                      # never overwrites
    assert "the file exists" in capsys.readouterr().err
    assert main(["init", "taylor_green_2d", "--out", "sub/tg.toml"]) == 0
    assert config.load(tmp_path / "sub/tg.toml")["case"]["name"] == "taylor_green_2d"
    assert main(["init", "riemann_1d"]) == 2                   # required keys: points to its configs
    assert "riemann_r1_tait, riemann_r2_tammann, sod_ideal_gas" in capsys.readouterr().err
    assert main(["init", "nope"]) == 2
    assert "allowed: a built-in config (blast_2d," in capsys.readouterr().err


def test_run_writes_the_output_contract(tmp_path):
    """`mlsph run CONFIG --out DIR --set ...` in a subprocess, as users and tools call it."""
    out = tmp_path / "r1"
    r = subprocess.run([sys.executable, "-m", "mlsph_jax.cli", "run", str(ROOT / "configs/riemann_r1_tait.toml"),
                        "--out", str(out), "--set", "case.n=60", "output.snapshots=2"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "l1_rho" in r.stdout  # the one-paragraph result
    s = json.loads((out / "summary.json").read_text())
    for k in ("case", "scheme", "n_particles", "n_steps", "t_final", "wall_time_s", "compile_time_s",
              "status", "metrics", "conservation"):
        assert k in s
    assert s["status"] == "ok" and s["t_final"] == pytest.approx(1e-5)
    with h5py.File(out / "fields.h5") as f:
        snaps = sorted(f["snapshots"])
        assert len(snaps) == 3
        g = f["snapshots"][snaps[-1]]
        assert {"x", "vol", "rho", "vel", "p", "ppd", "kind"} <= set(g)
        assert g.attrs["t"] == pytest.approx(1e-5)
    assert "fields.h5" in (out / "fields.xmf").read_text()
    resolved = config.load(out / "config.toml")
    assert resolved["case"]["n"] == 60
    assert (out / "profiles.png").stat().st_size > 1000


def _run_r1(out, *extra, env=None):
    r = subprocess.run([sys.executable, "-m", "mlsph_jax.cli", "run", str(ROOT / "configs/riemann_r1_tait.toml"),
                        "--out", str(out), "--quiet", "--set", "case.n=60", "output.snapshots=1", *extra],
                       capture_output=True, text=True, timeout=600, env=env)
    assert r.returncode == 0, r.stderr
    return json.loads((out / "summary.json").read_text())


def test_compilation_cache_loads_the_programs_of_a_second_run_with_the_same_numbers(tmp_path):
    """``--compilation-cache DIR`` (mlsph_jax.compilation_cache): the first run stores its compiled
    programs (neighbour kernel, chunk), the second of the same shapes loads them, so its compile
    time falls (measured on Taylor-Green 20 x 20: 2.56 -> 0.44 s for the chunk, the whole command
    18.8 -> 8.9 s) and its results are the same bit for bit; ``off`` runs without any cache, even
    one JAX's own variable turned on (as this suite's does)."""
    cache = tmp_path / "cache"
    a = _run_r1(tmp_path / "a", "--compilation-cache", str(cache))
    entries = lambda: {p.name for p in cache.iterdir() if p.name.endswith("-cache")}   # noqa: E731
    stored = entries()
    assert {"jit_chunk", "jit__update_kernel"} <= {name.split("-")[0] for name in stored}, stored
    b = _run_r1(tmp_path / "b", "--compilation-cache", str(cache))
    assert a["compilation_cache"] == b["compilation_cache"] == str(cache.resolve())
    assert entries() == stored          # every program of the second run came from the cache (a miss adds one)
    assert b["compile_time_s"] < a["compile_time_s"], (a["compile_time_s"], b["compile_time_s"])
    assert (a["metrics"], a["conservation"], a["n_steps"]) == (b["metrics"], b["conservation"], b["n_steps"])
    with h5py.File(tmp_path / "a" / "fields.h5") as fa, h5py.File(tmp_path / "b" / "fields.h5") as fb:
        last = sorted(fa["snapshots"])[-1]
        np.testing.assert_array_equal(fa["snapshots"][last]["rho"][()], fb["snapshots"][last]["rho"][()])
    env = {**os.environ, "JAX_COMPILATION_CACHE_DIR": str(tmp_path / "jax_own")}
    c = _run_r1(tmp_path / "c", "--compilation-cache", "off", env=env)
    assert "compilation_cache" not in c and not (tmp_path / "jax_own").exists()


def test_compilation_cache_that_cannot_be_a_folder_is_refused(tmp_path, capsys, monkeypatch):
    """Bad input: a --compilation-cache path (or MLSPH_JAX_CACHE_DIR) that is a file names the
    setting and what is allowed; the default folder that cannot be written (a read-only home) only
    costs the cache, with a warning (checked without running: the helper alone)."""
    from mlsph_jax import cli, compilation_cache

    bad = tmp_path / "a_file"
    bad.write_text("")
    assert main(["run", "riemann_r1_tait", "--out", str(tmp_path / "o"), "--compilation-cache", str(bad)]) == 2
    err = capsys.readouterr().err
    assert f"invalid --compilation-cache={str(bad)!r}" in err and "allowed: a writable folder, or 'off'" in err
    monkeypatch.setenv(compilation_cache.ENV, str(bad))
    assert main(["run", "riemann_r1_tait", "--out", str(tmp_path / "o")]) == 2
    assert f"invalid {compilation_cache.ENV}=" in capsys.readouterr().err
    monkeypatch.delenv(compilation_cache.ENV)
    monkeypatch.setattr(compilation_cache, "resolve", lambda option: bad / "xla")   # an unwritable default
    tried = []

    def unwritable(folder, **kw):
        tried.append(folder)
        raise compilation_cache.InputError(f"invalid folder {folder}")

    monkeypatch.setattr(compilation_cache, "enable", unwritable)
    cli._use_compilation_cache(None)                  # no error: a warning, and no cache
    assert tried == [bad / "xla"] and "running without the cache" in capsys.readouterr().err


def test_config_reference_is_current():
    """docs/config.md is generated from the schema; regenerate it when keys change."""
    assert (ROOT / "docs/config.md").read_text() == config.config_reference_markdown()


@pytest.mark.slow   # two differentiated runs (~30 s) for one printed line: kept out of the default suite's time
def test_sensitivity_says_which_window_a_time_average_uses(capsys, tmp_path):
    """``--of ke_mean`` without ``--window`` prints one line saying the average is over the whole
    run (start-up included) and how to exclude it; with ``--window`` or an instantaneous
    objective there is no such line."""
    base = ["sensitivity", "couette", "--set", "case.ny=8", "case.nx=8", "time.t_end=0.05", "--wrt", "physics.mu",
            "--n-steps", "30", "--out"]
    assert main([*base, str(tmp_path / "a"), "--of", "ke_mean"]) == 0
    out = capsys.readouterr().out
    notes = [ln for ln in out.splitlines() if "no --window given" in ln]
    assert len(notes) == 1 and "ke_mean averages over the whole run, t in [0, 0.05]" in notes[0], out
    assert "start-up included" in notes[0] and "--window T_START T_END" in notes[0]
    assert main([*base, str(tmp_path / "b"), "--of", "ke_mean", "--window", "0.01", "0.05"]) == 0
    assert "no --window given" not in capsys.readouterr().out
