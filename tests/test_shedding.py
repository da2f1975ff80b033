"""Vortex shedding behind the cylinder (issue 17 items 5 and 7; thesis §4.5.3, Table 4.2): the
whole-period statistics of :mod:`mlsph_jax.periodic` on signals with known frequency, amplitude
and mean, the symmetry-breaking trigger of the ``cylinder`` case, its bad input, and (slow) the
built-in unsteady configs (Re = 100 and 185) against the Table 4.2 targets."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mlsph_jax import config as config_mod
from mlsph_jax.cases import build_problem
from mlsph_jax.errors import ConfigError
from mlsph_jax.periodic import spectral_frequency, upward_crossings, whole_period_statistics
from mlsph_jax.testing import CONFIG_DIR

# --- whole-period statistics on synthetic signals ------------------------------------------------


def _shedding_like(t, f, amp, mean_cd, phase=0.4, growth=0.0):
    """A lift sin of frequency f (amplitude amp, with an optional exponential onset) and a drag
    oscillating at 2 f about mean_cd."""
    envelope = 1.0 - np.exp(-growth * t) if growth else 1.0
    cl = amp * envelope * np.sin(2 * np.pi * f * t + phase)
    cd = mean_cd + 0.1 * amp * np.sin(4 * np.pi * f * t + 2 * phase + 0.3)
    return cl, cd


@pytest.mark.parametrize("samples_per_period", [12, 24])
def test_statistics_of_a_sinusoid_off_the_fft_bins(samples_per_period):
    """St = 0.1653 sampled over a window of 150 (not a whole number of periods, so the frequency
    falls between FFT bins: 24.8 periods, bin width 1/150 = 4 % of f): the zero-crossing frequency
    is exact to 1e-5 relative, the interpolated spectral peak to 2 % of a bin, the mean drag over
    whole periods to 1e-6, the parabola-refined amplitude to 1e-3 (the raw sample maximum would be
    low by up to 1 - cos(pi / n) = 3.4 % at 12 samples per period) and the rms to amp / sqrt 2."""
    f, amp, cd0 = 0.1653, 0.3325, 1.3587
    period = 1.0 / f
    t = np.arange(0.0, 150.0, period / samples_per_period)
    cl, cd = _shedding_like(t, f, amp, cd0)
    w = whole_period_statistics(t, cl, 0.0, {"cd": cd})
    n_bins = f * (t[-1] - t[0])
    assert abs(n_bins - round(n_bins)) > 0.2        # the frequency is not an FFT bin of the record
    assert abs(w["frequency"] - f) <= 1e-5 * f
    assert abs(w["frequency_spectral"] - f) <= 0.02 / (w["window"][1] - w["window"][0])
    assert abs(w["means"]["cd"] - cd0) <= 1e-6
    assert abs(w["mean"]) <= 1e-6
    assert abs(w["amplitude"] - amp) <= 1e-3 * amp
    assert abs(w["rms"] - amp / math.sqrt(2.0)) <= 1e-4 * amp
    assert w["n_periods"] == 23 and abs(w["samples_per_period"] - samples_per_period) < 0.1
    # the raw FFT peak (no interpolation) is off by up to half a bin: the refinement matters
    spec = np.abs(np.fft.rfft(cl - cl.mean())) ** 2
    raw = np.argmax(spec[1:]) + 1
    assert abs(raw / (t[-1] - t[0] + t[1]) - f) > 10 * abs(w["frequency_spectral"] - f)


def test_statistics_use_whole_periods_after_the_transient():
    """A lift with an exponential onset and a nonzero mean (0.05), sampled unevenly: the window
    starts at the first upward crossing after t0 and ends at the last; the mean lift is the offset
    (not biased by a partial period) and the amplitude drift reports the onset if t0 is too early."""
    rng = np.random.default_rng(3)
    f, amp = 0.2, 0.5
    t = np.sort(np.concatenate([[0.0, 200.0], rng.uniform(0.0, 200.0, 4000)]))
    cl = 0.05 + amp * (1.0 - np.exp(-t / 8.0)) * np.sin(2 * np.pi * f * t)
    late = whole_period_statistics(t, cl, 100.0)
    assert late["window"][0] >= 100.0 and late["window"][1] <= 200.0
    assert abs(late["frequency"] - f) <= 1e-4 * f
    assert abs(late["mean"] - 0.05) <= 1e-4 and abs(late["amplitude"] - amp) <= 1e-3 * amp
    assert abs(late["amplitude_drift"]) < 1e-3
    early = whole_period_statistics(t, cl, 0.0)
    assert early["amplitude_drift"] > 0.2 and "not saturated" in early["note"]   # still growing: the transient is in it


def test_statistics_say_why_there_are_none():
    """No numbers (and no NaN) when the record cannot give them: a symmetric flow's round-off lift,
    a record shorter than two periods after the transient, nothing after it, too few samples per
    period; each note says which."""
    t = np.linspace(0.0, 100.0, 401)
    cl, _ = _shedding_like(t, 0.165, 0.33, 1.35)
    cases = {
        "no oscillation": (t, 1e-13 * np.sin(t), 0.0),
        "too short: 1 whole period": (t, cl, 90.0),
        "too short: 0 samples": (t, cl, 150.0),
        "under-resolved: 6.07 samples per period (period 6.061)": (t[::4], cl[::4], 0.0),
    }
    for words, (tt, y, t0) in cases.items():
        w = whole_period_statistics(tt, y, t0)
        assert words in w["note"] and "frequency" not in w, (words, w)


def test_crossings_and_spectrum_helpers():
    """upward_crossings of sin(t - 0.3) are at 0.3 + 2 pi k to third order in the step h (the
    crossing is the inflection point: |error| <= h^3 / 8 for a unit sine, against h^2 / 8 for a
    generic root), so the period needs no FFT bin; spectral_frequency of a pure tone between bins to
    2 % of a bin (the Gaussian interpolation's bias on a Hann window; measured 1.2-1.6 %)."""
    t = np.linspace(0.0, 30.0, 301)
    h = t[1] - t[0]
    c = upward_crossings(t, np.sin(t - 0.3))
    np.testing.assert_allclose(c, 0.3 + 2 * np.pi * np.arange(len(c)), atol=h ** 3 / 8)
    assert upward_crossings(t, np.sin(t - 0.3) - 0.5).size == 5      # crossings of y = 0.5: 5 as well
    f = 10.37 / 30.0                        # (far from DC: the image at -f leaks little)
    assert abs(spectral_frequency(t, np.cos(2 * np.pi * f * t)) - f) <= 0.02 / 30.0


# --- the trigger -------------------------------------------------------------------------------------

SMALL = ("case.n_theta=32", "case.r_far=4.0", "case.re=100", "case.mach=0.2", "case.steady_tol=0",
         "time.local_time_stepping=false", "time.t_end=0.1", "output.snapshots=2", "output.plots=false",
         "output.progress=false")


def test_trigger_breaks_the_mirror_symmetry():
    """Without the trigger the coarse Re = 100 initial state is its own mirror image (C_L < 1e-12
    of C_D); with it C_L is far above round-off before any step (measured -0.044; the shipped
    config's run then sheds, slow test).  The trigger's field is divergence-free and carries no
    circulation in the plane (a shielded vortex), and it leaves the far field at the free stream.
    (No run here: a run only repeats the initial asymmetry at this length.)"""
    import jax
    import jax.numpy as jnp

    from mlsph_jax.cases.cylinder import trigger_velocity
    from mlsph_jax.state import Kind

    cfg1 = config_mod.load(CONFIG_DIR / "cylinder.toml", [*SMALL, "case.perturbation=0.3"])
    pb1 = build_problem(cfg1)
    pb0 = build_problem(config_mod.load(CONFIG_DIR / "cylinder.toml", list(SMALL)))
    d0 = pb0.diagnostics(pb0.particles, 0.0, pb0.params)
    d1 = pb1.diagnostics(pb1.particles, 0.0, pb1.params)
    assert abs(d0["cl"]) < 1e-12 * abs(d0["cd"]), d0
    assert abs(d1["cl"]) > 1e-2, d1
    # the initial states differ only in the fluid's momentum and energy
    q0, q1 = np.asarray(pb0.particles.q), np.asarray(pb1.particles.q)
    frozen = np.asarray(pb1.particles.kind) != int(Kind.FLUID)
    assert np.array_equal(q0[frozen], q1[frozen]) and np.array_equal(q0[:, 0], q1[:, 0])
    # divergence-free (exact derivatives by autodiff) with zero net vorticity (spectrally accurate
    # trapezoidal sum over a box of +- 5 cores about the vortex), peak swirl speed 0.3 U_inf
    cfg = config_mod.load(CONFIG_DIR / "cylinder.toml", [*SMALL, "case.perturbation=0.3"])
    g = np.linspace(-1.0, 4.0, 101)
    X, Y = np.meshgrid(g, g - 1.5, indexing="ij")
    pts = jnp.asarray(np.c_[X.ravel(), Y.ravel()])
    J = jax.vmap(jax.jacfwd(lambda x: trigger_velocity(cfg, x[None], jnp)[0]))(pts)
    div, curl = J[:, 0, 0] + J[:, 1, 1], J[:, 1, 0] - J[:, 0, 1]
    h = g[1] - g[0]
    assert float(jnp.max(jnp.abs(div))) < 1e-12
    assert abs(float(jnp.sum(curl)) * h * h) < 1e-8 * float(jnp.max(jnp.abs(curl)))
    speed = np.hypot(*np.asarray(trigger_velocity(cfg, np.asarray(pts))).T)
    assert abs(speed.max() - 0.3) < 1e-3


@pytest.mark.parametrize("overrides, words", [
    (("case.perturbation=0.7",), ["case.perturbation=0.7", "[0.0, 0.5]"]),
    (("case.perturbation=-0.1",), ["case.perturbation=-0.1", "[0.0, 0.5]"]),
    (("case.perturbation=0.2", "case.perturbation_x=0.8"),
     ["case.perturbation_x=0.8", "case.perturbation_core=0.5", "into the body", ">= 0.5"]),
    (("case.perturbation=0.2", "case.perturbation_x=1.4"),
     ["case.perturbation_x=1.4", "two core radii", ">= 0.5"]),
    (("case.perturbation=0.2", "time.local_time_stepping=true"),
     ["case.perturbation=0.2", "time.local_time_stepping=true", "pseudo-time"]),
    (("case.perturbation=0.2", "case.perturbation_x=38"),
     ["case.perturbation_x=38", "case.r_far=40", "far field", "< case.r_far"]),
    (("case.perturbation_core=0",), ["case.perturbation_core=0", "> 0"]),
    (("case.transient=-1",), ["case.transient=-1", ">= 0"]),
])
def test_bad_trigger_and_statistics_input_names_the_key(overrides, words):
    """Out-of-range amplitude, a trigger vortex reaching into the body or the far field, a
    non-positive core, a negative transient: ConfigError naming the key, value and what is allowed."""
    with pytest.raises(ConfigError) as e:
        config_mod.load(CONFIG_DIR / "cylinder.toml", list(overrides))
    for w in words:
        assert w in str(e.value), (w, str(e.value))


def _sinusoid(n_per=12, f=0.165, amp=0.3, spp=24, t0=0.0):
    t = np.arange(t0, t0 + n_per / f, 1.0 / (f * spp))
    return t, amp * np.sin(2 * np.pi * f * t + 0.4)


@pytest.mark.parametrize("make, words", [
    (lambda t, y: (t, y + 0.09 * np.sin(2 * np.pi * 1.7 * t)), ["irregular"]),           # a ripple: extra crossings
    (lambda t, y: (np.delete(t, np.s_[60:110]), np.delete(y, np.s_[60:110])), ["gap"]),   # a sampling gap
    (lambda t, y: (t, y * np.exp(-t / 30.0)), ["not saturated"]),                          # a decaying lift
    (lambda t, y: (t, np.where(t > 40, np.nan, y)), ["non-finite", "y"]),
    (lambda t, y: (t, 1e-7 * np.sign(np.sin(37.0 * t))), ["no oscillation"]),                # round-off flicker
])
def test_statistics_refuse_signals_they_cannot_measure(make, words):
    """Each of these would give a wrong Strouhal number (measured before the checks: 0.259 with the
    ripple, 0.141 across the gap, a decaying lift reported as shedding); each now gives a note and
    no numbers."""
    t, y = make(*_sinusoid())
    w = whole_period_statistics(t, y, 0.0, {"cd": np.full_like(t, 1.2)})
    assert "frequency" not in w and all(x in w["note"] for x in words), w
    assert "frequency" in whole_period_statistics(*_sinusoid(), 0.0, {"cd": np.full_like(_sinusoid()[0], 1.2)})


def test_rms_is_the_fluctuation_about_the_mean():
    t, y = _sinusoid()
    w = whole_period_statistics(t, 0.5 + y, 0.0)
    assert abs(w["mean"] - 0.5) < 1e-6 and abs(w["rms"] - 0.3 / math.sqrt(2.0)) < 1e-4


def test_cylinder_statistics_and_the_run_hook():
    """``shedding_statistics`` scales the frequency by D / U (St) and names the metrics; the run
    hook writes a note, not numbers, for a failed run or a hook that raises."""
    from mlsph_jax.cases.cylinder import shedding_statistics

    t, cl = _sinusoid(f=0.2)
    s = shedding_statistics({"t": t, "cl": cl, "cd": np.full_like(t, 1.3)}, 0.0, D=2.0)
    assert abs(s["metrics"]["st"] - 0.4) < 1e-6 and abs(s["metrics"]["cd_mean"] - 1.3) < 1e-12
    assert set(s["metrics"]) >= {"st", "st_spectral", "cd_mean", "cl_mean", "cl_amplitude", "cl_rms"}
    import dataclasses

    from mlsph_jax.simulation import Simulation

    cfg = config_mod.load(CONFIG_DIR / "poiseuille.toml", ["case.ny=10", "case.nx=8", "time.t_end=0.02"])

    def broken(series):
        raise ValueError("broken statistics")

    pb = dataclasses.replace(build_problem(cfg), series_statistics=broken)
    out = Simulation(pb, cfl=0.3).run(None, snapshots=2, progress=False, plots=False).summary
    assert out["status"] == "ok" and "broken statistics" in out["series_statistics"]["note"]
    assert len(out["timeseries"]["t"]) == 3


# --- the built-in unsteady config (slow) ---------------------------------------------------------

#: Issue 17's Re = 100 targets (thesis Table 4.2, present method 1.3587, +-0.3325, 0.1653):
#: metric -> (value, relative tolerance).
RE100_TARGETS = {"cd_mean": (1.35, 0.03), "cl_amplitude": (0.33, 0.10), "st": (0.165, 0.03)}


def _builtin_shedding_metrics(name: str) -> dict:
    """Run the built-in config ``name`` as shipped; assert it sheds (>= 5 whole periods after its
    transient, the C_L amplitude settled to 5 % over them) and return its statistics' metrics."""
    from mlsph_jax.simulation import run_problem

    cfg = config_mod.load(CONFIG_DIR / f"{name}.toml", ["output.plots=false", "output.progress=false"])
    s = run_problem(build_problem(cfg), cfg, out_dir=None, quiet=True).summary
    stats = s["series_statistics"]
    assert "metrics" in stats, stats
    m = stats["metrics"]
    assert m["n_periods"] >= 5 and abs(stats["cl_amplitude_drift"]) < 0.05, stats
    return m


def _xfail_missed_targets(m: dict, targets: dict, where: str) -> None:
    missed = {k: (m[k], v) for k, v in targets.items() if abs(m[k] - v[0]) > v[1] * v[0]}
    if missed:
        pytest.xfail(f"Table 4.2 targets missed {where} (issue 17 open): {missed}")


@pytest.mark.slow
def test_builtin_re100_config_sheds_and_meets_table_4_2():
    """configs/cylinder_re100.toml as shipped (48 on the body, 1,920 particles, far field at 40 D,
    Mach 0.2, cubic reconstruction, trigger on, t_end = 150, statistics over the whole lift periods
    after t = 100): the wake sheds (St, mean C_D and the C_L amplitude over >= 5 whole periods, the
    amplitude settled to 5 % over them); against the Table 4.2 targets (mean C_D 1.35 +- 3 %, C_L
    amplitude 0.33 +- 10 %, St 0.165 +- 3 %) a missed target is reported as an expected failure
    with the measured values.  Measured with rcond 0.01, before decision 75 (docs/validation.md
    "Vortex shedding"; 21,011 steps, 28.6 min at load 3.4-5.8): 6 periods, drift 2.5 %, St 0.1407,
    mean C_D 1.2455, C_L amplitude 0.1960: all three missed (the wake at n_theta = 48 behaves like Re ~ 70).
    Since decision 108 (2026-12-06, 13 min): 6 periods, drift 2.4 %, St 0.1411, mean C_D 1.2608, C_L
    amplitude 0.1990: still all three missed."""
    m = _builtin_shedding_metrics("cylinder_re100")
    _xfail_missed_targets(m, RE100_TARGETS, "at n_theta = 48")


#: Thesis Table 4.2 at Re = 185 (present method; C_L as its rms there) with issue 17's tolerances
#: ("Re = 185 against Table 4.2 likewise"): metric -> (value, relative tolerance).
RE185_TARGETS = {"cd_mean": (1.3398, 0.03), "cl_rms": (0.4447, 0.10), "st": (0.1937, 0.03)}


@pytest.mark.slow
def test_builtin_re185_config_sheds_and_meets_table_4_2():
    """configs/cylinder_re185.toml as shipped (cylinder_re100's layout and scheme at Re = 185,
    t_end = 150, statistics over the whole lift periods after t = 100): the wake sheds (>= 5 whole
    periods, amplitude settled to 5 %); against Table 4.2 (St 0.1937 +- 3 %, mean C_D 1.3398 +- 3 %,
    C_L rms 0.4447 +- 10 %) a missed target is reported as an expected failure with the measured
    values.  Measured (docs/validation.md "The no-slip wall's normal velocity"; 2026-12-06, 21,619
    steps, 10 min): 7 periods, drift 0.02 %, St 0.1638, mean C_D 1.2091, C_L rms 0.2524: all three
    missed (-15.4 %, -9.8 %, -43.2 %; at n_theta = 80 C_D and C_L rms were met before decision 108)."""
    m = _builtin_shedding_metrics("cylinder_re185")
    _xfail_missed_targets(m, RE185_TARGETS, "at n_theta = 48")
