"""JAX's persistent compilation cache for the command line (``mlsph run / sensitivity / calibrate``).

A run compiles a few XLA programs: the neighbour kernel, the geometry of fixed particles and the
driver's chunk (Taylor-Green 20 x 20: 1.0 + 5.6 + 2.6 s, more than the 5 s of stepping).  JAX can
keep compiled programs on disk (``jax_compilation_cache_dir``), keyed by the program, the compile
options, the XLA flags and the JAX version, so the next run of the same shapes and scheme loads
them instead (the same executable: results are bit for bit those of a compiled run).

The command line turns it on (:func:`enable`), in the folder given by ``--compilation-cache``, else
the environment variable ``MLSPH_JAX_CACHE_DIR``, else the folder JAX was already given
(``JAX_COMPILATION_CACHE_DIR``, kept as it is), else ``$XDG_CACHE_HOME/mlsph_jax/xla`` (default
``~/.cache/mlsph_jax/xla``); ``off`` (flag or variable) disables it.  The Python API does not
change JAX's process-wide settings by itself: call :func:`enable` to get the same behaviour.
Only programs that took at least ``min_compile_s`` to compile are stored, and JAX evicts the least
recently used entries beyond ``max_bytes``.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import jax
from jax.experimental.compilation_cache import compilation_cache as _jax_cache

from .errors import InputError

__all__ = ["ENV", "OFF", "active", "default_dir", "disable", "enable", "resolve"]

#: Environment variable naming the cache folder (or ``off``).
ENV = "MLSPH_JAX_CACHE_DIR"
#: The value that disables the cache.
OFF = "off"


def default_dir() -> Path:
    """``$XDG_CACHE_HOME/mlsph_jax/xla`` (``~/.cache/mlsph_jax/xla`` without the variable)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "mlsph_jax" / "xla"


def active() -> str | None:
    """The folder of JAX's persistent compilation cache if it is on, else None."""
    folder = jax.config.jax_compilation_cache_dir
    return str(folder) if folder and jax.config.jax_enable_compilation_cache else None


def disable() -> None:
    """Turn JAX's persistent compilation cache off for this process (also one that
    ``JAX_COMPILATION_CACHE_DIR`` turned on).  Call it when no compilation is in progress."""
    jax.config.update("jax_enable_compilation_cache", False)
    _jax_cache.reset_cache()     # JAX keeps the cache object it made at its first use


def resolve(option: str | None) -> Path | None:
    """The cache folder to enable for the command-line value ``option`` (``None``: not given):
    the option, else :data:`ENV`, else JAX's own setting if one is made (``JAX_COMPILATION_CACHE_DIR``
    or ``jax.config``: then None, it is left as it is), else :func:`default_dir`.  None also when
    disabled (``off``: then call :func:`disable`)."""
    value = option if option is not None else os.environ.get(ENV)
    if value is None or value == "":
        return None if jax.config.jax_compilation_cache_dir else default_dir()
    if value.strip().lower() == OFF:
        return None
    return Path(value).expanduser()


def enable(path: str | os.PathLike | None = None, *, min_compile_s: float = 0.0,
           max_bytes: int = 2 * 1024**3, name: str = "--compilation-cache") -> Path:
    """Turn on JAX's persistent compilation cache in ``path`` (default :func:`default_dir`),
    creating the folder; returns it (absolute).  Process-wide (a JAX setting); call it when no
    compilation is in progress.  ``name``: the setting to name in an error."""
    folder = (default_dir() if path is None else Path(path).expanduser()).resolve()
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=folder, prefix=".mlsph_write_test-")   # one per process
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise InputError(f"invalid {name}={str(path if path is not None else folder)!r}: {e.strerror or e}; "
                         f"allowed: a writable folder, or {OFF!r} to run without the cache") from None
    jax.config.update("jax_enable_compilation_cache", True)
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", float(min_compile_s))
    jax.config.update("jax_compilation_cache_max_size", int(max_bytes))
    _jax_cache.reset_cache()     # a cache object JAX made earlier in the process would keep its folder
    return folder
