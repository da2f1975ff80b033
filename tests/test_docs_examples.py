"""Every Python example in the README and in docs/ runs as written and gives finite numbers.

The blocks of one page run in order in one namespace (later blocks use earlier names), from the
repository root (the examples name ``configs/...``).  A page's examples carry their own
assertions where a number is claimed (e.g. docs/extending.md); here every printed or returned
float must at least be finite.
"""

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


@pytest.mark.parametrize("page", PAGES_WITH_CODE, ids=lambda p: p.name)
def test_page_examples_run(page, monkeypatch, capsys):
    monkeypatch.chdir(ROOT)
    ns: dict = {"__name__": f"docs_example_{page.stem}"}
    for k, code in enumerate(_blocks(page)):
        *body, last = [ln for ln in code.strip().splitlines()]
        exec(compile("\n".join(body), f"{page.name}[{k}]", "exec"), ns)      # noqa: S102
        try:                                    # a trailing expression: its value must be finite
            value = eval(compile(last, f"{page.name}[{k}]:last", "eval"), ns)  # noqa: S307
        except SyntaxError:
            exec(compile(last, f"{page.name}[{k}]:last", "exec"), ns)          # noqa: S102
            value = None
        assert _finite(value), f"{page.name} block {k}: last expression {last!r} gave {value!r}"
    out = capsys.readouterr().out
    floats = [float(x) for x in re.findall(r"[-+]?\d+\.\d*(?:[eE][-+]?\d+)?|\bnan\b|\binf\b", out)]
    assert all(math.isfinite(x) for x in floats), out
