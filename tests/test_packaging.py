"""The package as installed: every folder of mlsph_jax/ is a declared package, and the built-in
configs (one copy, the repository's configs/) install as mlsph_jax/configs so that
`mlsph cases`, `mlsph validate couette` and `mlsph init couette` work from any folder."""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_pyproject_declares_every_folder_of_the_package():
    tool = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    folders = {".".join(p.relative_to(ROOT).parts) for p in (ROOT / "mlsph_jax").rglob("*")
               if p.is_dir() and p.name != "__pycache__" and any(f.is_file() for f in p.iterdir())}
    folders.add("mlsph_jax")
    assert set(tool["packages"]) == folders | {"mlsph_jax.configs"}
    assert tool["package-dir"] == {"mlsph_jax.configs": "configs"}
    assert tool["package-data"]["mlsph_jax.configs"] == ["*.toml"]
    assert not (ROOT / "mlsph_jax" / "configs").exists()    # one copy of the configs


@pytest.mark.slow
def test_non_editable_install_runs_builtin_configs_from_any_folder(tmp_path):
    src, target, elsewhere = tmp_path / "src", tmp_path / "site", tmp_path / "elsewhere"
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=ROOT, capture_output=True,
                           text=True, check=True).stdout.split()
    for f in files:
        if (ROOT / f).is_file():
            (src / f).parent.mkdir(parents=True, exist_ok=True)
            (src / f).write_bytes((ROOT / f).read_bytes())
    r = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(target), str(src)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    names = sorted(p.stem for p in (ROOT / "configs").glob("*.toml"))
    assert sorted(p.stem for p in (target / "mlsph_jax" / "configs").glob("*.toml")) == names
    assert (target / "mlsph_jax" / "reference" / "data" / "ghia1982_centerlines.csv").is_file()
    elsewhere.mkdir()
    env = dict(os.environ, PYTHONPATH=str(target))

    def mlsph(*args):
        return subprocess.run([sys.executable, "-m", "mlsph_jax.cli", *args], cwd=elsewhere, env=env,
                              capture_output=True, text=True, timeout=600)

    r = mlsph("cases")
    assert r.returncode == 0 and all(f"  {n}: " in r.stdout for n in names), r.stdout + r.stderr
    assert mlsph("validate", "--set", "case.ny=10", "couette").returncode == 0
    assert mlsph("init", "couette").returncode == 0
    assert (elsewhere / "couette.toml").read_text() == (ROOT / "configs/couette.toml").read_text()
