"""The status word of a run (mlsph_jax.status, mlsph_jax.run): every cause of failure is one bit,
computed inside jit on every run path, and never comes back silently.

Each cause is produced by a constructed state or setup and checked on the host driver
(``Simulation``) and on the differentiated path (``make_simulate``) where it applies.  Causes
that a healthy SSP-RK3 step cannot produce as a *finite* candidate (an inadmissible, negative
density or negative volume stage state gives NaN sound speeds, hence NaN in the next stage) are
injected into the candidate of the first step by wrapping ``ssp_rk3_step``: the status check,
the uncommitted step and the error are those of a real run.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math

import h5py
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mlsph_jax
from mlsph_jax import config, differentiable, integrate
from mlsph_jax import diffrax_path as dp
from mlsph_jax import neighbors as nb
from mlsph_jax.cases import build_problem
from mlsph_jax.cli import DEFAULT_CONFIG
from mlsph_jax.differentiable import check, make_simulate, run_differentiable, with_param
from mlsph_jax.eos import get_eos, to_conservative, to_primitive
from mlsph_jax.errors import InputError, NeighborOverflowError, SimulationError
from mlsph_jax.run import cfl_limit
from mlsph_jax.simulation import Simulation, run_problem
from mlsph_jax.state import Kind
from mlsph_jax.status import Status, state_status
from mlsph_jax.testing import periodic_shear_problem  # noqa: E402

SMALL_SOD = ["case.n=40", "scheme.frame=eulerian", "time.t_end=0.1", "output.progress=false"]
BAD = 17   # a fluid particle of the 40-particle tube


def tube(*sets, text=DEFAULT_CONFIG):
    small = SMALL_SOD if text == DEFAULT_CONFIG else [s for s in SMALL_SOD if not s.startswith("time.t_end")]
    cfg = config.loads(text, [*small, *sets])
    return cfg, build_problem(cfg)


# --------------------------------------------------------------------------------------------
# the status word itself
# --------------------------------------------------------------------------------------------

def test_status_bits_are_distinct_and_described():
    single = [s for s in Status if s != Status.OK]
    assert {s.name for s in single} == {
        "NONFINITE", "INADMISSIBLE", "NEGATIVE_DENSITY", "NEGATIVE_VOLUME", "NEIGHBOR_OVERFLOW_ROW",
        "NEIGHBOR_OVERFLOW_CELL", "NEIGHBOR_OVERFLOW_REACH", "DT_UNDERFLOW", "DT_ABOVE_CFL", "MOOD_UNRESOLVED",
        "GHOST_BAND", "WALL_CROSSED", "BOUNDARY_OVERFLOW", "AREA_CORRECTION_UNCONVERGED"}
    assert len({int(s) for s in single}) == len(single)
    assert all(bin(int(s)).count("1") == 1 for s in single)
    assert (Status.NEIGHBOR_OVERFLOW_ROW, Status.NEIGHBOR_OVERFLOW_CELL, Status.NEIGHBOR_OVERFLOW_REACH) == (
        nb.OVERFLOW_ROW, nb.OVERFLOW_CELL, nb.OVERFLOW_REACH)
    texts = [s.describe() for s in single]
    assert len(set(texts)) == len(single) and all(texts)
    both = Status.NONFINITE | Status.DT_ABOVE_CFL
    assert both.causes == [Status.NONFINITE, Status.DT_ABOVE_CFL]
    assert "NaN" in both.describe() and "CFL" in both.describe()
    assert Status.OK.describe() == "ok"
    assert (Status.NEIGHBOR_OVERFLOW_ROW | Status.NEIGHBOR_OVERFLOW_CELL).neighbor_overflow_only
    assert not (Status.NEIGHBOR_OVERFLOW_ROW | Status.NONFINITE).neighbor_overflow_only
    assert integrate.Status is Status   # re-exported where it was


def _gas_particles(eos_kind, params, rho, p, n=8):
    from mlsph_jax import make_particles

    x = (np.arange(n)[:, None] + 0.5) / n
    eos = get_eos(eos_kind)
    U = to_conservative(jnp.full(n, rho), jnp.zeros((n, 1)), jnp.full(n, p), eos, params)
    return make_particles(x, np.full(n, 1.0 / n), U)


def test_state_status_of_constructed_states():
    """Each cause on a hand-made state: the bit and the first offending (fluid) particle; a
    particle counts under its first cause only (NaN > V <= 0 > rho <= 0 > EOS); non-fluid
    particles are not checked."""
    from mlsph_jax import Params
    from mlsph_jax.scheme import Scheme

    gas = Params({"eos.gamma": 1.4})
    ideal = Scheme(eos="ideal_gas")
    p = _gas_particles("ideal_gas", gas, 1.0, 1.0)
    assert [int(v) for v in state_status(p, gas, ideal)] == [0, -1]

    def with_p(p, i, pressure, params, kind):   # particle i at pressure `pressure`, same rho and u
        U = np.asarray(p.U)
        pr = to_primitive(jnp.asarray(U), get_eos(kind), params)
        Ui = to_conservative(pr.rho[i], pr.vel[i], jnp.asarray(pressure), get_eos(kind), params)
        return p.replace(q=p.q.at[i].set(Ui * p.vol[i]))

    st, i = state_status(with_p(p, 5, -0.1, gas, "ideal_gas"), gas, ideal)            # ideal gas, p < 0
    assert (Status(int(st)), int(i)) == (Status.INADMISSIBLE, 5)
    st, i = state_status(with_p(p, 5, 0.0, gas, "ideal_gas"), gas, ideal)             # p = 0 is not > 0
    assert (Status(int(st)), int(i)) == (Status.INADMISSIBLE, 5)

    stiff = Params({"eos.gamma": 4.4, "eos.pc": 6e8})
    sg = Scheme(eos="stiffened_gas")
    ps = _gas_particles("stiffened_gas", stiff, 1000.0, 1e5)
    assert int(state_status(ps, stiff, sg)[0]) == 0
    st, i = state_status(with_p(ps, 3, -5e8, stiff, "stiffened_gas"), stiff, sg)      # p < 0 but p + pc > 0: ok
    assert int(st) == 0
    st, i = state_status(with_p(ps, 3, -7e8, stiff, "stiffened_gas"), stiff, sg)      # p + pc < 0
    assert (Status(int(st)), int(i)) == (Status.INADMISSIBLE, 3)

    bad = p.replace(q=p.q.at[6, 0].set(-0.1).at[2, 1].set(jnp.nan), vol=p.vol.at[4].set(-p.vol[4]))
    st, i = state_status(bad, gas, ideal)
    assert Status(int(st)) == Status.NONFINITE | Status.NEGATIVE_VOLUME | Status.NEGATIVE_DENSITY
    assert int(i) == 2                                   # NaN first
    st, i = state_status(bad.replace(q=bad.q.at[2, 1].set(0.0)), gas, ideal)
    assert (Status(int(st)), int(i)) == (Status.NEGATIVE_VOLUME | Status.NEGATIVE_DENSITY, 4)
    frozen = bad.replace(kind=jnp.where(jnp.arange(bad.n) < 7, Kind.FROZEN, bad.kind))
    assert int(state_status(frozen, gas, ideal)[0]) == 0   # only fluid particles are checked


# --------------------------------------------------------------------------------------------
# causes injected into the first step's candidate, on both paths
# --------------------------------------------------------------------------------------------

def _set_pressure(q, vol, i, pressure, eos_kind, params):
    pr = to_primitive(q[i] / vol[i], get_eos(eos_kind), params)
    return q.at[i].set(to_conservative(pr.rho, pr.vel, jnp.asarray(pressure), get_eos(eos_kind), params) * vol[i])


STIFF = DEFAULT_CONFIG.replace('kind = "ideal_gas"\ngamma = 1.4', 'kind = "stiffened_gas"\ngamma = 4.4\npc = 6e8')
STIFF = STIFF.replace("left = { rho = 1.0, u = 0.0, p = 1.0 }", "left = { rho = 1000.0, u = 0.0, p = 1e9 }")
STIFF = STIFF.replace("right = { rho = 0.125, u = 0.0, p = 0.1 }", "right = { rho = 1000.0, u = 0.0, p = 1e5 }")
STIFF = STIFF.replace("t_end = 0.2", "t_end = 2e-6")   # (overridden by SMALL_SOD's t_end otherwise)

INJECTED = {   # cause: (config text, extra overrides, corruption of the candidate at particle BAD)
    "nonfinite": (Status.NONFINITE, DEFAULT_CONFIG, lambda p, P: p.replace(q=p.q.at[BAD, 1].set(jnp.nan))),
    "negative_density": (Status.NEGATIVE_DENSITY, DEFAULT_CONFIG,
                         lambda p, P: p.replace(q=p.q.at[BAD, 0].set(-p.q[BAD, 0]))),
    "negative_volume": (Status.NEGATIVE_VOLUME, DEFAULT_CONFIG,
                        lambda p, P: p.replace(vol=p.vol.at[BAD].set(-p.vol[BAD]))),
    "inadmissible_ideal_gas": (Status.INADMISSIBLE, DEFAULT_CONFIG,
                               lambda p, P: p.replace(q=_set_pressure(p.q, p.vol, BAD, -0.05, "ideal_gas", P))),
    "inadmissible_stiffened_gas": (Status.INADMISSIBLE, STIFF,   # p + pc = -1e8 < 0
                                   lambda p, P: p.replace(q=_set_pressure(p.q, p.vol, BAD, -7e8, "stiffened_gas", P))),
}


@pytest.fixture
def inject(monkeypatch):
    """Corrupt the candidate of every step (so the first step fails) on both paths."""

    def install(corrupt):
        real = integrate.ssp_rk3_step

        def step(p, params, dt, scheme, geom_fn, boundary=None, cache=None):
            out, ovf, stats, *rest = real(p, params, dt, scheme, geom_fn, boundary, cache)
            return corrupt(out, params), ovf, stats, *rest     # (rest: the Verlet cache of moving runs)

        monkeypatch.setattr(integrate, "ssp_rk3_step", step)
        monkeypatch.setattr(differentiable, "ssp_rk3_step", step)

    return install


@pytest.mark.parametrize("name", list(INJECTED))
def test_injected_cause_stops_the_driver(name, inject, tmp_path):
    """Simulation: the failing step is not committed, the error names step 1, t = 0, the
    particle and the cause, summary.json records it and the final snapshot is the initial state."""
    status, text, corrupt = INJECTED[name]
    cfg, pb = tube(text=text)
    inject(corrupt)
    with pytest.raises(SimulationError) as ei:
        run_problem(pb, cfg, out_dir=tmp_path, quiet=True)
    e = ei.value
    assert (e.status, e.step, e.time, e.particle) == (status, 1, 0.0, BAD)
    assert status.describe() in str(e) and f"particle {BAD}" in str(e) and "step 1" in str(e)
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["status"].startswith("failed") and s["n_steps"] == 0
    with h5py.File(tmp_path / "fields.h5") as f:
        last = f["snapshots"][sorted(f["snapshots"], key=int)[-1]]
        np.testing.assert_array_equal(last["x"][()], np.asarray(pb.particles.x))


@pytest.mark.parametrize("name", list(INJECTED))
def test_injected_cause_in_a_differentiated_run(name, inject):
    """make_simulate: status, failed step, particle in SimOutput; the state and series stay at the
    last good state; run_differentiable raises SimulationError naming step, time, particle, cause."""
    status, text, corrupt = INJECTED[name]
    _, pb = tube(text=text)
    inject(corrupt)
    sim = make_simulate(pb, checkpoint="step")
    out = jax.jit(sim)(pb.params, pb.particles)
    assert (Status(int(out.status)), int(out.failed_step), float(out.failed_time), int(out.bad_particle)) == (
        status, 1, 0.0, BAD)
    np.testing.assert_array_equal(np.asarray(out.particles.q), np.asarray(pb.particles.q))
    assert np.all(np.asarray(out.series["ke"]) == float(out.series["ke"][0]))
    with pytest.raises(SimulationError, match=f"in step 1 starting at t=0, particle {BAD}") as ei:
        run_differentiable(sim, pb.params, pb.particles)
    assert ei.value.status == status and ei.value.particle == BAD and status.describe() in str(ei.value)


def test_nonfinite_from_the_physics_on_both_paths():
    """Not injected: a NaN viscosity makes the first step of the viscous shear flow non-finite.
    The differentiated run keeps the last good (finite) state and raises on the host; a
    parameter that makes the *initial* state inadmissible is reported as step 0."""
    pb = periodic_shear_problem()
    bad = dataclasses.replace(pb, params=with_param(pb.params, "physics.mu", jnp.nan))
    with pytest.raises(SimulationError, match="non-finite") as ei:
        Simulation(bad).run(progress=False)
    assert ei.value.status & Status.NONFINITE and ei.value.step == 1
    sim = make_simulate(pb, n_steps=10, checkpoint="none")
    out = jax.jit(sim)(bad.params, pb.particles)
    assert Status(int(out.status)) & Status.NONFINITE and int(out.failed_step) == 1
    assert np.all(np.isfinite(np.asarray(out.particles.q)))
    with pytest.raises(SimulationError, match="non-finite.*in step 1 starting at t=0"):
        check(out)
    out = jax.jit(sim)(with_param(pb.params, "eos.rho0", jnp.nan), pb.particles)
    assert Status(int(out.status)) == Status.INADMISSIBLE and int(out.failed_step) == 0


# --------------------------------------------------------------------------------------------
# neighbour overflow: row vs cell vs reach
# --------------------------------------------------------------------------------------------

@functools.cache
def _lagrangian_sod():
    pb = tube("scheme.frame=lagrangian")[1]
    return pb, Simulation(pb).run(progress=False)


def test_overflow_causes_are_distinct_bits():
    rng = np.random.default_rng(0)
    x = rng.uniform(size=(300, 2))
    h = np.full(300, 0.05)
    dom = mlsph_jax.Domain((0.0, 0.0), (1.0, 1.0), (True, True))
    spec = nb.plan(x, h, dom, headroom=1.5)
    assert int(nb.update(x, h, spec).overflow_bits) == 0
    row = nb.update(x, h, dataclasses.replace(spec, capacity=3))
    cell = nb.update(x, h, dataclasses.replace(spec, cell_capacity=2))
    reach = nb.update(x, 1.5 * h, spec)
    assert int(row.overflow_bits) == nb.OVERFLOW_ROW and bool(row.overflow)
    assert int(cell.overflow_bits) == nb.OVERFLOW_CELL and bool(cell.overflow)
    assert int(reach.overflow_bits) & nb.OVERFLOW_REACH and bool(reach.overflow)
    assert nb.overflow_causes(int(row.overflow_bits) | int(cell.overflow_bits)) == ["capacity", "cell_capacity"]


@pytest.mark.parametrize("limit, cause", [("capacity", Status.NEIGHBOR_OVERFLOW_ROW),
                                          ("cell_capacity", Status.NEIGHBOR_OVERFLOW_CELL)])
def test_driver_regrows_the_limit_the_cause_names(limit, cause):
    """Moving particles with a too small row (cell) capacity: the chunk reports the ROW (CELL)
    bit, the driver grows that limit (no host re-measure of which limit was hit), resumes from
    the uncommitted step and finishes with the same result as a run sized right."""
    pb, ref = _lagrangian_sod()
    sim = Simulation(pb)
    small = dataclasses.replace(sim.nspec, **{limit: 1})
    sim.setup = dataclasses.replace(sim.setup, nspec=small)
    sim._build()
    res = sim.run(progress=False)
    assert res.summary["status"] == "ok"
    log = sim.regrowth_log
    assert log and log[0]["causes"] == [cause.name] and log[0]["step"] == 1
    assert log[0][limit][1] > log[0][limit][0]
    other = "cell_capacity" if limit == "capacity" else "capacity"
    assert log[0][other][1] >= log[0][other][0]
    q_ref = np.asarray(ref.particles.q)      # to round-off of the state's scale (two programs; decision 98)
    np.testing.assert_allclose(np.asarray(res.particles.q), q_ref, rtol=1e-12, atol=1e-14 * np.abs(q_ref).max())


@pytest.mark.parametrize("limit, cause, text", [("capacity", Status.NEIGHBOR_OVERFLOW_ROW, "row capacity"),
                                                ("cell_capacity", Status.NEIGHBOR_OVERFLOW_CELL, "cell capacity")])
def test_differentiated_run_reports_the_overflow_cause(limit, cause, text):
    pb, _ = _lagrangian_sod()
    spec = dataclasses.replace(differentiable.make_simulate(pb, n_steps=60).setup.nspec, **{limit: 1})
    sim = make_simulate(pb, n_steps=60, nspec=spec)
    out = jax.jit(sim)(pb.params, pb.particles)
    assert Status(int(out.status)) == cause and int(out.failed_step) == 1 and bool(out.overflow)
    with pytest.raises(NeighborOverflowError, match=text) as ei:
        check(out)
    assert isinstance(ei.value, SimulationError) and "headroom" in str(ei.value)


# --------------------------------------------------------------------------------------------
# time step: underflow, above the CFL limit
# --------------------------------------------------------------------------------------------

def test_dt_underflow_on_the_driver():
    cfg, pb = tube("time.dt_min=0.5")
    with pytest.raises(SimulationError, match="time step underflow") as ei:
        run_problem(pb, cfg, quiet=True)
    e = ei.value
    assert (e.status, e.step, e.time) == (Status.DT_UNDERFLOW, 1, 0.0)
    assert e.particle == int(integrate.cfl_limiting_particle(pb.particles, pb.params, pb.scheme))


def test_fixed_dt_above_the_cfl_limit_on_the_driver():
    """A fixed time.dt far above the CFL limit of the initial state fails its first step (not
    committed) instead of blowing up later."""
    _, pb = tube()
    cfg, pb = tube(f"time.dt={3.0 * integrate.FIXED_DT_SLACK * cfl_limit(pb)!r}")
    with pytest.raises(SimulationError, match="above the CFL limit") as ei:
        run_problem(pb, cfg, quiet=True)
    assert ei.value.status & Status.DT_ABOVE_CFL and (ei.value.step, ei.value.time) == (1, 0.0)


def test_n_steps_above_the_cfl_limit_is_refused_before_running():
    _, pb = tube()
    limit = cfl_limit(pb)
    n_min = math.ceil(pb.t_end / limit)
    with pytest.raises(InputError) as ei:
        make_simulate(pb, n_steps=n_min - 1)
    msg = str(ei.value)
    assert f"n_steps={n_min - 1}" in msg and f"n_steps >= {n_min}" in msg and f"{limit:.4g}" in msg
    assert f"{pb.t_end / (n_min - 1):.4g}" in msg
    assert make_simulate(pb, n_steps=n_min).n_steps == n_min     # the smallest admissible count is accepted
    shear = periodic_shear_problem()
    with pytest.raises(InputError, match="n_steps >= "):
        dp.make_solve(shear, n_steps=2)                        # the diffrax fixed-step solve too
    dp.make_solve(shear, n_steps=2, adaptive=True)              # (an adaptive solve only starts with it)


def test_default_step_count_runs_through_a_flow_that_speeds_up():
    """Sod's post-shock state is faster than the initial states (|u| + c up by ~1.6x); the in-run
    test allows FIXED_DT_SLACK (2x) over the current CFL step, so the default count completes."""
    _, pb = tube()
    out = run_differentiable(make_simulate(pb, checkpoint="none"), pb.params, pb.particles)
    assert out.ok and np.isfinite(np.asarray(out.particles.q)).all()


def test_state_that_speeds_up_fails_above_the_cfl_limit_on_both_paths(monkeypatch):
    """Sod's tube at the smallest admissible step count, with no slack over the CFL step: the
    flow behind the shock is faster (|u| + c) than the initial state, so the fixed step soon
    exceeds its CFL limit: the run stops at that step (DT_ABOVE_CFL, not committed) and the error
    names the step count it needs."""
    monkeypatch.setattr(integrate, "FIXED_DT_SLACK", 1.0)
    cfg, pb = tube()
    n_min = math.ceil(pb.t_end / cfl_limit(pb))
    sim = make_simulate(pb, n_steps=n_min, checkpoint="none")
    out = jax.jit(sim)(pb.params, pb.particles)
    k = int(out.failed_step)
    assert Status(int(out.status)) == Status.DT_ABOVE_CFL and k > 1
    assert float(out.failed_time) == pytest.approx((k - 1) * sim.dt, rel=1e-12)
    with pytest.raises(SimulationError, match=r"n_steps >= \d+ for it") as ei:
        run_differentiable(sim, pb.params, pb.particles)
    assert ei.value.step == k and ei.value.particle is not None
    need = int(str(ei.value).split("n_steps >= ")[-1].split()[0])
    assert need > n_min
    # the driver with the same fixed step
    cfg, pb = tube(f"time.dt={pb.t_end / n_min!r}")
    with pytest.raises(SimulationError, match="above the CFL limit") as ei:
        run_problem(pb, cfg, quiet=True)
    assert ei.value.status == Status.DT_ABOVE_CFL and ei.value.step > 1


# --------------------------------------------------------------------------------------------
# MOOD
# --------------------------------------------------------------------------------------------

def test_mood_unresolved_stops_both_paths():
    """Sod with MOOD and a single MOOD iteration leaves flags unresolved in an early step: a
    particle would keep a flagged state, so the run stops loudly (it used to be a statistic)."""
    pb = build_problem(config.load("configs/sod_ideal_gas.toml", ["case.n=60", "scheme.mood_max_iter=1",
                                                                  "output.progress=false"]))
    with pytest.raises(SimulationError, match="MOOD flags not resolved") as ei:
        Simulation(pb).run(progress=False)
    assert ei.value.status == Status.MOOD_UNRESOLVED and ei.value.step >= 1 and ei.value.particle is not None
    out = jax.jit(make_simulate(pb, checkpoint="none"))(pb.params, pb.particles)
    assert Status(int(out.status)) == Status.MOOD_UNRESOLVED and int(out.failed_step) >= 1
    assert 0 <= int(out.bad_particle) < pb.particles.n
    assert np.asarray(pb.particles.kind)[int(out.bad_particle)] == Kind.FLUID


# --------------------------------------------------------------------------------------------
# diffrax
# --------------------------------------------------------------------------------------------

def test_diffrax_solve_reports_a_nan_solve():
    pb = periodic_shear_problem()
    sol_fn = dp.make_solve(pb, n_steps=20, ts=[0.01, 0.02])
    sol = jax.jit(sol_fn)(pb.params, pb.particles)
    assert int(sol.stats["status"]) == 0 and int(sol.stats["failed_save"]) == -1
    dp.check(sol)
    bad = with_param(pb.params, "physics.mu", jnp.nan)
    sol = jax.jit(sol_fn)(bad, pb.particles)
    assert Status(int(sol.stats["status"])) & Status.NONFINITE and int(sol.stats["failed_save"]) == 0
    with pytest.raises(SimulationError, match="non-finite.*saved state 0 at t=0.01"):
        dp.check(sol)
    with pytest.raises(SimulationError, match="non-finite"):
        dp.solve(pb, params=bad, n_steps=20)


# --------------------------------------------------------------------------------------------
# the README example and the CLI
# --------------------------------------------------------------------------------------------

def test_readme_example_with_too_few_steps_names_the_admissible_count():
    pb = build_problem(config.load("configs/taylor_green_2d.toml", ["case.n=16", "eos.c0=10"]))
    with pytest.raises(InputError, match=r"n_steps=100.*CFL limit .*n_steps >= 585"):
        make_simulate(pb, n_steps=100, checkpoint="nested")


def test_cli_sensitivity_never_exits_0_on_a_bad_run(tmp_path, capsys, monkeypatch):
    from mlsph_jax.cli import main

    rc = main(["sensitivity", "configs/taylor_green_2d.toml", "--set", "case.n=16", "eos.c0=10", "--n-steps", "100",
               "--wrt", "physics.mu", "--of", "ke_final", "--out", str(tmp_path / "a")])
    assert rc != 0 and "n_steps >= 585" in capsys.readouterr().err
    assert not (tmp_path / "a" / "sensitivity.json").exists()
    # a run that fails inside (Sod's tube at the default step count with no slack over the CFL
    # step: the flow outgrows the CFL limit of the initial state): exit 1, the error names the
    # cause, step, particle and the fix
    monkeypatch.setattr(integrate, "FIXED_DT_SLACK", 1.0)
    cfg = tmp_path / "sod.toml"
    cfg.write_text(DEFAULT_CONFIG)
    rc = main(["sensitivity", str(cfg), "--set", *SMALL_SOD, "--wrt", "eos.gamma", "--of", "ke_final",
               "--out", str(tmp_path / "b")])
    err = capsys.readouterr().err
    assert rc == 1 and "above the CFL limit" in err and "in step" in err and "particle" in err
    assert "n_steps >= " in err and "--n-steps" in err
    assert not (tmp_path / "b" / "sensitivity.json").exists()
