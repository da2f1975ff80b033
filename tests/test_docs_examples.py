"""Every Python example in the README and in docs/ runs as written and gives finite numbers.

The blocks of one page run in order in one namespace (later blocks use earlier names), from the
repository root (the examples name ``configs/...``).  A page's examples carry their own
assertions where a number is claimed (e.g. docs/extending.md); here every printed or returned
float must at least be finite.
"""

import ast
import math
import re
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
BLOCK = re.compile(r"```python\n(.*?)```", re.S)


def _blocks(page: Path) -> list[str]:
    return BLOCK.findall(page.read_text())


PAGES_WITH_CODE = [p for p in PAGES if _blocks(p)]


def test_the_pages_with_examples_are_found():
    names = {p.name for p in PAGES_WITH_CODE}
    assert {"README.md", "extending.md"} <= names


def _finite(value) -> bool:
    if value is None:
        return True
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return True
    return bool(np.all(np.isfinite(arr)))


@pytest.fixture
def clean_registries():
    """Components that a page registers are removed afterwards (later tests see the package's own)."""
    from mlsph_jax.registry import all_registries

    before = {kind: set(reg.names()) for kind, reg in all_registries().items()}
    yield
    for kind, reg in all_registries().items():
        for name in set(reg.names()) - before.get(kind, set()):
            reg.unregister(name)


@pytest.mark.parametrize("page", PAGES_WITH_CODE, ids=lambda p: p.name)
def test_page_examples_run(page, monkeypatch, capsys, clean_registries):
    monkeypatch.chdir(ROOT)
    ns: dict = {"__name__": f"docs_example_{page.stem}"}
    for k, code in enumerate(_blocks(page)):
        tree = ast.parse(code, f"{page.name}[{k}]")
        last = tree.body.pop() if tree.body and isinstance(tree.body[-1], ast.Expr) else None
        exec(compile(tree, f"{page.name}[{k}]", "exec"), ns)                                  # noqa: S102
        if last is not None:                    # a trailing expression: its value must be finite
            value = eval(compile(ast.Expression(last.value), f"{page.name}[{k}]:last", "eval"), ns)  # noqa: S307
            assert _finite(value), f"{page.name} block {k}: last expression gave {value!r}"
    out = capsys.readouterr().out
    floats = [float(x) for x in re.findall(r"[-+]?\d+\.\d*(?:[eE][-+]?\d+)?|\bnan\b|\binf\b", out)]
    assert all(math.isfinite(x) for x in floats), out
