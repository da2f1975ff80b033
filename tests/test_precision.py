"""``run.precision = "float32"``: the state, parameters and geometry in float32 (MLS moment
matrices and their solves and the Tait pressure in float64), within a documented tolerance of
the float64 run (docs/performance.md, Precision)."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.errors import ConfigError, InputError
from mlsph_jax.rhs import geometry, rhs
from mlsph_jax.run import setup_run
from mlsph_jax.simulation import Simulation, run_problem
from mlsph_jax.state import with_precision
from mlsph_jax.testing import CONFIG_DIR, REDUCED_OVERRIDES


def _runs(name: str, overrides):
    out = {}
    for prec in ("float64", "float32"):
        cfg = config.load(CONFIG_DIR / f"{name}.toml", [*overrides, f"run.precision={prec}", "output.plots=false",
                                                         "output.progress=false"])
        out[prec] = run_problem(build_problem(cfg), cfg, quiet=True)
    return out["float64"], out["float32"]


def _check(r64, r32, *, state_rtol: float, metric_rtol: float, metrics):
    assert r32.summary["precision"] == "float32" and r64.summary["precision"] == "float64"
    assert r32.summary["status"] == r64.summary["status"] == "ok"
    assert r32.summary["n_steps"] == r64.summary["n_steps"] > 1
    for k in ("x", "vol", "q"):
        a, b = getattr(r64.particles, k), getattr(r32.particles, k)
        assert a.dtype == np.float64 and b.dtype == np.float32, k   # the float32 run really is float32
        a, b = np.asarray(a), np.asarray(b, np.float64)
        assert np.abs(a - b).max() <= state_rtol * np.abs(a).max(), k
    for k in metrics:
        assert r32.summary["metrics"][k] == pytest.approx(r64.summary["metrics"][k], rel=metric_rtol), k


def test_float32_taylor_green_is_within_tolerance_of_float64():
    """Eulerian Taylor-Green, 144 particles, 0.05 s: conserved quantities within 1e-5 of their
    scale (measured 1.5e-6 on 256 particles) and the error metrics within 1e-4 relative, in the
    thesis' setting (c0 = 10, no low-Mach option).  With the built-in config's c0 = 20 and
    Thornber's correction the pressure L2 error of float32 differs by 1.7e-4 relative (c0 = 10
    with Thornber: 1.9e-4), outside this tolerance; the cause was not separated
    (docs/performance.md)."""
    r64, r32 = _runs("taylor_green_2d", (*REDUCED_OVERRIDES["taylor_green_2d"], "eos.c0=10",
                                         "scheme.low_mach_reconstruction=none"))
    _check(r64, r32, state_rtol=1e-5, metric_rtol=1e-4,
           metrics=("l2_velocity_error", "l2_pressure_error", "ke_rel_error", "umax_rel_error"))


@pytest.mark.slow
def test_float32_r1_tait_is_within_tolerance_of_float64():
    """Tait Riemann problem R1 (reduced: 50 particles, 5e-6 s): conserved quantities within
    2e-5 of their scale (measured 5e-6) and the L1 errors within 1e-4 relative."""
    r64, r32 = _runs("riemann_r1_tait", REDUCED_OVERRIDES["riemann_r1_tait"])
    _check(r64, r32, state_rtol=2e-5, metric_rtol=1e-4, metrics=("l1_rho", "l1_u", "l1_p"))


def test_float32_right_hand_side_computes_in_float32():
    """No float64 constant promotes a float32 right-hand side back to float64 (the scan of a
    chunk would refuse the carry; a silent promotion would make the mode pointless)."""
    cfg = config.loads('[case]\nname = "taylor_green_2d"\nn = 12\n', [])
    pb = build_problem(cfg)
    p = with_precision(pb.particles, "float32")
    prm = with_precision(pb.params, "float32")
    nl = setup_run(pb).nl
    g = jax.eval_shape(lambda p, nl: geometry(p.x, p.vol, nl, pb.scheme, pb.domain), p, nl)  # traced, not run
    assert {np.dtype(a.dtype) for a in jax.tree_util.tree_leaves(g) if np.issubdtype(a.dtype, np.floating)} \
        == {np.dtype(np.float32)}
    out = jax.eval_shape(lambda p, prm, g: rhs(p, prm, g, pb.scheme), p, prm, g)
    assert [np.dtype(a.dtype) for a in out] == [np.dtype(np.float32)] * 3


def test_bad_precision_is_refused():
    with pytest.raises(ConfigError, match=r"run\.precision"):
        config.loads('[case]\nname = "taylor_green_2d"\nn = 8\n', ["run.precision=float16"])
    cfg = config.loads('[case]\nname = "taylor_green_2d"\nn = 8\n', [])
    with pytest.raises(InputError, match=r"invalid run\.precision='half'; allowed: one of 'float64', 'float32'"):
        Simulation(build_problem(cfg), precision="half")
