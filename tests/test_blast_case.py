"""The ``blast_2d`` case (thesis §3.7.2, SPEC §12.1 V3): config checks, far field, metrics.

The coarse runs use dx = 5e-3 m (1,237 fluid + 707 frozen particles), the config's MLSPH-ALE at
first order (``scheme.reconstruction_degree=0 scheme.limiter=none``), t_end = 5e-6 s (10 steps);
each takes a few seconds.  Measured values (delaunay layout unless stated; bounds below carry the
margin):

    run                                      l1_rho_radial  radial_spread  radial_spread_linear
    symmetric, delaunay                      0.0616         0.0407         0.0120
    symmetric, perturbed                     0.0608         0.0444         0.0174
    symmetric, rings                         0.0594         0.0046         0.0022
    blast centre shifted by dx/5 (1 mm)      0.0624         0.0517         0.0336
    blast centre shifted by dx/2             0.0642         0.0762         0.0652

(The thesis' SPH-ALE, ``scheme.method=sph_ale``, beta 2, 1,034 frozen particles, gave 0.0662 /
0.0372 / 0.0129 symmetric and 0.0670 / 0.0598 / 0.0421 shifted by dx/5.)  So the symmetry bounds
are tight: an asymmetry of a fifth of a particle spacing in the initial condition already
exceeds them (radial_spread by 1.15x, radial_spread_linear by 1.9x), whereas the L1 error hardly
sees it (test_symmetry_bound_detects_a_shifted_blast runs that case).
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np
import pytest

from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.cases.blast_2d import far_field_rings, radial_spread
from mlsph_jax.errors import ConfigError
from mlsph_jax.simulation import run_problem
from mlsph_jax.state import Kind

CFG = "configs/blast_2d.toml"
COARSE = ("case.dx=5e-3", "time.t_end=5e-6", "scheme.reconstruction_degree=0", "scheme.limiter=none",
          "output.progress=false")

# Coarse first-order delaunay run (measured: l1 0.0616, spread 0.0407, spread_linear 0.0120;
# perturbed layout 0.0608 / 0.0444 / 0.0174).  ~20 % margin on l1, ~10 % on radial_spread, ~50 %
# on radial_spread_linear (it is small, so a relative margin is cheap) -- still below the
# 0.0517 / 0.0336 of a blast whose centre is shifted by only dx/5.
L1_BOUND = 0.075
SPREAD_BOUND = 0.045
SPREAD_LINEAR_BOUND = 0.018


def _err(overrides) -> str:
    with pytest.raises(ConfigError) as e:
        config.load(CFG, list(overrides))
    return str(e.value)


# --- config -----------------------------------------------------------------------------------

def test_config_file_validates_and_fills_case_defaults():
    cfg = config.load(CFG)
    c = cfg["case"]
    assert c["name"] == "blast_2d" and c["layout"] == "delaunay"
    assert (c["radius"], c["r_interface"], c["rho_in"], c["rho_out"], c["dx"]) == (0.1, 0.05, 1100.0, 1000.0, 2e-3)
    assert (c["perturbation"], c["seed"], c["reference_cells"]) == (0.2, 0, 4000)
    assert cfg["scheme"]["method"] == "mlsph_ale" and cfg["scheme"]["limiter"] == "mood"
    assert cfg["time"]["t_end"] == 1e-5
    # the case alone is runnable: Tait water, thesis time and Lagrangian frame are its defaults
    d = config.load(None, case="blast_2d")
    assert d["eos"] == {"kind": "tait", "rho0": 1000.0, "c0": 1466.0, "gamma": 7.0, "p0": 0.0}
    assert d["time"]["t_end"] == 1e-5 and d["scheme"]["frame"] == "lagrangian"


def test_bad_layout_names_the_key():
    msg = _err(["case.layout=hexagonal"])
    assert "case.layout" in msg and "hexagonal" in msg
    assert "rings" in msg and "delaunay" in msg and "perturbed" in msg


@pytest.mark.parametrize("r_if", ["0.1", "0.12"])
def test_interface_outside_disc_names_the_key(r_if):
    msg = _err([f"case.r_interface={r_if}"])
    assert f"invalid case.r_interface={r_if}" in msg and "case.radius=0.1" in msg


@pytest.mark.parametrize("overrides, fragments", [
    (["case.dx=0.02"], ["invalid case.dx=0.02", "r_interface/5"]),
    (["case.dx=0"], ["invalid case.dx=0"]),
    (["case.rho_in=-1"], ["invalid case.rho_in=-1"]),
    (["case.perturbation=0.7"], ["invalid case.perturbation=0.7"]),
    (["case.seed=-1"], ["invalid case.seed=-1"]),
    (["case.reference_cells=10"], ["invalid case.reference_cells=10"]),
    # waves would reach the frozen far field: r_if + s_max t_end >= R (s_max ~ 2137 m/s)
    (["time.t_end=3e-5"], ["invalid time.t_end=3e-05", "frozen far field", "allowed: t_end <"]),
])
def test_cross_checks_name_the_key(overrides, fragments):
    msg = _err(overrides)
    for f in fragments:
        assert f in msg, (f, msg)


def test_eos_must_be_tait():
    with pytest.raises(ConfigError) as e:
        config.load(None, case="blast_2d", overrides=["eos.kind=ideal_gas"])
    assert 'invalid eos.kind="ideal_gas"' in str(e.value) and '"tait"' in str(e.value)


def test_thesis_end_time_is_within_the_signal_bound():
    # 0.05 + 1951 (1 + ln 1.1) 1e-5 = 0.0714 < 0.1; the largest admissible t_end is ~2.34e-5
    config.load(CFG, ["time.t_end=2.3e-5"])
    _err(["time.t_end=2.4e-5"])


# --- set-up -----------------------------------------------------------------------------------

@pytest.mark.parametrize("method", ["mlsph_ale", "sph_ale"])   # beta 1.5 and 2: far fields of both widths
@pytest.mark.parametrize("layout", ["rings", "delaunay", "perturbed"])
def test_problem_set_up(layout, method):
    cfg = config.load(CFG, ["case.dx=5e-3", f"case.layout={layout}", f"scheme.method={method}"])
    pb = build_problem(cfg)
    p = pb.particles
    x, kind = np.asarray(p.x), np.asarray(p.kind)
    r = np.hypot(x[:, 0], x[:, 1])
    fluid, frozen = kind == int(Kind.FLUID), kind == int(Kind.FROZEN)
    assert fluid.sum() + frozen.sum() == p.n
    assert np.all(r[fluid] < 0.1) and np.all(r[frozen] > 0.1)
    # every fluid particle's support (radius kappa h_i = 2 beta sqrt(V_i), beta = 1.5 for the
    # config's mlsph_ale; up to 4.0 dx for the largest Delaunay boundary triangles, 3.1 dx on
    # rings) lies inside fluid + far field, and the band is at most two rings wider than that
    reach = 2.0 * pb.scheme.beta * np.sqrt(np.asarray(p.vol)[fluid].max())
    band = r[frozen].max() + 0.5 * 5e-3 - 0.1
    assert reach < band - 0.5 * 5e-3 and band < reach + 2 * 5e-3
    assert np.allclose(np.diff(np.unique(np.round(r[frozen], 12))), 5e-3)  # rings dr apart
    U = np.asarray(p.U)
    assert np.all(U[:, 1:] == 0.0)
    inner = fluid & (r <= 0.05)
    assert np.allclose(U[inner, 0], 1100.0, rtol=1e-14, atol=0)
    assert np.allclose(U[~inner, 0], 1000.0, rtol=1e-14, atol=0)
    assert np.all(np.asarray(p.ppd) == cfg["scheme"]["reconstruction_degree"])
    lo, hi = np.asarray(pb.domain.lower), np.asarray(pb.domain.upper)
    assert not any(pb.domain.periodic) and np.all(x > lo) and np.all(x < hi)


def test_far_field_continues_the_rings_layout():
    from mlsph_jax.cases.layouts import rings

    xo, vo = far_field_rings(0.1, 5e-3, 5)
    x, v = rings(0.125, 5e-3)
    keep = np.hypot(x[:, 0], x[:, 1]) > 0.1
    assert np.array_equal(xo, x[keep]) and np.array_equal(vo, v[keep])
    assert vo.sum() == pytest.approx(np.pi * (0.125**2 - 0.1**2), rel=1e-12)


def test_radial_spread_formulas():
    rng = np.random.default_rng(1)
    r = rng.uniform(0.0, 0.1, 20000)
    # a purely radial linear profile: the bin-mean spread is the within-bin gradient term
    # slope * dx / sqrt(12); the per-bin linear fit removes it
    rho = 1000.0 + 500.0 * r
    rms, worst, lin = radial_spread(r, rho, 2e-3)
    assert rms == pytest.approx(500.0 * 2e-3 / np.sqrt(12.0), rel=0.05)
    assert worst == pytest.approx(500.0 * 2e-3 / np.sqrt(12.0), rel=0.2)
    assert lin < 1e-9
    # added scatter of standard deviation s is measured as s
    noise = rng.normal(0.0, 0.3, r.size)
    rms, worst, lin = radial_spread(r, rho + noise, 2e-3)
    assert lin == pytest.approx(0.3, rel=0.05) and worst > 0.3
    # particles on rings (one radius per bin): no slope, deviations from the bin mean
    rr = np.repeat([0.0105, 0.0125], 4)
    rms, worst, lin = radial_spread(rr, np.array([1, 3, 1, 3, 5, 5, 5, 5.0]), 2e-3)
    assert (rms, worst, lin) == (pytest.approx(np.sqrt(0.5)), pytest.approx(1.0), pytest.approx(np.sqrt(0.5)))


# --- coarse runs ------------------------------------------------------------------------------

@functools.cache
def _run(*overrides: str, shift: float = 0.0, out=None):
    """Coarse first-order run; ``shift`` moves the centre of the high-density disc along x
    (a deliberately asymmetric initial condition).  Returns (problem, result)."""
    cfg = config.load(CFG, [*COARSE, *overrides])
    pb = build_problem(cfg)
    if shift:
        p = pb.particles
        x = np.asarray(p.x)
        inside = (np.hypot(x[:, 0] - shift, x[:, 1]) <= cfg["case"]["r_interface"]) \
            & (np.asarray(p.kind) == int(Kind.FLUID))
        q = np.asarray(p.q).copy()
        q[:, 0] = np.where(inside, 1100.0, 1000.0) * np.asarray(p.vol)
        pb.particles = p.replace(q=jnp.asarray(q))
    res = run_problem(pb, cfg, out_dir=out, quiet=True)
    assert res.summary["status"] == "ok"
    assert res.summary["t_final"] == pytest.approx(cfg["time"]["t_end"], rel=1e-12)
    return pb, res


@pytest.mark.slow   # CI time; the blast config's fingerprint runs the case in the default suite
def test_coarse_run_symmetry_accuracy_far_field(tmp_path):
    pb, res = _run(out=tmp_path)
    m = res.summary["metrics"]
    assert m["n_fluid"] == 1237 and m["n_frozen"] == 707
    assert m["l1_rho_radial"] < L1_BOUND, m
    assert m["l1_rho_radial"] > 0.5 * L1_BOUND, m  # not vacuous: first order smears the waves
    assert m["radial_spread"] < SPREAD_BOUND, m
    assert m["radial_spread_linear"] < SPREAD_LINEAR_BOUND, m
    assert m["radial_spread_max"] < 2.5 * SPREAD_BOUND, m  # measured 0.086
    # the explosion: the post-shock density peak of the reference ~1048.9 at t = 5e-6
    assert 1045.0 < m["rho_ref_shock"] < 1052.0
    # the frozen far field never changes (positions, volumes, conserved states)
    p0, p1 = pb.particles, res.particles
    frozen = np.asarray(p0.kind) == int(Kind.FROZEN)
    assert np.array_equal(np.asarray(p1.kind), np.asarray(p0.kind))
    for f in ("x", "vol", "q"):
        assert np.array_equal(np.asarray(getattr(p1, f))[frozen], np.asarray(getattr(p0, f))[frozen]), f
    # fluid particles do move (Lagrangian frame) and stay inside the far-field ring
    x1 = np.asarray(p1.x)[~frozen]
    assert not np.array_equal(x1, np.asarray(p0.x)[~frozen])
    assert np.hypot(x1[:, 0], x1[:, 1]).max() < 0.1
    # mass: the only exchange is with the frozen far field, which at this coarse resolution
    # (kernel support 3 dx = 15 mm) sees the numerical precursor of the shock; measured -1.8e-7
    assert abs(res.summary["conservation"]["mass"]) < 2e-6
    assert (tmp_path / "density_vs_radius.png").stat().st_size > 0
    assert (tmp_path / "density_field.png").stat().st_size > 0


@pytest.mark.slow   # 27 s; CI time: conservation to round-off stays in test_solver's default tests
def test_mass_is_conserved_to_round_off_away_from_the_far_field():
    """With the waves far from the frozen band (r_interface = 0.02, t_end = 2e-6: the fluid
    near r = R is undisturbed to ~1e-6 kg/m^3), no flux crosses into the far field and the
    pairwise-antisymmetric fluxes (Lagrangian frame: no mass self-flux) conserve the total mass
    to round-off (measured 1.5e-16)."""
    _, res = _run("case.dx=4e-3", "case.r_interface=0.02", "time.t_end=2e-6")
    assert abs(res.summary["conservation"]["mass"]) < 1e-13


def test_symmetry_bound_detects_a_shifted_blast():
    """The symmetry bounds are not loose: the same run with the high-density disc shifted by
    dx/5 = 1 mm breaks them (measured radial_spread 0.0517, radial_spread_linear 0.0336), while
    its L1 error stays within the symmetric bound (0.0624)."""
    _, res = _run(shift=1e-3)
    m = res.summary["metrics"]
    assert m["radial_spread"] > SPREAD_BOUND * 1.05, m
    assert m["radial_spread_linear"] > SPREAD_LINEAR_BOUND * 1.6, m
    assert m["l1_rho_radial"] < L1_BOUND, m


# --- thesis-like runs (minutes each on 2 cores) -------------------------------------------------

@pytest.mark.slow
@pytest.mark.parametrize("layout", ["delaunay", "rings", "perturbed"])
def test_default_config_mlsph_ale_mood(layout):
    """The built-in config (MLSPH-ALE, quadratic reconstruction, MOOD, dx = 2e-3): the density
    keeps the radial symmetry for every layout (thesis Fig. 3.7), follows the reference and
    overshoots by less than 2 % (issue 14)."""
    cfg = config.load(CFG, [f"case.layout={layout}", "output.progress=false"])
    res = run_problem(build_problem(cfg), cfg, quiet=True)
    s = res.summary
    assert s["status"] == "ok" and s["t_final"] == pytest.approx(1e-5, rel=1e-12)
    m = s["metrics"]
    b = SLOW_BOUNDS[layout]
    assert m["l1_rho_radial"] < b[0] and m["radial_spread"] < b[1] and m["radial_spread_linear"] < b[2], m
    assert m["overshoot"] < b[3], m
    assert s["mood"]["unresolved_stages"] == 0
    assert abs(s["conservation"]["mass"]) < 1e-8


#: layout -> (l1_rho_radial, radial_spread, radial_spread_linear, overshoot) bounds for the default
#: config, ~25-30 % above the measured values (in the comments; the overshoot at issue 14's 2 %,
#: on the rings at 0.7 %, below SPH-ALE's 1.44 % there; MOOD flagged at most 17 % of the
#: particles in a stage, with no unresolved stage).  The thesis'
#: SPH-ALE gave 0.0293 / 0.0285 / 0.0113, 0.0256 / 0.00031 / 0.00021 and 0.0294 / 0.0279 / 0.0101.
SLOW_BOUNDS = {
    "delaunay": (0.028, 0.038, 0.016, 0.02),    # 0.0218, 0.0300, 0.0123, 0.0174
    "rings": (0.025, 0.002, 0.0016, 0.007),     # 0.0198, 0.00157, 0.00124, 0.0045 (one ring per bin)
    "perturbed": (0.028, 0.038, 0.015, 0.02),   # 0.0216, 0.0296, 0.0113, 0.0165
}
