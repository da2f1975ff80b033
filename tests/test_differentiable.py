"""Differentiable whole runs (mlsph_jax.differentiable, mlsph_jax.sensitivity): gradients against
central finite differences, checkpointing equivalence, bad input, the CLI."""

from __future__ import annotations

import dataclasses
import json
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mlsph_jax import config  # noqa: E402
from mlsph_jax.cases import build_problem  # noqa: E402
from mlsph_jax.differentiable import make_simulate, with_param  # noqa: E402
from mlsph_jax.errors import InputError  # noqa: E402
from mlsph_jax.sensitivity import sensitivity  # noqa: E402
from mlsph_jax.testing import couette_problem, periodic_shear_problem  # noqa: E402

#: The Taylor-Green config as the thesis runs it (Mach 0.1, no low-Mach option; the built-in
#: config has c0 = 20 and Thornber since issue 14): the fixed step counts here were chosen for it.
THESIS_TG = ("eos.c0=10", "scheme.low_mach_reconstruction=none")


def test_gradients_match_finite_differences_smooth_case():
    """Start-up Couette flow (viscous, walls, Tait): d(ke_final)/d(mu, c0, wall velocity) by
    reverse mode agree with central differences (relative step 1e-5) to better than 1e-5."""
    pb = couette_problem()
    res = sensitivity(pb, ["physics.mu", "eos.c0", "boundary.wall_velocity"], "ke_final", check_fd=True,
                      n_steps=30)
    for k in ("physics.mu", "eos.c0"):
        e = res["gradients"][k]
        assert abs(e["gradient"]) > 0 and e["rel_disagreement"] < 1e-5, (k, e)
        assert e["verdict"] == "agree" and e["hint"] == "" and "fd_10_step" not in e
    e = res["gradients"]["boundary.wall_velocity"]
    g, fd = np.asarray(e["gradient"]), np.asarray(e["fd"])
    assert abs(g[1, 0]) > 0  # the moving plate drives the flow
    # tangential wall speeds; the wall-normal components (column 1) sit exactly on the kink of the
    # Rusanov wave speed |u.n| at u.n = 0: not differentiable there, and which one-sided derivative
    # reverse mode returns depends on the round-off that puts each u.n just above or below 0 (the
    # compiler's multiply-add contractions).  Measured: with XLA:CPU's default fusion emitters the
    # moving wall's normal entry disagrees with the central difference by 2.3e-3 (rel_difference
    # 4.4e-4 over the array: verdict "disagree", second FD step taken, hint naming the kink); with
    # the elemental emitters the test suite compiles with (tests/conftest.py) by 2.4e-4
    # (rel_difference 4.7e-5: "agree").  So: each normal entry within a one-sided derivative's
    # 1e-2 of the FD, and a "disagree" must come with the second step and name the kink.
    np.testing.assert_allclose(g[:, 0], fd[:, 0], rtol=1e-5)
    np.testing.assert_allclose(g[:, 1], fd[:, 1], rtol=1e-2)
    assert e["verdict"] == "agree" or (e["verdict"] == "disagree" and "fd_10_step" in e
                                       and "|u.n|" in e["hint"]), e


# CI time (48 s, the default suite's second-slowest test).  In the default suite each mode is
# checked on its own: "nested" (make_simulate's and sensitivity's default) against central
# differences in this file's FD tests and test_time_average_objectives.py's
# test_couette_windowed_ke_mean_matches_host_and_finite_differences, "none" in test_flux_hllc's FD
# test and test_diffrax_path's gradient, "step" against forward mode to 1e-10 in
# test_forward_mode_and_vjp_agree_with_reverse_mode.  No default test compares two modes with each
# other at round-off any more: "none" = "nested" to 1e-12 over 1,000 steps (issue 15) is this slow test.
@pytest.mark.slow
def test_checkpointing_gives_the_same_gradient_over_1000_steps():
    pb = couette_problem(ny=6, nx=4, t_end=0.5)
    grads = {}
    # "step" is checked against forward mode in test_forward_mode_and_vjp_agree_with_reverse_mode
    for ck in ("none", "nested"):
        sim = make_simulate(pb, n_steps=1000, checkpoint=ck, record_every=10)
        assert sim.n_steps == 1000

        def loss(mu, sim=sim):
            return sim(with_param(pb.params, "physics.mu", mu), pb.particles).series["ke"][-1]

        grads[ck] = float(jax.jit(jax.grad(loss))(0.1))
    assert np.isfinite(grads["none"]) and grads["none"] != 0
    assert grads["nested"] == pytest.approx(grads["none"], rel=1e-12)


def test_gradient_wrt_initial_fields_and_positions():
    """Directional derivatives of ke_final along random perturbations of the initial conserved
    fields and of the particle positions match central differences (relative 1e-5; measured
    1.1e-6 for the fields)."""
    pb = periodic_shear_problem()
    sim = make_simulate(pb, n_steps=10)

    def f(q, x):
        return sim(pb.params, pb.particles.replace(q=q, x=x)).series["ke"][-1]

    gq, gx = jax.jit(jax.grad(f, argnums=(0, 1)))(pb.particles.q, pb.particles.x)
    assert np.abs(np.asarray(gq)).max() > 0 and np.abs(np.asarray(gx)).max() > 0
    rng = np.random.default_rng(0)
    dq = jnp.asarray(rng.normal(size=pb.particles.q.shape)) * 1e-3 * pb.particles.q
    dx = jnp.asarray(rng.normal(size=pb.particles.x.shape)) * 1e-3
    fj = jax.jit(f)
    q0, x0 = pb.particles.q, pb.particles.x
    eps = 1e-3
    fd_q = (fj(q0 + eps * dq, x0) - fj(q0 - eps * dq, x0)) / (2 * eps)
    fd_x = (fj(q0, x0 + eps * dx) - fj(q0, x0 - eps * dx)) / (2 * eps)
    assert float(jnp.sum(gq * dq)) == pytest.approx(float(fd_q), rel=1e-5)
    assert float(jnp.sum(gx * dx)) == pytest.approx(float(fd_x), rel=1e-5)


# CI time: reverse mode through MOOD stays in the default suite (test_mood's
# test_gradient_through_a_mood_run_is_finite), FD checks of run gradients too (smooth case, HLLC run)
@pytest.mark.slow
def test_mood_riemann_gradient_matches_finite_differences():
    """R1 with MOOD (n = 40): flags carry no gradient, so the gradient is that of the selected
    branch; away from flag changes it matches finite differences (measured: gamma 1.6e-10)."""
    cfg = config.load("configs/riemann_r1_tait.toml", ["case.n=40"])
    res = sensitivity(build_problem(cfg), ["eos.gamma"], "ke_final", check_fd=True)
    e = res["gradients"]["eos.gamma"]
    assert e["rel_disagreement"] < 1e-3, e


def test_bad_inputs_name_the_argument():
    pb = couette_problem()
    with pytest.raises(InputError, match="checkpoint"):
        make_simulate(pb, checkpoint="all")
    with pytest.raises(InputError, match="record_every"):
        make_simulate(pb, n_steps=10, record_every=3)
    with pytest.raises(InputError, match="--wrt 'physics.nu'"):
        sensitivity(pb, ["physics.nu"], "ke_final")
    with pytest.raises(InputError, match="--of 'drag'.*ke_final"):
        sensitivity(pb, ["physics.mu"], "drag", n_steps=20)


@pytest.mark.slow   # 29 s; CI time: the default suite runs the CLI in test_run_status and test_local_time_stepping
def test_sensitivity_cli(tmp_path):
    from mlsph_jax.cli import main

    out = tmp_path / "s"
    rc = main(["sensitivity", "configs/riemann_r1_tait.toml", "--wrt", "eos.gamma", "--of", "ke_final",
               "--set", "case.n=30", "--out", str(out)])
    assert rc == 0
    s = json.loads((out / "sensitivity.json").read_text())
    assert s["objective"] == "ke_final" and np.isfinite(s["gradients"]["eos.gamma"]["gradient"])
    assert s["mode"] == "forward"   # --mode auto with one scalar parameter
    assert main(["sensitivity", "configs/riemann_r1_tait.toml", "--wrt", "eos.nope", "--of", "ke_final"]) == 2
    assert main(["sensitivity", "configs/riemann_r1_tait.toml", "--wrt", "eos.gamma", "--of", "ke_final",
                 "--mode", "sideways"]) == 2


@pytest.mark.slow   # 57 s; the default suite recovers the same viscosity through `mlsph calibrate` below
def test_calibration_recovers_the_taylor_green_viscosity(tmp_path):
    """Experiment (a) at a coarse resolution: the viscosity of a Taylor-Green run (Re = 100,
    8 x 8 particles, 30 steps: the fewest whose dt is within the CFL limit, 29, rounded up to a
    multiple of record_every) is recovered from its kinetic-energy history starting 50 % off,
    to within 0.5 % (L-BFGS reaches round-off in ~6 iterations; measured 4e-15 at 12 x 12)."""
    import re
    import subprocess
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    r = subprocess.run([sys.executable, str(root / "experiments" / "calibrate_viscosity.py"), "--n", "8",
                        "--t-end", "0.1", "--steps", "6", "--n-steps", "30", "--out", str(tmp_path)],
                       capture_output=True, text=True, cwd=root)
    assert r.returncode == 0, r.stderr[-2000:]
    m = re.search(r"mu_true = (\S+), start = (\S+), fitted = (\S+), relative error (\S+)", r.stdout)
    mu_true, mu_start, _, rel = (float(g) for g in m.groups())
    assert mu_start == pytest.approx(1.5 * mu_true, rel=1e-5)
    history = json.loads((tmp_path / "history.json").read_text())
    losses = [h["loss"] for h in history["history"]] if isinstance(history, dict) else [h["loss"] for h in history]
    assert losses[0] > 1e3 * min(losses)
    assert rel < 5e-3, r.stdout


@pytest.mark.slow   # 87 s; CI time (under 20 min): the default suite calibrates through notebook 02
def test_calibrate_cli_fits_the_viscosity_and_writes_history_and_plot(tmp_path):
    """`mlsph calibrate` end to end: a target CSV from a hidden Taylor-Green run (Re = 100,
    mu = 0.01), the fit started from Re = 66.7 (mu = 0.015, 50 % off) recovers mu to 0.5 %,
    and history.json / calibration.png are written; a bad --lr is an input error (exit 2)."""
    from mlsph_jax.cli import main

    cfg = config.load("configs/taylor_green_2d.toml", ["case.n=8", "time.t_end=0.1", *THESIS_TG])
    pb = build_problem(cfg)
    obs = jax.jit(make_simulate(pb, n_steps=30, record_every=5))(pb.params, pb.particles)
    target = tmp_path / "target.csv"     # as mlsph run writes it: ke_exact is not a recorded series
    target.write_text("t,ke,ke_exact\n" + "".join(f"{t!r},{k!r},0.25\n" for t, k in zip(
        np.asarray(obs.times).tolist(), np.asarray(obs.series["ke"]).tolist(), strict=True)))
    common = ["calibrate", "configs/taylor_green_2d.toml", "--fit", "physics.mu", "--target", str(target),
              "--set", "case.n=8", "time.t_end=0.1", *THESIS_TG, "case.re=66.66666666666667", "--n-steps", "30",
              "--record-every", "5", "--quiet"]
    out = tmp_path / "cal"
    assert main(common + ["--steps", "25", "--out", str(out)]) == 0
    hist = json.loads((out / "history.json").read_text())
    assert hist["history"][0]["params"]["physics.mu"] == pytest.approx(0.015, rel=1e-12)
    assert hist["final"]["physics.mu"] == pytest.approx(float(pb.params["physics.mu"]), rel=5e-3)
    assert hist["columns"] == ["ke"] and hist["ignored_columns"] == ["ke_exact"]
    assert hist["stopped"] == "plateau" and len(hist["history"]) < 26     # not 25 iterations on a plateau
    # --tol stops at the first iterate whose loss is below it (here the one after the first fit)
    tol = 0.5 * hist["history"][2]["loss"] + 0.5 * hist["history"][1]["loss"]
    assert main(common + ["--steps", "6", "--tol", repr(tol), "--out", str(tmp_path / "tol")]) == 0
    h2 = json.loads((tmp_path / "tol" / "history.json").read_text())
    assert h2["stopped"] == "tol" and len(h2["history"]) == 3 and h2["loss"] <= tol
    assert (out / "calibration.png").stat().st_size > 0
    assert main(common + ["--lr", "-1", "--out", str(tmp_path / "bad")]) == 2
    assert main(common + ["--tol", "0", "--out", str(tmp_path / "bad")]) == 2
    (tmp_path / "none.csv").write_text("t,ke_exact\n0.0,0.25\n")
    assert main([*common[:5], str(tmp_path / "none.csv"), *common[6:], "--out", str(tmp_path / "bad")]) == 2


# 29 s; CI time: gradients of runs vs FD stay in the default suite (smooth case, fields and positions)
@pytest.mark.slow
def test_taylor_green_metrics_are_differentiable_and_agree_with_the_host_metrics():
    """The Taylor-Green error metrics exist as jnp functions (``--of l2_velocity_error`` etc.):
    on the same state they equal the host metrics of summary.json and an independent numpy
    evaluation of the formulas (exact solution written out here), and their gradient with
    respect to the viscosity (which enters both the run and the exact solution) and the sound
    speed matches central finite differences to 1e-5."""
    from mlsph_jax.cases.taylor_green_2d import fields

    cfg = config.load("configs/taylor_green_2d.toml", ["case.n=8", "time.t_end=0.05", *THESIS_TG])
    pb = build_problem(cfg)
    sim = make_simulate(pb, n_steps=15)
    out = jax.jit(sim)(pb.params, pb.particles)
    t = sim.n_steps * sim.dt
    host = pb.metrics(out.particles, t, pb.params)
    dm = pb.differentiable_metrics(out.particles, t, pb.params)
    for k, v in dm.items():
        assert float(v) == pytest.approx(host[k], rel=1e-12), k
    f = fields(out.particles, pb.params, "tait")
    x, vol, vel, p = f["x"], f["vol"], f["vel"], f["p"]
    F = np.exp(-8 * np.pi**2 * float(pb.params["physics.mu"]) * t)       # L = U0 = rho0 = 1
    ue = F * np.stack([np.sin(2 * np.pi * x[:, 0]) * np.cos(2 * np.pi * x[:, 1]),
                       -np.cos(2 * np.pi * x[:, 0]) * np.sin(2 * np.pi * x[:, 1])], 1)
    pe = 0.25 * F**2 * (np.cos(4 * np.pi * x[:, 0]) + np.cos(4 * np.pi * x[:, 1]))
    l2u = np.sqrt(np.sum(vol[:, None] * (vel - ue) ** 2) / np.sum(vol[:, None] * ue**2))
    dp = (p - np.average(p, weights=vol)) - (pe - np.average(pe, weights=vol))
    l2p = np.sqrt(np.average(dp**2, weights=vol)) / (0.5 * F**2)
    ke = np.sum(0.5 * vol * f["rho"] * np.sum(vel**2, 1))
    assert float(dm["l2_velocity_error"]) == pytest.approx(l2u, rel=1e-10)
    assert float(dm["l2_pressure_error"]) == pytest.approx(l2p, rel=1e-10)
    assert float(dm["ke_rel_error"]) == pytest.approx(abs(ke / (0.25 * F**2) - 1), rel=1e-10)
    res = sensitivity(pb, ["physics.mu", "eos.c0"], "l2_velocity_error", check_fd=True, n_steps=15)
    for k, e in res["gradients"].items():
        assert abs(e["gradient"]) > 0 and e["rel_disagreement"] < 1e-5, (k, e)


def test_forward_mode_and_vjp_agree_with_reverse_mode():
    """jax.jacfwd (forward mode) and jax.vjp (reverse mode, what jax.grad uses) through a whole
    run agree (the issue's 'differentiable with grad, jacfwd and vjp'); the reverse-mode
    gradient itself is checked against finite differences in the tests above."""
    pb = periodic_shear_problem()
    sim = make_simulate(pb, n_steps=8, checkpoint="step")

    def ke(theta):
        p = with_param(with_param(pb.params, "physics.mu", theta[0]), "eos.c0", theta[1])
        return sim(p, pb.particles).series["ke"][-1]

    theta = jnp.asarray([float(pb.params["physics.mu"]), float(pb.params["eos.c0"])])
    jf = jax.jit(jax.jacfwd(ke))(theta)             # forward mode

    def reverse(theta):                             # reverse mode (what jax.grad calls)
        val, pull = jax.vjp(ke, theta)
        return pull(jnp.ones_like(val))[0]

    gv = jax.jit(reverse)(theta)
    assert np.all(np.asarray(gv) != 0)
    np.testing.assert_allclose(jf, gv, rtol=1e-10)


def test_sensitivity_in_forward_mode_equals_reverse_mode(monkeypatch):
    """``sensitivity(mode="forward")`` (jax.jacfwd of the objective, one tangent per parameter
    component carried through the run) gives the value and the gradients of reverse mode (which
    the finite-difference tests above verify) to 1e-10, for a scalar and a vector parameter, with
    the stencil passes split into several row blocks (the loop JVP forward mode uses);
    ``"auto"`` picks forward for one scalar component and reverse above it; an unknown mode is
    refused before anything runs."""
    import mlsph_jax.approximation as apx
    from mlsph_jax.sensitivity import FORWARD_MAX_COMPONENTS, resolve_mode
    from mlsph_jax.state import Params

    monkeypatch.setattr(apx, "BLOCK_SLOTS", 16 * 10)   # ~16 rows per block: 4+ blocks for 64 particles

    pb = periodic_shear_problem()
    wrt = ["physics.mu", "physics.body_force"]
    pb = dataclasses.replace(pb, params=Params({**{k: pb.params[k] for k in pb.params},
                                                "physics.body_force": jnp.asarray([0.3, -0.2])}))
    res = {m: sensitivity(pb, wrt, "ke_final", n_steps=8, checkpoint="step", mode=m) for m in ("reverse", "forward")}
    assert res["forward"]["mode"] == "forward" and res["reverse"]["mode"] == "reverse"
    np.testing.assert_allclose(res["forward"]["value"], res["reverse"]["value"], rtol=1e-13)
    for k in wrt:
        g_f = np.asarray(res["forward"]["gradients"][k]["gradient"])
        g_r = np.asarray(res["reverse"]["gradients"][k]["gradient"])
        assert np.all(g_r != 0), k
        np.testing.assert_allclose(g_f, g_r, rtol=1e-10, err_msg=k)
    assert FORWARD_MAX_COMPONENTS == 1
    assert resolve_mode("auto", {"physics.mu": 0.02}) == "forward"
    assert resolve_mode("auto", {"physics.mu": 0.02, "eos.c0": 10.0}) == "reverse"
    assert resolve_mode("auto", {"physics.body_force": np.zeros(2)}) == "reverse"
    with pytest.raises(InputError, match=r"mode \(--mode\) 'backward'.*auto, reverse, forward"):
        sensitivity(pb, ["physics.mu"], "ke_final", n_steps=8, mode="backward")


def test_neighbour_overflow_in_a_differentiated_run_is_an_error():
    """A differentiated run keeps its neighbour capacity fixed; when compression overflows it,
    run_differentiable raises NeighborOverflowError instead of truncating (sensitivity and
    calibrate call the same check_overflow on their runs)."""
    from mlsph_jax.differentiable import run_differentiable
    from mlsph_jax.errors import NeighborOverflowError

    cfg = config.load("configs/riemann_r1_tait.toml", ["case.n=40", "scheme.limiter=none",
                                                        "scheme.reconstruction_degree=0"])
    pb = build_problem(cfg)
    sim = make_simulate(pb, n_steps=40, headroom=1.0)
    with pytest.raises(NeighborOverflowError, match="capacity"):
        run_differentiable(sim, pb.params, pb.particles)
    ok = make_simulate(pb, n_steps=40)  # the default headroom suffices
    assert not bool(run_differentiable(ok, pb.params, pb.particles).overflow)


def test_fd_verdict_states_agreement_and_the_likely_cause():
    from mlsph_jax.sensitivity import AGREE_TOL, fd_verdict

    ok = fd_verdict(-2.0, -2.0 * (1 + 1e-8))
    assert ok["verdict"] == "agree" and ok["rel_difference"] == pytest.approx(1e-8, rel=1e-3) and ok["hint"] == ""
    # a vector parameter whose second component is zero up to round-off in both: agreement
    assert fd_verdict([1.0, 0.0], [1.0, 1e-13])["verdict"] == "agree"
    step = fd_verdict(1.0, 1.093, 1.25)            # FD moves with the step: the FD side is suspect
    assert step["verdict"] == "disagree" and step["rel_difference"] > AGREE_TOL
    assert "change" in step["hint"] and "--fd-rel" in step["hint"] and "MOOD is on" not in step["hint"]
    kink = fd_verdict(1.0, 1.093, 1.093 * (1 + 1e-7), mood=True)   # FD stable, AD differs
    assert "branch taken" in kink["hint"] and "MOOD is on" in kink["hint"]
