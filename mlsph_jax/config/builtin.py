"""The built-in configs, by name, from any folder.

The repository's ``configs/*.toml`` are the only copy: ``pyproject.toml`` maps that folder to the
package ``mlsph_jax.configs`` (``package-dir``), so an installed package (``pip install .``)
holds them as ``mlsph_jax/configs/*.toml``; a source checkout (or ``PYTHONPATH``) reads the
repository's folder.  ``mlsph run couette``, ``mlsph init couette`` and ``mlsph cases`` use
:func:`config_path`, :func:`builtin_configs` and :func:`describe`.
"""

from __future__ import annotations

import re
from pathlib import Path

from ..errors import ConfigError

__all__ = ["CONFIG_DIR", "builtin_configs", "config_path", "describe"]

_PACKAGE = Path(__file__).resolve().parent.parent


def _config_dir() -> Path:
    for d in (_PACKAGE / "configs", _PACKAGE.parent / "configs"):   # installed, then source checkout
        if d.is_dir() and any(d.glob("*.toml")):
            return d
    return _PACKAGE / "configs"


#: Folder of the built-in configs (installed package data, else the repository's ``configs/``).
CONFIG_DIR = _config_dir()


def builtin_configs() -> list[str]:
    """Names (file stems) of the built-in configs."""
    return sorted(p.stem for p in CONFIG_DIR.glob("*.toml"))


def config_path(name: str) -> Path:
    """``name`` as a config file: an existing path as given, else the built-in config of that
    name (with or without ``.toml``); :class:`ConfigError` naming the built-in names otherwise."""
    p = Path(name)
    if p.is_file():
        return p
    stem = p.name[:-5] if p.name.endswith(".toml") else p.name
    if p.parent == Path(".") and stem in builtin_configs():
        return CONFIG_DIR / f"{stem}.toml"
    raise ConfigError(f"config file {name!r} does not exist and is not a built-in config; allowed: a TOML file or "
                      f"one of {', '.join(builtin_configs())} (mlsph cases lists them)")


_SENTENCE_END = re.compile(r"\.(?=\s+[A-Z]|\s*\n|\s*$)")


def describe(path: str | Path) -> str:
    """First sentence of a config's leading comment block (lines joined; never cut inside a
    sentence: it ends at a period closing a line or followed by a capital)."""
    lines = []
    for ln in Path(path).read_text().splitlines():
        if not ln.startswith("#") or not ln[1:].strip():
            break
        lines.append(ln[1:].strip())
    text = "\n".join(lines)
    m = _SENTENCE_END.search(text)
    return " ".join((text[: m.end()] if m else text).split())
