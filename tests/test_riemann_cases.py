"""First-order Riemann problems against the exact solutions (thesis R1, R2 and Sod).

Bounds were set from runs of the built-in configs (first order, Lagrangian, MLSPH-ALE, particles
moved with the MLS interpolant of w and the fluxes at u_i, the thesis as printed: the configs'
position updates are overridden by ``mls_literal`` so that every case keeps the documented
first-order scheme) with 15-25 % margin; the measured values
are in docs/validation.md:

    case  n    l1_rho  l1_u    l1_p        observed L1 order (n = 100 -> 200 -> 400)
    R1    100  0.0385  0.0770  0.0388      0.56-0.58 (all variables)
    R2    200  0.0604  0.0291  0.0230      0.63-0.74
    Sod   200  0.0258  0.0412  0.0234      0.48-0.75

A first-order scheme converges at order 1/2..1 in L1 on solutions with shocks and contacts, so
the refinement test asserts monotone decrease with an observed order of at least 0.4.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.simulation import run_problem

CONFIGS = {"r1": "configs/riemann_r1_tait.toml", "r2": "configs/riemann_r2_tammann.toml",
           "sod": "configs/sod_ideal_gas.toml"}
BOUNDS = {  # (n, l1_rho, l1_u, l1_p)
    "r1": (100, 0.045, 0.090, 0.045),
    "r2": (200, 0.072, 0.035, 0.028),
    "sod": (200, 0.031, 0.050, 0.028),
}


@functools.cache
def run(case: str, n: int, *extra: str) -> dict:
    cfg = config.load(CONFIGS[case], [f"case.n={n}", "scheme.method=mlsph_ale", "scheme.reconstruction_degree=0",
                                      "scheme.limiter=none", "scheme.position_update=mls_literal", *extra])
    res = run_problem(build_problem(cfg), cfg, quiet=True)
    assert res.summary["status"] == "ok"
    assert res.summary["t_final"] == pytest.approx(cfg["time"]["t_end"], rel=1e-12)
    return res.summary


@pytest.mark.parametrize("case", ["r1", "r2", "sod"])
def test_first_order_l1_bounds(case):
    n, b_rho, b_u, b_p = BOUNDS[case]
    m = run(case, n)["metrics"]
    assert m["l1_rho"] < b_rho and m["l1_u"] < b_u and m["l1_p"] < b_p, m
    # not vacuous: a first-order scheme smears the waves over several particles
    assert m["l1_rho"] > 0.2 * b_rho


@pytest.mark.slow   # CI time; test_first_order_l1_bounds keeps R1 against the exact solution
def test_first_order_converges_under_refinement_r1():
    errs = [run("r1", n)["metrics"] for n in (100, 200, 400)]
    for key in ("l1_rho", "l1_u", "l1_p"):
        e = np.array([m[key] for m in errs])
        orders = np.log2(e[:-1] / e[1:])
        assert np.all(orders > 0.4), (key, e, orders)


@pytest.mark.slow
@pytest.mark.parametrize("case", ["r2", "sod"])
def test_first_order_converges_under_refinement_slow(case):
    errs = [run(case, n)["metrics"] for n in (100, 200, 400, 800)]
    for key in ("l1_rho", "l1_u", "l1_p"):
        e = np.array([m[key] for m in errs])
        orders = np.log2(e[:-1] / e[1:])
        assert np.all(orders > 0.4), (key, e, orders)


def test_mass_is_conserved_in_the_tube():
    """Frozen ends hold the undisturbed states and the waves never reach them, so the mass of
    the tube changes only by the self-flux quadrature defect (tiny on a uniform 1D lattice)."""
    s = run("r1", 100)
    assert abs(s["conservation"]["mass"]) < 1e-8
