"""Test-session set-up: one persistent JAX compilation cache shared by the whole test run.

Most of the suite's time is XLA compilation, and several tests compile the same program (the
`mlsph calibrate` test runs the CLI twice on one config; the notebooks, the README examples and
the CLI tests run the same reduced configs).  JAX's own persistent cache
(``jax_compilation_cache_dir``) keys an executable by its HLO, compiler options and devices, so a
second compilation of the same program anywhere in the run - another test, an xdist worker, a
``mlsph`` subprocess, a notebook kernel - loads it instead.  The results are the same executable,
so no number changes; only programs that take more than JAX's default threshold (1 s) to compile
are stored.

The cache lives in a fresh temporary folder made by the pytest process that starts the run (the
xdist controller, whose environment the workers and every subprocess inherit) and removed at its
end, so every run starts cold and nothing outside the run is read or written.  A
``JAX_COMPILATION_CACHE_DIR`` already set by the user is used as it is and kept.
"""

from __future__ import annotations

import os
import shutil
import tempfile

_ENV = "JAX_COMPILATION_CACHE_DIR"
_made_here: str | None = None


def pytest_configure(config):
    global _made_here
    if not os.environ.get(_ENV):
        _made_here = tempfile.mkdtemp(prefix="mlsph-jax-test-cache-")
        os.environ[_ENV] = _made_here
    import jax

    jax.config.update("jax_compilation_cache_dir", os.environ[_ENV])


def pytest_unconfigure(config):
    if _made_here is not None:
        shutil.rmtree(_made_here, ignore_errors=True)
