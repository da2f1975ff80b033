"""Time-averaged objectives of differentiated runs (``cd_mean``, ``cl_rms``, ``ke_mean``, ...;
mlsph_jax.differentiable ``average``/``window``, mlsph_jax.sensitivity; issue 17 item 5): the
in-run trapezoidal average equals the host's average of the per-step values of the same run, its
derivative matches central finite differences, and bad windows / names are refused."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mlsph_jax import config as config_mod
from mlsph_jax.cases import build_problem
from mlsph_jax.differentiable import make_simulate, window_weights, with_param
from mlsph_jax.errors import InputError
from mlsph_jax.sensitivity import make_objective, objective_names, sensitivity, time_average
from mlsph_jax.testing import CONFIG_DIR, couette_problem

ALPHA = "geometry.body.alpha"
#: The coarse ellipse of tests/test_shape_sensitivity.py (448 particles), linear reconstruction to
#: keep the compilation of the default test short.
SMALL_ELLIPSE = ("case.n_theta=32", "case.r_far=3.0", "case.mach=0.2", "output.plots=false", "output.progress=false",
                 "time.local_time_stepping=false", "case.body=\"ellipse\"", "case.aspect=2.0", "case.alpha=5.0")


def host_average(t, f, a, b):
    """The host's time average over [a, b] of the samples f(t) (t increasing): the trapezoidal
    rule on the samples inside (a, b) plus the window ends linearly interpolated, / (b - a)."""
    t, f = np.asarray(t, float), np.asarray(f, float)
    inside = (t > a) & (t < b)
    tt = np.concatenate([[a], t[inside], [b]])
    ff = np.concatenate([[np.interp(a, t, f)], f[inside], [np.interp(b, t, f)]])
    return float(np.sum(0.5 * (ff[1:] + ff[:-1]) * np.diff(tt)) / (b - a))


@pytest.mark.parametrize("window", [None, (0.0, 1.0), (0.13, 0.71), (0.3, 0.3 + 1e-3), (0.95, 1.0),
                                    (0.35, 0.35 + 1e-12)])
def test_window_weights_are_the_trapezoidal_rule_and_exact_for_linear_data(window):
    """sum w_k = 1; for f(t) = 3 - 2t (linear) the weighted sum is its exact mean over the window,
    3 - (a + b); for random samples it is the host trapezoid with interpolated ends."""
    n, dt = 10, 0.1
    w = window_weights(n, dt, window)
    a, b = window or (0.0, 1.0)
    t = np.arange(n + 1) * dt
    assert w.shape == (n + 1,) and np.all(w >= 0)
    assert abs(w.sum() - 1.0) < 1e-13
    assert abs(w @ (3 - 2 * t) - (3 - (a + b))) < 1e-13
    f = np.random.default_rng(1).normal(size=n + 1)
    assert abs(w @ f - host_average(t, f, a, b)) < 1e-12
    if window is not None and window[0] > 0:
        assert w[0] == 0.0    # outside the window: no weight (the run skips the evaluation)


@pytest.mark.parametrize("a, b", [(0.3, 0.7), (0.3 + 1e-12, 0.7 - 1e-12), (0.7, 0.9)])
def test_window_ends_on_step_times_give_no_round_off_weights(a, b):
    """Window ends on (or within 1e-9 dt of) a step time: the steps outside get weight exactly 0
    (0.3 / 0.1 = 2.9999999999999996 made a 1e-32 weight for step 2) and the rest is the plain
    trapezoid, w = dt / (b - a) x (1/2, 1, ..., 1, 1/2)."""
    n, dt = 10, 0.1
    w = window_weights(n, dt, (a, b))
    k0, k1 = round(a / dt), round(b / dt)
    assert np.all(w[:k0] == 0.0) and np.all(w[k1 + 1:] == 0.0), w
    ref = np.full(k1 - k0 + 1, 1.0)
    ref[[0, -1]] = 0.5
    np.testing.assert_allclose(w[k0:k1 + 1], ref / (k1 - k0), rtol=1e-12)


def test_steps_outside_the_window_are_not_evaluated_t0_included():
    """A quantity that is infinite at t = 0 (1 / t) averaged over a window that starts later:
    the t = 0 term is skipped like every step outside the window (it was 0 x inf = NaN), and the
    mean is the trapezoid of 1 / t_k over the window's steps."""
    pb = couette_problem()
    sim0 = make_simulate(pb, n_steps=30)
    win = (5 * sim0.dt, 20 * sim0.dt)
    sim = make_simulate(pb, n_steps=30, average=lambda p, t, P: {"inv": 1.0 / jnp.asarray(t)}, window=win)
    out = sim(pb.params, pb.particles)
    w = window_weights(30, sim.dt, win)
    k = np.arange(1, 31)
    expected = w[1:] @ (1.0 / (k * sim.dt))
    assert abs(float(time_average(out.averages["inv"], "mean")) - expected) <= 1e-13 * expected


def test_couette_windowed_ke_mean_matches_host_and_finite_differences():
    """Start-up Couette flow: ``ke_mean`` over a window whose ends fall between steps, (a) equals
    the host's trapezoidal average of the kinetic energy recorded after every step of the same
    run (to round-off), and (b) its reverse-mode derivative w.r.t. the viscosity matches central
    differences (measured 1.1e-10 relative; target 1e-4)."""
    pb = couette_problem()
    n = 30
    sim = make_simulate(pb, n_steps=n)            # record_every = 1: ke after every step
    t_end = n * sim.dt
    win = (0.1 * t_end, 0.77 * t_end)             # 3 steps and 23.1 steps: an end inside a step
    res = sensitivity(pb, ["physics.mu"], "ke_mean", check_fd=True, n_steps=n, window=win)
    assert res["window"] == pytest.approx(list(win), rel=1e-15)
    out = sim(pb.params, pb.particles)
    host = host_average(out.times, out.series["ke"], *win)
    assert abs(res["value"] - host) <= 1e-13 * abs(host)
    # not the whole-run mean: the window matters (the energy grows from rest)
    assert abs(host - host_average(out.times, out.series["ke"], 0.0, t_end)) > 1e-3 * abs(host)
    e = res["gradients"]["physics.mu"]
    assert e["verdict"] == "agree" and e["rel_difference"] < 1e-6 and abs(e["gradient"]) > 0, e


@pytest.mark.slow   # CI time; the Couette test checks a windowed mean against host and FD
def test_cylinder_cd_mean_and_cl_rms_match_host_and_finite_differences():
    """The ellipse A = 2 at 5 deg after the impulsive start (8 steps, window [1.5 dt, 7.2 dt]):
    the in-run averages of C_D and C_L (accumulated at every step, ``average=``) equal the host's
    trapezoidal averages of the C_D / C_L recorded after every step of the same run, to
    round-off; d (cd_mean, cl_mean, cl_rms) / d alpha by forward mode (one compilation for
    values, records and derivatives) match central finite differences to 1e-6."""
    pb = build_problem(config_mod.load(CONFIG_DIR / "cylinder.toml",
                                       [*SMALL_ELLIPSE, "scheme.reconstruction_degree=1"]))
    dm = pb.differentiable_metrics
    both = lambda p, t, P: {k: dm(p, t, P)[k] for k in ("cd", "cl")}  # noqa: E731
    n = 8
    base = make_simulate(pb, n_steps=n, t_end=n * 6e-3, cfl=0.6, checkpoint="none")
    win = (1.5 * base.dt, 7.2 * base.dt)
    sim = make_simulate(pb, **{**base.options, "diagnostics": both}, average=both, window=win)

    def f(alpha, P0):
        P = with_param(P0, ALPHA, alpha)
        out = sim(P, pb.particles_at(P))
        obj = jnp.stack([time_average(out.averages["cd"], "mean"), time_average(out.averages["cl"], "mean"),
                         time_average(out.averages["cl"], "rms")])
        return obj, (out.series["cd"], out.series["cl"], out.status)

    g = jax.jit(lambda a, P0: jax.jvp(lambda b: f(b, P0), (a,), (jnp.ones_like(a),)))
    a0 = jnp.asarray(math.radians(5.0))
    (obj, (cd, cl, status)), (dobj, _) = g(a0, pb.params)
    assert int(status) == 0
    t = np.arange(n + 1) * base.dt
    m_cl = host_average(t, cl, *win)
    host = np.array([host_average(t, cd, *win), m_cl,
                     math.sqrt(host_average(t, np.asarray(cl) ** 2, *win) - m_cl ** 2)])
    np.testing.assert_allclose(np.asarray(obj), host, rtol=1e-12, atol=0)
    assert host[2] > 1e-3 * abs(host[1])      # the lift does change over the window
    h = 1e-5 * float(a0)
    fd = (np.asarray(g(a0 + h, pb.params)[0][0]) - np.asarray(g(a0 - h, pb.params)[0][0])) / (2 * h)
    assert np.all(np.abs(fd) > 0)
    np.testing.assert_allclose(np.asarray(dobj), fd, rtol=1e-6)


def _fluctuating(eps):
    """q(t) = 1.6 + eps sin(2 pi t / T) on the Couette run's steps (T = the run's end time)."""
    def average(p, t, P):
        return {"q": 1.6 + eps * jnp.sin(2 * jnp.pi * t / T) + 0.0 * P["physics.mu"]}
    T = 30 * make_simulate(couette_problem(), n_steps=30).dt
    return average, T


@pytest.mark.parametrize("eps", [1e-7, 1e-8])
def test_rms_of_a_tiny_fluctuation_has_no_cancellation(eps):
    """q = 1.6 + eps sin(2 pi t / T): the in-run rms over the window equals the weighted rms of the
    fluctuation computed on the host from eps sin(...) alone (no 1.6 to cancel), to 1e-6 relative
    (the one-pass sqrt(<q^2> - <q>^2) was 7.5 % wrong at eps = 1e-7 and 0 at 1e-8)."""
    pb = couette_problem()
    average, T = _fluctuating(eps)
    win = (0.1 * T, 0.83 * T)
    sim = make_simulate(pb, n_steps=30, average=average, window=win)
    out = sim(pb.params, pb.particles)
    rms = float(time_average(out.averages["q"], "rms"))
    w = window_weights(30, sim.dt, win)
    s = eps * np.sin(2 * np.pi * np.arange(31) * sim.dt / T)
    exact = math.sqrt(w @ (s - w @ s) ** 2)
    assert exact > 0.1 * eps
    assert abs(rms - exact) <= 1e-6 * exact, (rms, exact)
    assert abs(float(time_average(out.averages["q"], "mean")) - (1.6 + w @ s)) <= 1e-15 * 1.6


def test_rms_of_a_constant_is_zero_with_a_zero_gradient():
    """A quantity that does not fluctuate: rms exactly 0 and its derivative 0, not NaN (the square
    root is taken only where the variance is positive)."""
    pb = couette_problem()
    sim = make_simulate(pb, n_steps=30, average=lambda p, t, P: {"c": 2.0 * P["physics.mu"]})

    def f(mu):
        return time_average(sim(with_param(pb.params, "physics.mu", mu), pb.particles).averages["c"], "rms")

    val, g = jax.value_and_grad(f)(jnp.asarray(pb.params["physics.mu"]))
    assert float(val) == 0.0 and float(g) == 0.0


def test_sensitivity_refuses_an_rms_that_is_zero(monkeypatch):
    """``sensitivity`` of an rms objective whose value is exactly 0 raises an InputError naming --of,
    the value and why (its gradient is undefined), instead of printing NaN."""
    pb = couette_problem()
    dm = lambda p, t, P: {"const": 2.0 * P["physics.mu"]}  # noqa: E731  (a metric that never changes)
    monkeypatch.setattr(pb, "differentiable_metrics", dm, raising=False)
    with pytest.raises(InputError, match=r"--of 'const_rms'.*const_rms is 0.*gradient is undefined"):
        sensitivity(pb, ["physics.mu"], "const_rms", n_steps=30)


def test_sensitivity_refuses_a_non_finite_gradient(monkeypatch):
    """An objective whose gradient is not finite (here sqrt at 0 of a metric: value 0, derivative
    NaN) is refused with an InputError naming --of, the value and the parameter, not printed."""
    pb = couette_problem()
    dm = lambda p, t, P: {"kink": jnp.sqrt(P["physics.mu"] - pb.params["physics.mu"])}  # noqa: E731
    monkeypatch.setattr(pb, "differentiable_metrics", dm, raising=False)
    with pytest.raises(InputError, match=r"--of 'kink': its value is 0 but its gradient with respect to "
                                         r"physics.mu is not finite"):
        sensitivity(pb, ["physics.mu"], "kink", n_steps=30)


def test_unknown_time_average_reduction_is_refused():
    avg = {"mean": jnp.asarray(1.0), "variance": jnp.asarray(0.5)}
    with pytest.raises(InputError, match=r"invalid time-average reduction 'std'; allowed: mean, rms"):
        time_average(avg, "std")


# --- bad input ------------------------------------------------------------------------------

@pytest.mark.parametrize("window, words", [
    ((0.0, 99.0), ["--window", "99", "outside the run", "0 <= T_START < T_END <= 0.05"]),
    ((-0.01, 0.02), ["--window", "-0.01", "outside the run"]),
    ((0.02, 0.02), ["--window", "0.02", "empty"]),
    ((0.03, 0.01), ["--window", "empty"]),
    ((0.0, float("nan")), ["--window", "nan", "not a finite number"]),
    ((float("-inf"), 0.02), ["--window", "-inf", "not a finite number"]),
    ((0.01,), ["--window", "two numbers"]),
])
def test_bad_window_names_the_option_value_and_range(window, words):
    pb = couette_problem()
    sim = make_simulate(pb, n_steps=30)
    with pytest.raises(InputError) as e:
        make_objective(pb, sim, "ke_mean", window=window)
    for w in words:
        assert w in str(e.value), (w, str(e.value))


def test_unknown_objective_and_window_on_an_instant_are_refused():
    pb = couette_problem()
    sim = make_simulate(pb, n_steps=30)
    names = objective_names(pb, sim)
    assert {"ke_final", "ke_mean", "ke_rms", "mass_mean"} <= set(names)
    with pytest.raises(InputError, match=r"invalid --of 'ke_average'; allowed: .*ke_mean.*ke_rms"):
        make_objective(pb, sim, "ke_average")
    with pytest.raises(InputError, match=r"--window .* with --of 'ke_final'.*time averages only.*ke_mean"):
        make_objective(pb, sim, "ke_final", window=(0.0, 0.01))
    with pytest.raises(InputError, match=r"window=.*without average="):
        make_simulate(pb, n_steps=30, window=(0.0, 0.01))


def test_cylinder_objectives_include_the_time_averaged_coefficients():
    pb = build_problem(config_mod.load(CONFIG_DIR / "cylinder.toml", list(SMALL_ELLIPSE)))
    names = objective_names(pb, make_simulate(pb, n_steps=4, t_end=0.024, cfl=0.6))
    assert {"cd", "cl", "cd_mean", "cl_mean", "cl_rms", "cd_pressure_mean"} <= set(names)


def test_cli_refuses_a_window_outside_the_run(capsys):
    from mlsph_jax.cli import main

    rc = main(["sensitivity", "couette", "--set", "case.ny=8", "case.nx=8", "time.t_end=0.05", "--wrt", "physics.mu",
               "--of", "ke_mean", "--n-steps", "30", "--window", "0.0", "0.5"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "--window" in err and "0.5" in err and "T_END <= 0.05" in err


# --- reverse mode through the whole run on the body (slow) ----------------------------------

@pytest.mark.slow
def test_whole_run_cd_mean_gradient_matches_fd():
    """Reverse mode through 40 steps (checkpoint "step"): d cd_mean / d (alpha, aspect) over the
    window [0.12, 0.24] of the ellipse A = 2 at 5 deg, quadratic reconstruction (the cubic default
    of configs/cylinder.toml stops with NaN in the first step of a differentiated run on this
    layout, with or without a time average), via mlsph_jax.sensitivity, against central FD on the
    same compiled run, to 1e-4 relative."""
    pb = build_problem(config_mod.load(CONFIG_DIR / "cylinder.toml",
                                       [*SMALL_ELLIPSE, "scheme.reconstruction_degree=2"]))
    res = sensitivity(pb, [ALPHA, "geometry.body.aspect"], "cd_mean", check_fd=True, n_steps=40, t_end=0.24,
                      cfl=0.6, checkpoint="step", record_every=40, window=(0.12, 0.24))
    for k in (ALPHA, "geometry.body.aspect"):
        e = res["gradients"][k]
        assert e["verdict"] == "agree" and abs(e["gradient"]) > 0, e
