"""Refactors keep the numbers: every built-in config, on reduced sizes (default suite) and as
shipped (``slow``), reproduces its recorded fingerprint (step count, final time, case metrics,
conservation drifts, MOOD statistics) to 1e-12 relative.

The fingerprints in tests/data/ were recorded with ``experiments/record_config_metrics.py``
before the code they guard was moved.  A change that is *meant* to change the numbers (a new
default, a physics fix) re-records them in the same commit and says so in its message.
"""

import json
from pathlib import Path

import pytest

from mlsph_jax.testing import REDUCED_OVERRIDES, builtin_configs, fingerprint_differences, run_fingerprint

DATA = Path(__file__).parent / "data"
REDUCED = json.loads((DATA / "config_fingerprints.json").read_text())
FULL_PATH = DATA / "config_fingerprints_full.json"


def test_every_builtin_config_has_a_fingerprint():
    assert sorted(REDUCED) == builtin_configs() == sorted(REDUCED_OVERRIDES)


@pytest.mark.parametrize("name", builtin_configs())
def test_reduced_config_reproduces_its_fingerprint(name):
    fp = run_fingerprint(name, REDUCED_OVERRIDES[name])
    assert fp["n_steps"] > 0
    assert fingerprint_differences(fp, REDUCED[name]) == []


#: Built-in configs without a full-size fingerprint, and why (their full runs are the slow
#: validation tests against published values, which hold their numbers instead).
FULL_NOT_RECORDED = {
    "cylinder": "the full steady run (~2 min idle, 10 contended) is tests/test_cylinder.py's slow Re = 40 test",
    "cylinder_re100": "the full shedding run (~7 min idle, 29 contended) is tests/test_shedding.py's slow test",
}


def test_full_fingerprints_cover_every_config_but_the_listed_ones():
    full = json.loads(FULL_PATH.read_text())
    assert sorted(set(builtin_configs()) - set(full)) == sorted(FULL_NOT_RECORDED)


@pytest.mark.slow
@pytest.mark.parametrize("name", builtin_configs())
def test_full_config_reproduces_its_fingerprint(name):
    if name in FULL_NOT_RECORDED:
        pytest.skip(f"no full-size fingerprint for {name}: {FULL_NOT_RECORDED[name]}")
    full = json.loads(FULL_PATH.read_text())
    fp = run_fingerprint(name)
    assert fingerprint_differences(fp, full[name]) == []


def test_fingerprint_comparison_detects_a_change():
    ref = REDUCED["sod_ideal_gas"]
    changed = json.loads(json.dumps(ref))
    key = sorted(changed["metrics"])[0]
    changed["metrics"][key] *= 1.0 + 1e-9
    assert fingerprint_differences(ref, ref) == []
    assert any(key in p for p in fingerprint_differences(changed, ref))
