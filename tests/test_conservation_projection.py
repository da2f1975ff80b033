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
from mlsph_jax.differentiable import make_simulate
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


@pytest.mark.parametrize("sets", [(), ("scheme.reconstruction_degree=0",)], ids=["fused", "separate-viscous-pass"])
def test_projected_totals_are_the_wall_fluxes_on_disordered_particles_between_plates(sets):
    """Boundary-integral plates (Couette channel, shifting frame) around a jittered layout with a
    random state and volumes: with the projection the fluid's sum of d(VU)/dt is the plates' flux
    exactly (no mass through a wall; momentum -sum_b dGamma_b (p_b n_b - tau_b n_b), all of each wall
    point's weight landing on the fluid) and the sum of dV/dt their normal motion (zero), to
    round-off in every component; without it the mass, momentum and volume totals are off."""
    from mlsph_jax.eos import to_primitive
    from mlsph_jax.testing import rhs_once

    def totals(projection):
        cfg = config.load(COUETTE, [*QUIET, "case.nx=8", "case.ny=10", "case.walls=boundary_integral",
                                    "scheme.frame=ale_shift", *sets,
                                    f"scheme.conservation_projection={str(projection).lower()}"])
        pb = build_problem(cfg)
        p = pb.particles
        rng = np.random.default_rng(1)
        x = np.asarray(p.x) + 0.15 * float(np.sqrt(np.asarray(p.vol).min())) * rng.uniform(-1, 1, p.x.shape)
        U0 = np.asarray(p.q / p.vol[:, None])
        rho = U0[:, 0] * (1 + 0.01 * rng.uniform(-1, 1, len(x)))
        u = U0[:, 1:3] / U0[:, :1] + 0.1 * rng.uniform(-1, 1, (len(x), 2))
        U = to_conservative(jnp.asarray(rho), jnp.asarray(u), None, get_eos(pb.scheme.eos), pb.params)
        vol = jnp.asarray(np.asarray(p.vol) * (1 + 0.05 * rng.uniform(-1, 1, len(x))))
        p = p.replace(x=jnp.asarray(x), q=U * vol[:, None], vol=vol)
        assert np.all(np.asarray(p.kind) == 0)
        _, dv, dq = (np.asarray(a) for a in rhs_once(pb, p, pb.boundary))
        prim = to_primitive(p.q / p.vol[:, None], get_eos(pb.scheme.eos), pb.params)
        bp, st, vals, pw, tau, _ = pb.boundary.wall_state(p, pb.params, pb.scheme, prim)
        weight = np.asarray(bp.dgamma) * np.asarray(jnp.sum(jnp.where(st.mask, vals, 0.0), axis=1))
        wall_momentum = np.sum(weight[:, None] * np.asarray(pw[:, None] * bp.normal - tau), axis=0)
        wall_motion = float(np.sum(weight * np.asarray(jnp.sum(bp.velocity * bp.normal, axis=-1))))
        scale = np.abs(dq).sum(0)
        return (abs(dq[:, 0].sum()) / scale[0], np.abs(dq[:, 1:].sum(0) + wall_momentum) / scale[1:],
                abs(dv.sum() - wall_motion) / np.abs(dv).sum())

    mass, momentum, volume = totals(True)
    assert mass < 1e-13 and np.all(momentum < 1e-13) and volume < 1e-13, (mass, momentum, volume)
    mass, momentum, volume = totals(False)
    assert mass > 1e-6 and np.all(momentum > 1e-6) and volume > 1e-6, (mass, momentum, volume)


def test_projected_rates_are_differentiable():
    """The global sums of the projection have the derivative of the rates they came from: reverse
    and forward derivatives of the projection term (projected minus plain right-hand side, a
    smooth function of the state: the Rusanov flux' |u.n| kinks cancel in the difference) with
    respect to the state against central differences on the disordered shifted cloud."""
    from jax.test_util import check_grads

    pb = build_problem(config.load(TG, ["case.n=12", "scheme.conservation_projection=false", *QUIET]))
    on = build_problem(config.load(TG, ["case.n=12", "scheme.conservation_projection=true", *QUIET])).scheme
    x = np.mod(jittered_lattice(12, 0.25, seed=2, upper=L, dim=2), L)
    vol = jnp.full(len(x), L * L / len(x))
    rng = np.random.default_rng(4)
    u = 0.3 * rng.uniform(-1, 1, x.shape)
    U = to_conservative(jnp.asarray(1.0 + 0.01 * rng.uniform(-1, 1, len(x))), jnp.asarray(u), None,
                        get_eos("tait"), pb.params)
    p = pb.particles.replace(x=jnp.asarray(x), vol=vol, q=U * vol[:, None])
    sch = pb.scheme
    _, nl = nb.allocate(x, sch.beta * np.sqrt(np.asarray(vol)), pb.domain, support=sch.support)
    geom = geometry(p.x, p.vol, nl, sch, pb.domain)
    f = jax.jit(lambda q: rhs(p.replace(q=q), pb.params, geom, on)[2] - rhs(p.replace(q=q), pb.params, geom, sch)[2])
    assert float(jnp.abs(f(p.q)).max()) > 1e-6                 # the projection acts on this state
    check_grads(f, (p.q,), order=1, modes=("fwd", "rev"), eps=1e-6, atol=1e-9, rtol=1e-7)


@pytest.mark.slow   # 45 s (CI time); the default suite holds the projection's derivative by check_grads above
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
    with pytest.raises(InputError, match=r"scheme\.conservation_projection=true with scheme\.self_flux=false"):
        _problem(TG, "scheme.self_flux=false", "scheme.conservation_projection=true")
    pb = _problem(COUETTE, "case.walls=mirror_ghosts", "scheme.conservation_projection=true")
    with pytest.raises(InputError, match=r"conservation_projection=true with \d+ particles that are not fluid"):
        setup_run(pb)
    with pytest.raises(InputError, match=r"allowed: periodic domains and closed boundary-integral walls"):
        Simulation(pb)
    pb = _problem(ROOT / "configs" / "riemann_r1_tait.toml", "case.n=60", "scheme.conservation_projection=true")
    with pytest.raises(InputError, match=r"\d+ particles that are not fluid"):     # its frozen ends
        make_simulate(pb)
    pb = _problem(TG, "case.n=10", "scheme.frame=eulerian", "scheme.conservation_projection=true")
    with pytest.raises(InputError, match=r"conservation_projection=true with run\.decomposition=\"spatial\""):
        Simulation(pb, devices=1, decomposition="spatial")
    with pytest.raises(InputError, match=r"local_time_stepping=true with scheme\.conservation_projection=true"):
        Simulation(pb, local_time_stepping=True)


def test_projection_is_refused_with_walls_that_are_not_closed():
    """Bad input: walls whose normals do not sum to zero (one plate alone) leave a net defect for a
    fluid at rest; the check names the setting and the gap."""
    from types import SimpleNamespace

    from mlsph_jax.rhs import check_conservation_projection

    cfg = config.load(TG, ["case.n=10", "scheme.conservation_projection=true", *QUIET])
    sch = build_problem(cfg).scheme
    kind = np.zeros(4, np.int32)

    def walls(normals):
        bp = SimpleNamespace(dgamma=np.full(len(normals), 0.5), normal=np.asarray(normals, float))
        return SimpleNamespace(points=lambda params: bp, wall_terms=object())

    check_conservation_projection(sch, kind, walls([[0, 1], [0, -1]]))        # two plates: closed
    with pytest.raises(InputError, match=r"conservation_projection=true with walls that are not closed"):
        check_conservation_projection(sch, kind, walls([[0, 1], [0, 1]]))
