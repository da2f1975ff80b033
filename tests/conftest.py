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

The default (not ``slow``) test run also compiles at LLVM optimisation level 0
(``--xla_backend_optimization_level=0``; decision 98): the suite is mostly compilation of short
runs, and without LLVM's optimisation passes it takes ~36 % less time (905 -> 582 s on two
workers, docs/performance.md "Test-suite time"), while the few run-dominated tests get up to
1.6x slower.  A run that selects the ``slow`` tests (``-m slow``, run-dominated) keeps the
default level; ``MLSPH_TEST_BACKEND_OPTIMIZATION=default`` keeps it for any run.  Both settings
only change how XLA lowers the same HLO, so results differ by round-off: the tests compare two
different programs to round-off, not bit for bit.

The test run also compiles with XLA:CPU's elemental fusion emitters
(``--xla_cpu_use_fusion_emitters=false`` appended to ``XLA_FLAGS``) instead of the MLIR fusion
emitters that jaxlib 0.10 uses by default: the same HLO programs, and test files that compile many
of them run up to ~40 % faster (docs/performance.md, "Test-suite time"). The code generator only
changes how each fused loop is lowered, so results differ from a default-flag run by round-off
(multiply-add contractions), which branches (a kink, a MOOD flag, a step count) and chaotic runs
can amplify: the one test that holds numbers recorded with the default flags to round-off,
``tests/test_config_regression.py``, compares the few entries whose round-off a reduced run
amplifies beyond its tolerance with a tolerance measured for them (decision 97), and runs its
full-size (``slow``) configs in a subprocess with the user's own ``XLA_FLAGS`` (kept in
``MLSPH_TEST_USER_XLA_FLAGS``). ``MLSPH_TEST_USE_FUSION_EMITTERS=1`` keeps
the default emitters for the whole run; an ``XLA_FLAGS`` that already names the option is left as
it is.
"""

from __future__ import annotations

import os
import shutil
import tempfile

_ENV = "JAX_COMPILATION_CACHE_DIR"
_made_here: str | None = None
#: XLA_FLAGS as the user started the run (set once by the process that starts it; xdist workers
#: and subprocesses inherit it).
USER_XLA_FLAGS = "MLSPH_TEST_USER_XLA_FLAGS"
_EMITTERS = "--xla_cpu_use_fusion_emitters=false"
_BACKEND_O0 = "--xla_backend_optimization_level=0"


def _selects_slow_tests(config) -> bool:
    """Whether the run's marker expression selects a test marked ``slow`` (pyproject's default
    ``-m 'not slow'`` does not; ``-m slow``, ``-m ''`` and ``-m 'slow or not slow'`` do)."""
    expr = config.getoption("markexpr", "") or ""
    if not expr.strip():
        return True
    from _pytest.mark.expression import Expression  # pytest's own evaluation of ``-m``

    return Expression.compile(expr).evaluate(lambda name, **kwargs: name == "slow")


def pytest_configure(config):
    global _made_here
    # a developer's own command-line cache folder (mlsph_jax.compilation_cache) stays out of the run
    os.environ.pop("MLSPH_JAX_CACHE_DIR", None)
    if not os.environ.get(_ENV):
        _made_here = tempfile.mkdtemp(prefix="mlsph-jax-test-cache-")
        os.environ[_ENV] = _made_here
    if USER_XLA_FLAGS not in os.environ:       # read by XLA when the backend starts, i.e. later
        flags = os.environ.get("XLA_FLAGS", "")
        os.environ[USER_XLA_FLAGS] = flags
        if "xla_cpu_use_fusion_emitters" not in flags and os.environ.get("MLSPH_TEST_USE_FUSION_EMITTERS") != "1":
            flags = f"{flags} {_EMITTERS}".strip()
        if ("xla_backend_optimization_level" not in flags and not _selects_slow_tests(config)
                and os.environ.get("MLSPH_TEST_BACKEND_OPTIMIZATION") != "default"):
            flags = f"{flags} {_BACKEND_O0}".strip()
        os.environ["XLA_FLAGS"] = flags
    import jax

    jax.config.update("jax_compilation_cache_dir", os.environ[_ENV])


def pytest_unconfigure(config):
    if _made_here is not None:
        shutil.rmtree(_made_here, ignore_errors=True)
