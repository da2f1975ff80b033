"""``scheme.conservation_projection`` (decision 112; docs/moving_particles.md §9): with the
self-flux term of eq. 4.36 the totals of V U and of V drift in moving frames (the fluid rows'
defect terms do not cancel); the projection subtracts V_i R / sum V from every fluid row, so the
totals change by wall fluxes and sources alone, to round-off, while uniform states stay exact.
"""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mlsph_jax import config
from mlsph_jax import neighbors as nb
from mlsph_jax.cases import build_problem
from mlsph_jax.eos import get_eos, to_conservative
from mlsph_jax.errors import InputError
from mlsph_jax.rhs import geometry, rhs
from mlsph_jax.run import setup_run
from mlsph_jax.sensitivity import sensitivity
from mlsph_jax.simulation import Simulation, run_problem
from mlsph_jax.testing import jittered_lattice

ROOT = Path(__file__).resolve().parents[1]
TG = ROOT / "configs" / "taylor_green_2d_mlsph.toml"
COUETTE = ROOT / "configs" / "couette.toml"
QUIET = ("output.progress=false", "output.plots=false")
L = 2.0 * np.pi


def _cloud(frame, projection, n=12, uniform=False, sets=()):
    """The §4.5.1 config's scheme (``frame``) on a jittered periodic n x n cloud with a vortex-like
    (or uniform) state: ``(rates (dx, dV, dq), V, U)``."""
    cfg = config.load(TG, [f"case.n={n}", f"scheme.frame={frame}",
                           f"scheme.conservation_projection={str(projection).lower()}", *sets, *QUIET])
    pb = build_problem(cfg)
    x = np.mod(jittered_lattice(n, 0.25, seed=2, upper=L, dim=2), L)
    vol = np.full(len(x), L * L / len(x)) * (1.0 + 0.1 * np.cos(x[:, 0] + 2 * x[:, 1]))
    vol *= L * L / vol.sum()
    rng = np.random.default_rng(3)
    if uniform:
        u, rho = np.tile([0.7, -0.4], (len(x), 1)), np.ones(len(x))
    else:
        u = 0.5 * np.stack([np.sin(x[:, 1]), np.cos(x[:, 0])], 1) + 0.05 * rng.uniform(-1, 1, x.shape)
        rho = 1.0 + 0.01 * np.cos(x[:, 0])
    U = to_conservative(jnp.asarray(rho), jnp.asarray(u), None, get_eos("tait"), pb.params)
    p = pb.particles.replace(x=jnp.asarray(x), vol=jnp.asarray(vol), q=U * jnp.asarray(vol)[:, None])
    sch = pb.scheme
    _, nl = nb.allocate(x, sch.beta * np.sqrt(vol), pb.domain, support=sch.support)
    geom = geometry(p.x, p.vol, nl, sch, pb.domain)
    return [np.asarray(r) for r in rhs(p, pb.params, geom, sch)], vol, np.asarray(U)


@pytest.mark.parametrize("frame,sets", [("ale_shift", ()), ("lagrangian", ()),
                                        ("ale_shift", ("scheme.reconstruction_degree=0",))],
                         ids=["ale_shift", "lagrangian", "ale_shift-separate-viscous-pass"])
def test_projection_zeroes_the_net_defect_with_a_uniform_rate(frame, sets):
    """On a disordered periodic cloud the fluid rows' totals sum_i d(V_i U_i)/dt and sum_i dV_i/dt
    are not zero without the projection (shifting frame: mass 1e-4 of sum |rate|, the defect of
    §9; the Lagrangian frame keeps mass exact but not the total volume), and zero to round-off
    with it, also where the viscous terms come from their own pass (first-order states).  The
    projection changes each row by V_i times one rate per component (the volume-weighted least
    change), nothing else, and not the positions' rate."""
    (dx0, dv0, dq0), vol, _ = _cloud(frame, False, sets=sets)
    (dx1, dv1, dq1), _, _ = _cloud(frame, True, sets=sets)
    rel = lambda r: abs(r.sum(0)) / np.abs(r).sum(0)   # noqa: E731
    assert rel(dv0) > 1e-6 and rel(dv1) < 1e-13, (rel(dv0), rel(dv1))
    assert np.all(rel(dq1) < 1e-13), rel(dq1)
    if frame == "ale_shift":
        assert rel(dq0)[0] > 1e-6, rel(dq0)
    else:       # w = u: no mass flux at all
        assert rel(dq0)[0] < 1e-13 and np.abs(dq1[:, 0] - dq0[:, 0]).max() < 1e-14
    np.testing.assert_array_equal(dx1, dx0)
    for a, b in ((dq1, dq0), (dv1[:, None], dv0[:, None])):
        per_volume = (a - b) / vol[:, None]           # the same rate in every row
        spread = per_volume.max(0) - per_volume.min(0)
        assert np.all(spread <= 1e-10 * np.abs(per_volume).max(0) + 1e-18), spread


def test_projection_keeps_a_uniform_state_exact_on_disordered_shifted_particles():
    """A uniform stream on the jittered cloud in the shifting frame: the drift moves the particles
    and changes their volumes, the defect R of V U is U times the volume's, so the projected rates
    still satisfy d(V_i U_i)/dt = U dV_i/dt in every row: U stays uniform and exact, to the
    unprojected scheme's own round-off (measured: 2.7e-14 in the momentum rows, from the
    cancellation of the Tait pressure's terms, against rates of 0.02; the same with and without)."""
    (_, dv0, dq0), _, U = _cloud("ale_shift", False, uniform=True)
    (_, dv, dq), _, _ = _cloud("ale_shift", True, uniform=True)
    assert np.abs(dv).max() > 1e-3 and np.abs(dv - dv0).max() > 1e-5    # the drift and the projection act
    r0 = np.abs(dq0 - U * dv0[:, None]).max(0)
    r1 = np.abs(dq - U * dv[:, None]).max(0)
    assert np.all(r0 < 1e-13) and np.all(r1 <= 1.5 * r0 + 1e-16), (r0, r1)


def _couette(projection, t_end="0.3"):
    cfg = config.load(COUETTE, [*QUIET, "case.nx=8", "case.ny=10", "time.cfl=0.6", "case.walls=boundary_integral",
                                "scheme.frame=ale_shift", f"time.t_end={t_end}",
                                f"scheme.conservation_projection={str(projection).lower()}"])
    res = run_problem(build_problem(cfg), cfg, out_dir=None, quiet=True)
    return res.summary, res.particles


def test_couette_on_shifted_particles_keeps_mass_and_area_with_the_projection():
    """Start-up Couette on boundary-integral walls in the shifting frame (t = 0.3): without the
    projection the mass drifts (the wall rows' first-moment correction, §9); with it mass and the
    channel's area are kept to round-off and the velocity error does not grow (t = 1, measured:
    L-inf 1.661e-3 against 1.698e-3, mass -7e-15 against 9.7e-6)."""
    s0, p0 = _couette(False)
    s1, p1 = _couette(True)
    assert s0["status"] == s1["status"] == "ok"
    area = float(np.sum(np.asarray(p1.vol)))
    area0 = float(np.sum(np.asarray(build_problem(config.load(
        COUETTE, [*QUIET, "case.nx=8", "case.ny=10", "case.walls=boundary_integral"])).particles.vol)))
    assert abs(s0["conservation"]["mass"]) > 1e-9, s0["conservation"]
    assert abs(s1["conservation"]["mass"]) < 1e-12, s1["conservation"]
    assert abs(area / area0 - 1) < 1e-13 < abs(float(np.sum(np.asarray(p0.vol))) / area0 - 1)
    assert s1["metrics"]["linf_u_error"] <= 1.05 * s0["metrics"]["linf_u_error"], (s0["metrics"], s1["metrics"])


def test_gradient_through_the_projection_matches_finite_differences():
    """d E_k(t_end) / d mu of a short shifted-frame Taylor-Green run with the projection (the
    global sums are differentiated like every other term): reverse mode against central
    differences."""
    cfg = config.load(TG, ["case.n=10", "time.t_end=0.1", "scheme.conservation_projection=true", *QUIET])
    res = sensitivity(build_problem(cfg), ["physics.mu"], "ke_final", check_fd=True, mode="reverse", n_steps=6)
    e = res["gradients"]["physics.mu"]
    assert abs(e["gradient"]) > 0 and e["rel_disagreement"] < 1e-5, e


def _problem(path, *sets):
    return build_problem(config.load(path, [*QUIET, *sets]))


def test_projection_is_refused_where_it_has_no_meaning():
    """Bad input, named: without the self-flux term there is no defect to project; with particles
    that are not fluid (mirror ghosts, a frozen far field) the fluid's closure does not sum to zero
    and the projection would accelerate a fluid at rest (refused on every run path, setup_run); the
    spatial decomposition does not build the global sum across its shards."""
    with pytest.raises(InputError, match=r"scheme\.conservation_projection=True with scheme\.self_flux=False"):
        _problem(TG, "scheme.self_flux=false", "scheme.conservation_projection=true")
    pb = _problem(COUETTE, "case.walls=mirror_ghosts", "scheme.conservation_projection=true")
    with pytest.raises(InputError, match=r"conservation_projection=True with \d+ particles that are not fluid"):
        setup_run(pb)
    with pytest.raises(InputError, match=r"allowed: periodic domains and boundary-integral walls"):
        Simulation(pb)
    pb = _problem(TG, "case.n=10", "scheme.frame=eulerian", "scheme.conservation_projection=true")
    with pytest.raises(InputError, match=r"conservation_projection=true with run\.decomposition=\"spatial\""):
        Simulation(pb, devices=1, decomposition="spatial")
    assert jax.devices()    # (the spatial refusal comes before any device is used)
