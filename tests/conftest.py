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

The default suite (``-m 'not slow'``) also compiles with XLA's LLVM back-end optimisation off
(``--xla_backend_optimization_level=0 --xla_llvm_disable_expensive_passes=true``, appended to
any ``XLA_FLAGS`` of the user's): its programs run for seconds but took longer to compile, and
XLA's speed on the CPU comes from its HLO fusions, which these flags keep.  Measured on a loaded
2-core machine (tests/test_config_regression.py and tests/test_local_time_stepping.py, -n 2):
151 s against 255 s, every reduced-config fingerprint equal to 1e-12 relative except the lift
coefficient of the symmetric cylinder, which is round-off in either build (6e-14 against -9e-14;
see ``testing.fingerprint_differences``).  The slow suite and ``mlsph`` itself keep XLA's
defaults; ``MLSPH_TEST_XLA_DEFAULTS=1`` keeps them for the default suite as well.
"""

from __future__ import annotations

import os
import shutil
import tempfile

_ENV = "JAX_COMPILATION_CACHE_DIR"
_made_here: str | None = None
FAST_COMPILE_FLAGS = "--xla_backend_optimization_level=0 --xla_llvm_disable_expensive_passes=true"


def pytest_configure(config):
    global _made_here
    if "not slow" in (config.option.markexpr or "") and not os.environ.get("MLSPH_TEST_XLA_DEFAULTS"):
        flags = os.environ.get("XLA_FLAGS", "")
        if FAST_COMPILE_FLAGS not in flags:      # the xdist workers inherit the controller's flags
            os.environ["XLA_FLAGS"] = f"{flags} {FAST_COMPILE_FLAGS}".strip()
    if not os.environ.get(_ENV):
        _made_here = tempfile.mkdtemp(prefix="mlsph-jax-test-cache-")
        os.environ[_ENV] = _made_here
    import jax

    jax.config.update("jax_compilation_cache_dir", os.environ[_ENV])


def pytest_unconfigure(config):
    if _made_here is not None:
        shutil.rmtree(_made_here, ignore_errors=True)
