"""MOOD a-posteriori order reduction (thesis §3.6.3, eq. 3.12-3.13; mlsph_jax.mood).

* the detectors: EOS-aware PAD and the relaxed discrete maximum principle (NAD);
* a constructed case where the unlimited degree-3 candidate creates new extrema and MOOD
  removes them, touching only particles near the discontinuities;
* the built-in Riemann configs (MOOD on): L1 errors at least 1.5x below first order at the
  same particle count and overshoots below 2 % of the jump (the measured values are in
  docs/validation.md);
* R2's 5e9 Pa left state runs to t_end with positive density; the summary and snapshots carry
  the MOOD statistics and the PPD map;
* gradients through a MOOD-limited run are finite.
"""

from __future__ import annotations

import dataclasses
import functools
import json

import h5py
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mlsph_jax import Domain, Kind, Params, config, make_particles
from mlsph_jax import neighbors as nb
from mlsph_jax.cases import build_problem
from mlsph_jax.eos import get_eos, to_conservative
from mlsph_jax.errors import InputError
from mlsph_jax.integrate import StepControl, _euler, initial_carry, make_chunk, static_geometry
from mlsph_jax.mood import admissible, detect, mood_substep, nad_fields, stencil_bounds
from mlsph_jax.rhs import rhs
from mlsph_jax.scheme import Scheme
from mlsph_jax.simulation import run_problem

GAS = Params({"eos.gamma": 1.4})


# ------------------------------------------------------------------------------- detectors
def test_pad_is_eos_aware():
    rho = jnp.array([1.0, 1.0, -1.0, 1.0])
    p = jnp.array([1.0, -0.5, 1.0, jnp.nan])
    vel = jnp.zeros((4, 1))
    gas = get_eos("ideal_gas")
    U = to_conservative(rho, vel, p, gas, GAS)
    ok = admissible(U, Scheme(eos="ideal_gas"), GAS)
    assert ok.tolist() == [True, False, False, False]
    # stiffened gas: p + pc > 0 is admissible even for p < 0
    sg = Params({"eos.gamma": 4.4, "eos.pc": 6e8})
    U = to_conservative(jnp.array([1000.0, 1000.0]), jnp.zeros((2, 1)), jnp.array([-1e8, -7e8]),
                        get_eos("stiffened_gas"), sg)
    assert admissible(U, Scheme(eos="stiffened_gas"), sg).tolist() == [True, False]
    # Tait: any positive density is admissible, also with p <= 0 (thesis R1 right state p = 0)
    tait = Params({"eos.rho0": 1000.0, "eos.c0": 1466.0, "eos.gamma": 7.0, "eos.p0": 0.0})
    U = jnp.array([[990.0, 0.0], [1000.0, 0.0], [-1.0, 0.0]])
    assert admissible(U, Scheme(eos="tait"), tait).tolist() == [True, True, False]


def test_nad_relaxed_maximum_principle():
    """eq. 3.12-3.13: the bounds are the stencil extrema widened by max(1e-4, 1e-3 range)."""
    scheme = Scheme(eos="ideal_gas", mood_variables=("rho",))
    idx = jnp.array([[0, 1, 3], [1, 0, 2], [2, 1, 3]])
    mask = jnp.array([[True, True, False], [True, True, True], [True, True, False]])
    rho = jnp.array([1.0, 2.0, 3.0])
    U = to_conservative(rho, jnp.zeros((3, 1)), jnp.ones(3), get_eos("ideal_gas"), GAS)
    lo, hi = stencil_bounds(nad_fields(U, scheme, GAS), idx, mask)
    np.testing.assert_array_equal(np.asarray(lo[:, 0]), [1.0, 1.0, 2.0])
    np.testing.assert_array_equal(np.asarray(hi[:, 0]), [2.0, 3.0, 3.0])
    # particle 0: range 1 -> delta 1e-3; particle 2: range 1 -> delta 1e-3
    cand = to_conservative(jnp.array([2.0009, 0.5, 1.9989]), jnp.zeros((3, 1)), jnp.ones(3),
                           get_eos("ideal_gas"), GAS)
    assert detect(cand, (lo, hi), scheme, GAS).tolist() == [False, True, True]
    flat = dataclasses.replace(scheme, mood_delta_rel=0.0, mood_delta_abs=0.0)
    # the default floor is scaled by the largest magnitude: 1e-4 * 3 = 3e-4 < 1e-3 here
    assert dataclasses.replace(scheme, mood_delta_floor="absolute").mood_delta_floor == "absolute"
    assert detect(cand, (lo, hi), flat, GAS).tolist() == [True, True, True]


def test_mood_scheme_errors_name_the_key():
    with pytest.raises(InputError, match="scheme.mood_variables"):
        Scheme(mood_variables=("density",))
    with pytest.raises(InputError, match="scheme.mood_max_iter"):
        Scheme(mood_max_iter=0)
    with pytest.raises(InputError, match="reconstruction_degree"):
        Scheme(limiter="mood", reconstruction_degree=0)
    with pytest.raises(config.ConfigError, match="scheme.mood_variables"):
        config.load("configs/sod_ideal_gas.toml", ['scheme.mood_variables=["temperature"]'])


# ------------------------------------------------------------------ constructed overshoot case
def _pulse(n=80):
    """1D periodic advection of a density pulse (ideal gas, u = 1, p = 1): the unlimited
    cubic reconstruction overshoots at both jumps."""
    dx = 1.0 / n
    x = (np.arange(n) + 0.5) * dx
    rho = np.where((x > 0.3) & (x < 0.6), 4.0, 1.0)
    U = to_conservative(jnp.asarray(rho), jnp.ones((n, 1)), jnp.ones(n), get_eos("ideal_gas"), GAS)
    p = make_particles(x[:, None], np.full(n, dx), U)
    domain = Domain((0.0,), (1.0,), (True,))
    return p, domain, x


def _substep(scheme, p, domain, dt):
    h = scheme.beta * p.vol
    _, nl = nb.allocate(np.asarray(p.x), np.asarray(h), domain, support=scheme.support)
    geom = static_geometry(p, nl, scheme, domain)

    def euler(z):
        return _euler(z, dt, rhs(z, GAS, geom, scheme))

    return geom, euler


def test_mood_rejects_the_overshooting_candidate():
    p, domain, x = _pulse()
    base = Scheme(eos="ideal_gas", reconstruction_degree=3, degree=3, beta=2.0, mood_variables=("rho",))
    dt = 0.4 / 80 / (1.0 + np.sqrt(1.4 / 1.0))
    geom, euler = _substep(base, p, domain, dt)
    p3 = p.replace(ppd=jnp.full_like(p.ppd, 3))
    unlimited = euler(p3)
    lo, hi = stencil_bounds(nad_fields(p.U, base, GAS), geom.idx, geom.mask)
    rho_u = np.asarray(unlimited.q[:, 0] / unlimited.vol)
    lo, hi = np.asarray(lo[:, 0]), np.asarray(hi[:, 0])
    delta = np.maximum(1e-4, 1e-3 * (hi - lo))
    new_extrema = (rho_u < lo - delta) | (rho_u > hi + delta)
    assert new_extrema.sum() >= 2, "the constructed case must overshoot without MOOD"

    mood = dataclasses.replace(base, limiter="mood")
    E, ppd, n_evals, unresolved = jax.jit(lambda z: mood_substep(z, GAS, dt, geom, mood, euler))(p3)
    rho_m = np.asarray(E.q[:, 0] / E.vol)
    assert not bool(jnp.any(unresolved)) and int(n_evals) >= 2
    assert np.all((rho_m >= lo - delta) & (rho_m <= hi + delta))
    demoted = np.asarray(ppd) == 0
    assert demoted[new_extrema].all()
    # demotion is local: only particles within a few smoothing lengths of the two jumps
    dist = np.minimum(np.abs(x - 0.3), np.abs(x - 0.6))
    assert np.all(dist[demoted] < 4 * 2.0 / 80)
    # particles whose whole stencil is unaffected keep the high-order candidate (to round-off:
    # the two are compiled differently)
    far = dist > 10 * 2.0 / 80
    np.testing.assert_allclose(np.asarray(E.q)[far], np.asarray(unlimited.q)[far], rtol=1e-14, atol=1e-16)


def test_an_inadmissible_parachute_candidate_leaves_the_stage_unresolved():
    """First order is MOOD's last resort: when even the degree-0 candidate fails PAD (here a time
    step ~40x the CFL limit drives densities negative), the stage is reported unresolved instead
    of being accepted."""
    p, domain, _ = _pulse()
    mood = Scheme(eos="ideal_gas", reconstruction_degree=2, beta=2.0, limiter="mood")
    dt = 40 * 0.4 / 80 / (1.0 + np.sqrt(1.4 * 4.0))
    geom, euler = _substep(mood, p, domain, dt)
    first = euler(p.replace(ppd=jnp.zeros_like(p.ppd)))
    assert not np.all(np.asarray(admissible(first.q / first.vol[:, None], mood, GAS))), \
        "the constructed step must make the first-order candidate inadmissible"
    E, ppd, _, unresolved = jax.jit(lambda z: mood_substep(z, GAS, dt, geom, mood, euler))(p)
    assert bool(jnp.any(unresolved & (ppd == 0)))
    _, euler_cfl = _substep(mood, p, domain, dt / 40)
    fine = mood_substep(p, GAS, dt / 40, geom, mood, euler_cfl)[3]     # a CFL step: resolved
    assert not bool(jnp.any(fine))


# ---------------------------------------------------------------------- built-in Riemann configs
CONFIGS = {"r1": "configs/riemann_r1_tait.toml", "r2": "configs/riemann_r2_tammann.toml",
           "sod": "configs/sod_ideal_gas.toml"}


@functools.cache
def _run(case: str, *over: str):
    cfg = config.load(CONFIGS[case], ["output.progress=false", *over])
    res = run_problem(build_problem(cfg), cfg, quiet=True)
    assert res.summary["status"] == "ok"
    return res


# slow (CI time): MOOD's detection, parachute and positivity stay in the default suite
# (test_mood_rejects_the_overshooting_candidate, test_strong_r2_runs_to_the_end_with_positive_density)
@pytest.mark.slow
@pytest.mark.parametrize("case", ["r1", "r2", "sod"])
def test_mood_beats_first_order_without_overshoot(case):
    mood = _run(case)
    assert mood.summary["scheme"]["limiter"] == "mood"
    first = _run(case, "scheme.reconstruction_degree=0", "scheme.limiter=none").summary["metrics"]
    m = mood.summary["metrics"]
    for k in ("l1_rho", "l1_u", "l1_p"):
        assert m[k] * 1.5 < first[k], (k, m[k], first[k])
    assert m["overshoot"] < 0.02, m
    # not vacuous: the config's reconstruction (cubic for R1, quadratic for R2 and Sod) without the limiter
    # overshoots (or fails) on the same case
    try:
        raw = _run(case, "scheme.limiter=none").summary["metrics"]
        assert raw["overshoot"] > 0.02 or raw["l1_rho"] > m["l1_rho"]
    except Exception as e:  # R2 and Sod blow up without a limiter
        assert "non-finite" in str(e) or "density" in str(e)


def test_strong_r2_runs_to_the_end_with_positive_density(tmp_path):
    cfg = config.load(CONFIGS["r2"], ["output.progress=false", "output.snapshots=2"])
    assert cfg["case"]["left"]["p"] == 5e9
    res = run_problem(build_problem(cfg), cfg, out_dir=tmp_path, quiet=True)
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["status"] == "ok" and s["t_final"] == pytest.approx(7e-5, rel=1e-12)
    fluid = np.asarray(res.particles.kind) == Kind.FLUID
    rho = np.asarray(res.particles.q[:, 0] / res.particles.vol)[fluid]
    assert np.all(np.isfinite(rho)) and rho.min() > 0
    mood = s["mood"]
    assert 0 < mood["flagged_fraction_mean"] <= mood["flagged_fraction_max"] < 0.5
    assert mood["rhs_evaluations_per_stage"] >= 1 and mood["unresolved_stages"] == 0
    with h5py.File(tmp_path / "fields.h5") as f:
        last = sorted(f["snapshots"], key=int)[-1]
        ppd = f["snapshots"][last]["ppd"][...]
    assert set(np.unique(ppd)) <= {0, 2} and (ppd == 0).any() and (ppd == 2).any()


def test_gradient_through_a_mood_run_is_finite():
    """d(sum of V rho u^2)/d(c0) through a few MOOD-limited Lagrangian SSP-RK3 steps of R1."""
    cfg = config.load(CONFIGS["r1"], ["case.n=40", "output.progress=false"])
    pb = build_problem(cfg)
    h = pb.scheme.beta * np.asarray(pb.particles.vol)
    nspec, _ = nb.allocate(np.asarray(pb.particles.x), h, pb.domain, support=pb.scheme.support, headroom=2.0,
                           cell_size=pb.scheme.support * float(h.max()) * 2.5)
    chunk = make_chunk(pb.scheme, pb.domain, StepControl(cfl=0.3), 6, nspec=nspec)

    def loss(c0):
        params = Params({**{k: pb.params[k] for k in pb.params}, "eos.c0": c0})
        out = chunk(initial_carry(pb.particles), params, None, jnp.asarray(1e-5))
        q = out.particles.q
        return jnp.sum(q[:, 1] ** 2 / q[:, 0]), out

    (val, out), g = jax.value_and_grad(loss, has_aux=True)(jnp.asarray(1466.0))
    assert int(out.status) == 0 and int(out.step) == 6
    assert float(out.mood[0]) > 0  # MOOD was active
    assert np.isfinite(float(g)) and float(g) != 0.0
