"""The ``taylor_green_2d`` case (thesis §3.7.3 / §4.5.1, SPEC §12.1 V4): exact solution,
kinetic-energy decay, convergence of the velocity error, and config errors.

Uniform-state and symmetry sanity checks of the scheme live in tests/test_solver.py and
tests/test_viscous.py; they are not repeated here.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.cases.taylor_green_2d import TaylorGreen, error_metrics, lattice
from mlsph_jax.errors import ConfigError
from mlsph_jax.simulation import run_problem

BASE = """
[case]
name = "taylor_green_2d"
[scheme]
method = "mlsph_ale"
frame = "eulerian"
reconstruction_degree = 2
[output]
plots = false
progress = false
"""


def _cfg(*sets: str) -> dict:
    return config.loads(BASE, list(sets))


def _run(*sets: str) -> dict:
    cfg = _cfg(*sets)
    return run_problem(build_problem(cfg), cfg, out_dir=None, quiet=True).summary


# -- exact solution and set-up (no time stepping) ---------------------------------------------

def test_exact_decay_rates_match_the_thesis():
    # L = 1, U0 = rho0 = 1: E_k / E_k0 = exp(-16 pi^2 t / Re) (thesis eq. 3.19)
    cfg = _cfg("case.re=100")
    tg = TaylorGreen.from_config(cfg)
    t = 0.37
    ratio = tg.kinetic_energy(t) / tg.kinetic_energy(0.0)
    assert ratio == pytest.approx(math.exp(-16 * math.pi**2 * t / 100), rel=1e-13)
    assert tg.kinetic_energy(0.0) == pytest.approx(0.25)   # E_k0 = U0^2 L^2 / 4
    assert cfg["case"]["re"] == 100.0 and build_problem(cfg).params["physics.mu"] == pytest.approx(0.01)
    # [0, 2 pi]^2 with re = 200 pi (mu = 0.01): u = e^{-2t/100} sin x cos y (thesis eq. 4.41)
    tg = TaylorGreen.from_config(_cfg(f"case.length={2 * math.pi!r}", f"case.re={200 * math.pi!r}"))
    assert tg.nu == pytest.approx(0.01)
    x = np.array([[0.3, 1.1]])
    assert tg.velocity(x, t)[0, 0] == pytest.approx(math.exp(-2 * t / 100) * math.sin(0.3) * math.cos(1.1), rel=1e-13)
    p_exact = 0.25 * math.exp(-4 * t / 100) * (math.cos(0.6) + math.cos(2.2))
    assert tg.pressure(x, t)[0] == pytest.approx(p_exact, rel=1e-13)


@pytest.mark.parametrize("layout", ["cartesian", "perturbed"])
def test_initial_state_matches_the_exact_solution(layout):
    cfg = _cfg(f"case.layout={layout}", "case.n=24")
    pb = build_problem(cfg)
    m = error_metrics(pb.particles, 0.0, pb.params, TaylorGreen.from_config(cfg), "tait")
    assert m["l2_velocity_error"] < 1e-14 and m["umax_rel_error"] < 1e-14
    assert m["l2_pressure_error"] < 1e-12                   # density from the inverted Tait law
    assert m["ke_rel_error"] < (1e-5 if layout == "cartesian" else 2e-3)
    x = np.asarray(pb.particles.x)
    assert x.shape == (576, 2) and x.min() >= 0.0 and x.max() < 1.0
    assert np.allclose(np.asarray(pb.particles.vol), (1 / 24) ** 2)


def test_perturbed_lattice_displacements_are_bounded_and_seeded():
    a = lattice(10, 1.0, "perturbed", 0.2, seed=3)
    b = lattice(10, 1.0, "perturbed", 0.2, seed=3)
    c = lattice(10, 1.0, "cartesian")
    d = a - c
    d = d - np.round(d / 1.0)
    assert np.array_equal(a, b) and 0.15 < np.abs(d).max() / 0.1 <= 0.2


# -- kinetic-energy decay ----------------------------------------------------------------------

def test_kinetic_energy_decay_at_re_100():
    """E_k(t) against the exact exp(-16 pi^2 t / Re), Re = 100, t = 0.1, 50 x 50 Cartesian
    particles (the built-in config's resolution), Eulerian MLSPH-ALE, quadratic reconstruction.

    The exact decay over t = 0.1 is 14.6 %.  Measured ke_rel_error = |E_k / E_k,exact - 1| at
    t = 0.1 (same scheme, Cartesian, Re = 100) — a convergence study:

        n =  25: 0.1811     n =  50: 0.02412     n = 100: 0.00256     (observed order 2.9, 3.2)

    The error is the numerical dissipation of the Rusanov flux (the same run at Re = 1e6 loses
    0.0260 of its energy at n = 50, 0.1865 at n = 25: it does not depend on the viscosity), so
    it converges at the third order of the quadratic reconstruction.  Tolerance: the measured
    0.0241 at n = 50 plus 25 %, at every output time; the energy must decay faster than the
    exact solution, never slower.  At this resolution the measured decay E_k/E_k0 = 0.833
    corresponds to an effective Re of 86 (exact 0.854 at Re = 100); the test still rejects a
    wrong decay law such as Re = 60 (0.769) by a wide margin."""
    s = _run("case.n=50", "case.re=100", "time.t_end=0.1", "output.snapshots=2")
    m = s["metrics"]
    assert m["ke_rel_error"] < 0.0241 * 1.25
    assert m["ke_ratio_rel_error"] < 0.0241 * 1.25
    assert m["ke"] < m["ke_exact"]                            # dissipative, not energy-producing
    ts = s["timeseries"]
    assert ts["t"][-1] == pytest.approx(0.1)
    r = np.asarray(ts["ke"]) / ts["ke"][0]
    exact = np.exp(-16 * math.pi**2 * np.asarray(ts["t"]) / 100)
    assert np.all(np.abs(r / exact - 1) < 0.0241 * 1.25)
    assert abs(r[-1] - math.exp(-16 * math.pi**2 * 0.1 / 60)) > 0.05  # Re = 60 is rejected
    assert m["l2_velocity_error"] < 0.0121 * 1.25               # measured 0.01214
    assert m["l2_pressure_error"] < 0.0134 * 1.25               # measured 0.01340


# -- convergence on a perturbed layout ---------------------------------------------------------

def _velocity_errors(ns, t_end=0.2):
    return [_run(f"case.n={n}", "case.layout=perturbed", "case.perturbation=0.15", "case.seed=1",
                 f"time.t_end={t_end}", "output.snapshots=1")["metrics"]["l2_velocity_error"] for n in ns]


@pytest.mark.slow   # CI time; the Re = 100 decay and the config fingerprints stay in the default suite
def test_velocity_error_converges_at_second_order_or_better_on_a_perturbed_layout():
    """Relative L2 velocity error at t = 0.2, Re = 100, perturbed lattice (+-0.15 dx, seed 1),
    Eulerian MLSPH-ALE with quadratic reconstruction.  A prototype measured 0.524, 0.0923,
    0.0117 for n = 16, 32, 64 (orders 2.5, 3.0); the test requires an observed order >= 1.8."""
    e16, e32 = _velocity_errors((16, 32))
    assert math.log2(e16 / e32) >= 1.8


@pytest.mark.slow
def test_velocity_error_converges_at_second_order_or_better_on_a_perturbed_layout_fine():
    e32, e64 = _velocity_errors((32, 64))
    assert math.log2(e32 / e64) >= 1.8


# -- the built-in config at its defaults (issue 14 targets) -------------------------------------

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "taylor_green_2d.toml"


def _run_builtin(*sets: str) -> dict:
    cfg = config.load(CONFIG, [*sets, "output.plots=false", "output.progress=false", "output.snapshots=1"])
    return run_problem(build_problem(cfg), cfg, out_dir=None, quiet=True).summary


# CI time: the shipped config is held by its fingerprint; the Re = 100 decay stays in the default suite
@pytest.mark.slow
def test_builtin_config_coarse_run_keeps_its_kinetic_energy():
    """configs/taylor_green_2d.toml at 16 x 16 to t* = 1 (Re = 100), its scheme as shipped (cubic
    reconstruction + Thornber's low-Mach correction, c0 = 20).  Measured ke_rel_error 0.0152 (docs/
    validation.md, "Taylor-Green defaults"); asserted + 30 %.  The previous default (plain Rusanov
    at c0 = 10) is off by 50 % here (acoustic dissipation of the velocity jump), which the bound
    rejects."""
    s = _run_builtin("case.n=16")
    m = s["metrics"]
    assert s["status"] == "ok"
    assert m["ke_rel_error"] < 0.0152 * 1.3
    assert m["ke"] < 0.25                                     # decayed from E_k0 = 0.25


@pytest.mark.slow
@pytest.mark.parametrize(("n", "target", "u_measured"), [
    (25, 0.01, 1.25e-4),     # E_k error measured 6.3e-5 (plain Rusanov at c0 = 10: 0.075)
    (50, 0.001, 3.96e-4),    # E_k error measured 7.8e-4 (Thornber at c0 = 10: 0.0022)
])
def test_builtin_config_meets_the_issue_14_targets(n, target, u_measured):
    """Issue 14: E_k error at t* = 1 <= 1 % at 25 x 25 and <= 0.1 % at 50 x 50 (Cartesian), the
    built-in config at its defaults (25 x 25: ~2 min, 50 x 50: ~13 min on 2 shared cores); the
    velocity L2 error within its measured value + 25 %."""
    m = _run_builtin(f"case.n={n}")["metrics"]
    assert m["ke_rel_error"] <= target
    assert m["l2_velocity_error"] < u_measured * 1.25


@pytest.mark.slow
def test_builtin_config_meets_the_target_on_the_perturbed_layout():
    """Issue 14: E_k error at t* = 1 <= 0.1 % also on the perturbed 50 x 50 layout (+-0.15 dx,
    seed 0), the built-in config at its defaults (~6 min on 2 shared cores).  Measured with the
    quadratic area correction (decision 59): ke_rel_error 2.6e-4, velocity L2 3.81e-4, pressure L2
    1.96e-3, the Cartesian run's level; without it 0.0097 / 0.0088 / 0.041.  The L2 errors are
    asserted within their measured values + 25 %."""
    m = _run_builtin("case.n=50", "case.layout=perturbed")["metrics"]
    assert m["ke_rel_error"] <= 0.001
    assert m["l2_velocity_error"] < 3.81e-4 * 1.25
    assert m["l2_pressure_error"] < 1.96e-3 * 1.25


# -- bad input ---------------------------------------------------------------------------------

@pytest.mark.parametrize("override, needle", [
    ("case.layout=hexagonal", "case.layout"),
    ("case.re=-100", "case.re"),
    ("case.re=0", "case.re"),
    ("case.n=4", "case.n"),
    ("case.perturbation=0.5", "case.perturbation"),
    ("case.length=0", "case.length"),
    ("case.u0=-1", "case.u0"),
    ("case.u0=6", "case.u0"),                 # Tait law not invertible at p = -rho0 u0^2/2
    ("physics.mu=0.02", "physics.mu"),        # inconsistent with case.re = 100
    ("eos.kind=ideal_gas", "eos.kind"),
    ("physics.body_force=[0.0, -9.81]", "physics.body_force"),
    ("case.nn=3", "case.n"),                  # unknown key, with a suggestion
])
def test_bad_input_names_the_key(override, needle):
    with pytest.raises(ConfigError, match=needle.replace(".", r"\.")):
        _cfg(override)


def test_consistent_viscosity_is_accepted_and_support_wider_than_half_the_box_is_rejected():
    assert _cfg("physics.mu=0.01")["physics"]["mu"] == 0.01
    with pytest.raises(ConfigError, match=r"case\.n=8"):           # 2 * 2.0 * 2 = 8 >= n
        build_problem(_cfg("case.n=8", "scheme.method=sph_ale"))


# -- thesis configurations (slow) ----------------------------------------------------------------

@pytest.mark.slow
def test_thesis_section_4_5_1_run_in_the_shifting_frame():
    """The built-in §4.5.1 config (configs/taylor_green_2d_mlsph.toml: [0, 2 pi]^2, 50 x 50,
    Re = 100 on L / 2 pi, MLSPH-ALE in the particle-shifting ALE frame, t = 2; ~80 s).
    Measured (2026-12-06, the config's scheme since issue 14 and decision 112): ke_rel_error
    0.00445, l2_velocity_error 0.00231, l2_pressure_error 0.0107, mass -2.6e-14 (the scheme before
    issue 14: 0.1177, 0.0946, mass drift 0.89 %); asserted with 25 % margins, mass and momentum to
    round-off, and dissipative (never energy-producing)."""
    cfg = config.load(Path(__file__).resolve().parents[1] / "configs" / "taylor_green_2d_mlsph.toml",
                      ["output.plots=false", "output.progress=false", "output.snapshots=2"])
    s = run_problem(build_problem(cfg), cfg, out_dir=None, quiet=True).summary
    m, c = s["metrics"], s["conservation"]
    assert s["status"] == "ok"
    assert m["ke_rel_error"] < 0.00445 * 1.25 and m["l2_velocity_error"] < 0.00231 * 1.25
    assert m["l2_pressure_error"] < 0.0107 * 1.25
    assert m["ke"] < m["ke_exact"]
    assert abs(c["mass"]) < 1e-12
    assert abs(c["momentum_x"]) < 1e-10 and abs(c["momentum_y"]) < 1e-10


@pytest.mark.slow
def test_thesis_resolution_re100():
    """Thesis §3.7.3 resolution dx = L/100, Re = 100, t* = 1 (~13 min on 2 cores).  Measured
    ke_rel_error 0.026, l2_velocity_error 0.013, l2_pressure_error 0.015
    (docs/validation.md); asserted with 25 % margins."""
    s = _run("case.n=100", "case.re=100", "time.t_end=1.0", "output.snapshots=2")
    m = s["metrics"]
    assert m["ke_rel_error"] < 0.026 * 1.25
    assert m["l2_velocity_error"] < 0.013 * 1.25
    assert m["l2_pressure_error"] < 0.015 * 1.25
