"""The notebooks in notebooks/ execute without error (reduced resolution, as shipped) and are
stored executed (outputs and plots visible on GitHub).

nbformat and nbclient are test extras (``pip install -e ".[test]"``); without them these tests
fail with that instruction instead of being skipped silently.
"""

from __future__ import annotations

from pathlib import Path

import pytest

try:
    import nbclient
    import nbformat
except ImportError as e:          # reported by test_notebook_tools_are_installed
    nbclient = nbformat = None
    MISSING = str(e)
else:
    MISSING = ""

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))


def _need_tools():
    if nbclient is None:
        pytest.fail(f"the notebook tests need nbformat and nbclient ({MISSING}); install the test extras: "
                    'pip install -e ".[test]"')


def test_notebook_tools_are_installed():
    _need_tools()


def test_there_are_notebooks():
    names = [p.name for p in NOTEBOOKS]
    assert "01_quickstart.ipynb" in names and "02_gradients_and_calibration.ipynb" in names


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_is_stored_executed(path):
    """Every code cell ran (in order) and the plots are stored as images."""
    _need_tools()
    nb = nbformat.read(path, as_version=4)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert [c.get("execution_count") for c in code] == list(range(1, len(code) + 1))
    outputs = [o for c in code for o in c.get("outputs", [])]
    assert not [o for o in outputs if o.output_type == "error"]
    assert any("image/png" in o.get("data", {}) for o in outputs), "no plot stored"


#: Executed under ``slow`` only (CI time): the gradients-and-calibration notebook (~70 s), whose
#: code paths the default suite runs in tests/test_differentiable.py and the README's examples.
SLOW_NOTEBOOKS = ("02_gradients_and_calibration.ipynb",)


@pytest.mark.parametrize("path", [pytest.param(p, marks=pytest.mark.slow) if p.name in SLOW_NOTEBOOKS else p
                                  for p in NOTEBOOKS], ids=[p.name for p in NOTEBOOKS])
def test_notebook_executes(path):
    _need_tools()
    nb = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(nb, timeout=900, kernel_name="python3",
                                     resources={"metadata": {"path": str(path.parent)}})
    client.execute()
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []) if o.output_type == "error"]
    assert not errors
