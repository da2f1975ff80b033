"""The ``lid_driven_cavity`` case (thesis §3.7.5, SPEC §12.1 V7, §8.3): Ghia reference data,
config checks, walls and corner ghosts, boundary-integral walls (thesis eq. 4.24; decision 61),
centre-line interpolation, and a coarse Re = 100 run against Ghia et al. (1982).

Measured at Re = 100 with the QUADRATIC reconstruction of the config before issue 14 (Eulerian
MLSPH-ALE, c0 = 10 u_lid, CFL 0.6), deviations from Ghia at the 15 interior points of each centre
line (max / rms); the config's scheme now does better (24 x 24: 0.0066 / 0.0064, see RUN24 below):

    n x n     stopped at (steady_tol 2e-3)   u dev            v dev            u_min (Ghia -0.2109)
    24 x 24   t = 6                          0.0702 / 0.0407  0.0670 / 0.0347  -0.2197
    40 x 40   t = 8 (the config's size)      0.0451 / 0.0251  0.0324 / 0.0162  -0.2095
    50 x 50   t = 8                          0.0341 / 0.0180  0.0190 / 0.0093  -0.2096
    (50 x 50 continued to t = 20: u 0.0342 / 0.0177, v 0.0175 / 0.0085)

The 24 x 24 state misses Ghia's Re = 400 profiles by 0.229 (u) / 0.293 (v) and the Re = 1000
profiles by 0.306 / 0.400, and the fluid at rest misses the Re = 100 ones by 0.80 / 0.245, so
the bounds below (25 % above the measured 24 x 24 values of the config's scheme) separate the Re = 100 solution from
all of them.  (At 24 x 24 the simulated flow itself depends only weakly on Re: u_min = -0.2066,
-0.2123, -0.2197, -0.2266, -0.2278 for Re = 10, 30, 100, 1000, 1e5 at t = 6 -- the centre lines
at Re <= 100 are close to Stokes flow, and the scheme's numerical dissipation caps the effective
Reynolds number at a few hundred on such coarse lattices; at 40 x 40, Re = 1000 departs clearly,
u_min = -0.243 at t = 8 and still falling.)
"""

from __future__ import annotations

import numpy as np
import pytest

from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.cases.lid_driven_cavity import cavity_metrics, ghia_deviations, mls_interpolate, worst_points
from mlsph_jax.errors import ConfigError, InputError
from mlsph_jax.reference import ghia
from mlsph_jax.simulation import run_problem
from mlsph_jax.state import Kind

CFG = "configs/lid_driven_cavity.toml"
QUIET = ("output.progress=false", "output.plots=false")


def _err(overrides, path=CFG) -> str:
    with pytest.raises(ConfigError) as e:
        config.load(path, list(overrides))
    return str(e.value)


# --- Ghia data ---------------------------------------------------------------------------------

def test_ghia_table_matches_the_shared_reference_and_flags_the_misprint():
    y, u = ghia.centerline("u", 100)
    assert y.size == 17 and (y[0], y[-1], u[0], u[-1]) == (0.0, 1.0, 0.0, 1.0)
    assert u[np.argmin(u)] == -0.21090 and y[np.argmin(u)] == 0.4531
    x, v = ghia.centerline("v", 1000)
    assert x.size == 17 and v[x == 0.9063][0] == -0.51550 and v[x == 0.5][0] == 0.02526
    # the flagged misprint v(Re=400, x=0.9063) = -0.23827 is left out unless asked for
    x4, v4 = ghia.centerline("v", 400)
    assert x4.size == 16 and 0.9063 not in x4
    xa, va = ghia.centerline("v", 400, include_misprint=True)
    assert va[xa == 0.9063][0] == -0.23827 and v4[x4 == 0.5][0] == 0.05186
    xi, _ = ghia.centerline("u", 400, include_walls=False)
    assert xi.size == 15 and xi.min() > 0 and xi.max() < 1
    # value for value identical to the project's shared reference files, when present
    import pathlib

    shared = pathlib.Path("/work/shared/reference")
    if shared.is_dir():
        for comp, fname in (("u", "ghia1982_u_vertical_centerline.csv"), ("v", "ghia1982_v_horizontal_centerline.csv")):
            ref = np.loadtxt(shared / fname, delimiter=",", skiprows=1)
            for k, re in enumerate(ghia.REYNOLDS):
                c, val = ghia.centerline(comp, re, include_misprint=True)
                np.testing.assert_array_equal(c, ref[:, 0])
                np.testing.assert_array_equal(val, ref[:, 1 + k])


def test_ghia_input_errors():
    assert ghia.table_reynolds(400.0000001) == 400 and ghia.table_reynolds(3200) is None
    with pytest.raises(InputError, match="component"):
        ghia.centerline("w", 100)
    with pytest.raises(InputError, match="re=250"):
        ghia.centerline("u", 250)


def test_mls_interpolation_reproduces_quadratics():
    rng = np.random.default_rng(0)
    xs = rng.uniform(-0.2, 1.2, (3000, 2))
    f = lambda x: 1.0 + 2 * x[:, 0] - x[:, 1] + 0.5 * x[:, 0] ** 2 - 3 * x[:, 0] * x[:, 1] + x[:, 1] ** 2  # noqa: E731
    xe = rng.uniform(0.0, 1.0, (50, 2))
    np.testing.assert_allclose(mls_interpolate(xs, f(xs), xe, 0.06), f(xe), atol=1e-10)
    two = np.stack([f(xs), 2 * f(xs)], 1)
    np.testing.assert_allclose(mls_interpolate(xs, two, xe, 0.06), np.stack([f(xe), 2 * f(xe)], 1), atol=1e-10)


# --- config ------------------------------------------------------------------------------------

def test_config_and_derived_viscosity():
    cfg = config.load(CFG)
    c = cfg["case"]
    assert (c["n"], c["length"], c["u_lid"], c["re"]) == (40, 1.0, 1.0, 100.0)
    assert cfg["eos"] == {"kind": "tait", "rho0": 1.0, "c0": 10.0, "gamma": 7.0, "p0": 0.0}
    assert cfg["physics"]["mu"] == 0.0 and cfg["scheme"]["frame"] == "eulerian"
    pb = build_problem(cfg)
    assert float(pb.params["physics.mu"]) == pytest.approx(0.01) and pb.scheme.viscous
    assert pb.config["physics"]["mu"] == pytest.approx(0.01) and pb.steady_tol == c["steady_tol"] > 0
    # Re = 400 / 1000 are one override away; an explicit, consistent physics.mu is accepted
    for re, mu in ((400, 0.0025), (1000, 0.001)):
        pbr = build_problem(config.load(CFG, [f"case.re={re}"]))
        assert float(pbr.params["physics.mu"]) == pytest.approx(mu, rel=1e-12)
    config.load(CFG, ["case.re=400", "physics.mu=0.0025"])
    # the resolved config written to the output round-trips (it records the derived mu)
    assert config.validate(pb.config)["physics"]["mu"] == pytest.approx(0.01)


@pytest.mark.parametrize("overrides, fragments", [
    (["physics.mu=0.02"], ["invalid physics.mu=0.02", "case.re=100", "0.01", "set case.re instead"]),
    (["scheme.frame=lagrangian"], ['invalid scheme.frame="lagrangian"', '"eulerian"']),
    (["physics.body_force=[0.0, -9.81]"], ["invalid physics.body_force=[0.0, -9.81]", "allowed: []"]),
    (["case.re=0"], ["invalid case.re=0"]),
    (["case.u_lid=-1"], ["invalid case.u_lid=-1"]),
    (["case.n=4"], ["invalid case.n=4"]),
    (["case.steady_tol=-1"], ["invalid case.steady_tol=-1"]),
    (["case.reynolds=100"], ["unknown key case.reynolds"]),
    (["case.walls=boundary_integral", "scheme.method=sph_ale"],
     ['invalid case.walls="boundary_integral" with scheme.method="sph_ale"', "MLS shape functions",
      'case.walls = "mirror_ghosts"']),
    (["case.walls=ghosts"], ['invalid case.walls="ghosts"', "boundary_integral", "mirror_ghosts"]),
])
def test_bad_input_names_the_key(overrides, fragments):
    msg = _err(overrides)
    for f in fragments:
        assert f in msg, (f, msg)


def test_eos_must_be_tait():
    with pytest.raises(ConfigError) as e:
        config.load(None, case="lid_driven_cavity", overrides=["eos.kind=ideal_gas"])
    assert 'invalid eos.kind="ideal_gas"' in str(e.value) and '"tait"' in str(e.value)


# --- set-up ------------------------------------------------------------------------------------

def test_walls_and_corner_ghosts():
    cfg = config.load(CFG, ["case.n=20"])
    pb = build_problem(cfg)
    p = pb.particles
    x, kind = np.asarray(p.x), np.asarray(p.kind)
    fluid, ghost = kind == int(Kind.FLUID), kind == int(Kind.GHOST)
    dx = 1.0 / 20
    # 3 layers per wall (support radius 3 dx) and 3 x 3 corner ghosts per corner
    assert fluid.sum() == 400 and ghost.sum() == 4 * 3 * 20 + 4 * 9
    inside = (x[:, 0] > 0) & (x[:, 0] < 1) & (x[:, 1] > 0) & (x[:, 1] < 1)
    assert np.array_equal(inside, fluid)
    assert x[ghost].min() == pytest.approx(-2.5 * dx) and x[ghost].max() == pytest.approx(1 + 2.5 * dx)
    np.testing.assert_array_equal(np.asarray(pb.params["boundary.wall_velocity"]),
                                  [[0, 0], [1, 0], [0, 0], [0, 0]])
    # fluid at rest: lid ghosts carry u_G = 2 u_lid - 0 = 2, the other ghosts (and the corner
    # ghosts, u_GC = u_F) are at rest
    vel = np.asarray(p.q[:, 1:3] / p.q[:, :1])
    lid = ghost & (x[:, 1] > 1) & (x[:, 0] > 0) & (x[:, 0] < 1)
    corner = ghost & ~((x[:, 0] > 0) & (x[:, 0] < 1)) & ~((x[:, 1] > 0) & (x[:, 1] < 1))
    assert lid.sum() == 60 and corner.sum() == 36
    np.testing.assert_allclose(vel[lid], np.tile([2.0, 0.0], (60, 1)))
    assert np.all(vel[ghost & ~lid] == 0.0) and np.all(vel[fluid] == 0.0)
    assert not any(pb.domain.periodic)


def test_initial_state_metrics():
    """At rest the centre-line velocities are 0 except next to the lid (the MLS fit sees the
    lid ghosts): the deviation from Ghia is that of Ghia's profile itself."""
    pb = build_problem(config.load(CFG, ["case.n=20"]))
    m = cavity_metrics(pb.particles, pb.params, pb.config, pb.scheme, 100)
    assert m["kinetic_energy"] == 0.0
    assert m["ghia_v_max_abs_dev"] == pytest.approx(0.24533, abs=1e-12)     # |v_Ghia(0.8047)|
    assert m["ghia_u_max_abs_dev"] > 0.5


def test_ghia_deviations_are_signed_and_located():
    """A quadratic velocity field (u = 0.3 - 0.8 y + 1.1 y^2, v = 0.2 x - 0.5 x^2 on every particle,
    ghosts included) is reproduced by the MLS fit, so the signed deviations at Ghia's interior
    points are the field minus Ghia's values, and the worst points are where |field - Ghia| is
    largest; the metrics are their max and rms."""
    pb = build_problem(config.load(CFG, ["case.n=20"]))
    x = np.asarray(pb.particles.x)
    vel = np.stack([0.3 - 0.8 * x[:, 1] + 1.1 * x[:, 1] ** 2, 0.2 * x[:, 0] - 0.5 * x[:, 0] ** 2], 1)
    p = _with_state(pb, np.ones(len(x)), vel, pb.params)
    (yu, du), (xv, dv) = dev = ghia_deviations(p, pb.params, pb.config, pb.scheme, 1000)
    yg, ug = ghia.centerline("u", 1000, include_walls=False)
    xg, vg = ghia.centerline("v", 1000, include_walls=False)
    np.testing.assert_array_equal(yu, yg)
    np.testing.assert_array_equal(xv, xg)
    np.testing.assert_allclose(du, 0.3 - 0.8 * yg + 1.1 * yg**2 - ug, atol=1e-10)
    np.testing.assert_allclose(dv, 0.2 * xg - 0.5 * xg**2 - vg, atol=1e-10)
    w = worst_points(dev)
    ku, kv = np.argmax(np.abs(du)), np.argmax(np.abs(dv))
    assert w == {"u": [yg[ku], du[ku]], "v": [xg[kv], dv[kv]]}
    m = cavity_metrics(p, pb.params, pb.config, pb.scheme, 1000)
    assert m["ghia_u_max_abs_dev"] == abs(w["u"][1]) and m["ghia_v_max_abs_dev"] == abs(w["v"][1])
    assert m["ghia_u_rms_dev"] == pytest.approx(np.sqrt(np.mean(du**2)), rel=1e-12)


# --- the mirror walls' tangential force (decision 81) ------------------------------------------

def test_wall_tangential_components_of_the_ghosts():
    """Lid and bottom ghosts: x tangential; side-wall ghosts: y; corner ghosts and fluid: none."""
    pb = build_problem(config.load(CFG, ["case.n=10"]))
    p = pb.particles
    t = np.asarray(pb.boundary.wall_tangential(p.n, 2))
    x, kind = np.asarray(p.x), np.asarray(p.kind)
    inx, iny = (x[:, 0] > 0) & (x[:, 0] < 1), (x[:, 1] > 0) & (x[:, 1] < 1)
    fluid = kind == int(Kind.FLUID)
    np.testing.assert_array_equal(t[fluid], 0.0)
    np.testing.assert_array_equal(t[~fluid & inx & ~iny], np.tile([1.0, 0.0], ((~fluid & inx & ~iny).sum(), 1)))
    np.testing.assert_array_equal(t[~fluid & iny & ~inx], np.tile([0.0, 1.0], ((~fluid & iny & ~inx).sum(), 1)))
    np.testing.assert_array_equal(t[~fluid & ~inx & ~iny], 0.0)


def _lid_layer_rates(flag: str, n: int = 16):
    """Rates ``dq / V`` of the cavity (Re = 1000, ``scheme.ghost_shear_dissipation = flag``) in the
    lid-layer state u = exp(-(1 - y)/delta), v = 0, rho = rho0 (delta = 1.5 dx, the Re = 1000 lid
    layer at 50 x 50), ghosts regenerated: ``(x, fluid mask, inviscid rates (physics.mu = 0), full
    rates, mu, dx, delta)``."""
    import jax
    import jax.numpy as jnp

    from mlsph_jax import neighbors as nb
    from mlsph_jax.rhs import geometry, rhs
    from mlsph_jax.state import Params

    pb = build_problem(config.load(CFG, [*QUIET, f"case.n={n}", "case.re=1000",
                                         f"scheme.ghost_shear_dissipation={flag}"]))
    p, sch, P = pb.particles, pb.scheme, pb.params
    _, nl = nb.allocate(p.x, sch.beta * p.vol ** 0.5, pb.domain)
    x = np.asarray(p.x)
    dx = 1.0 / n
    delta = 1.5 * dx
    vel = np.stack([np.exp(-(1.0 - x[:, 1]) / delta), np.zeros(len(x))], 1)
    p = pb.boundary.apply(_with_state(pb, np.ones(len(x)), vel, P), P)
    f = jax.jit(lambda p, P: rhs(p, P, geometry(p.x, p.vol, nl, sch, pb.domain), sch, pb.boundary)[2] / p.vol[:, None])
    inviscid = np.asarray(f(p, Params({**{k: P[k] for k in P}, "physics.mu": jnp.asarray(0.0)})))
    return x, np.asarray(p.kind) == int(Kind.FLUID), inviscid, np.asarray(f(p, P)), float(P["physics.mu"]), dx, delta


@pytest.mark.slow   # CI time; the cavity config's ghost_shear_dissipation = false path is held by its fingerprint
def test_mirror_walls_exert_no_inviscid_tangential_force():
    """Decision 81.  A lid layer u = exp(-s/delta) (s = 1 - y, v = 0) has the exact rate
    d(rho u)/dt = mu u'' and the lid's tangential force per unit length is the wall shear
    mu/delta.  Through the inviscid fluxes alone (mu = 0) a mirror wall must transmit no
    tangential momentum (the star region of the Riemann problem between a fluid state and its
    mirror image has zero normal velocity).  Summed over the central columns (x-independent state:
    the fluxes through the columns' sides cancel, so the sum is what the lid gives) the fluxes with
    ``scheme.ghost_shear_dissipation = false`` give < 1e-3 of the wall shear.  With the thesis'
    Rusanov dissipation on the whole jump (``true``, the default, and the only behaviour before
    decision 81) the same sum exceeds the physical wall shear (1.8 x at 50 x 50,
    docs/validation.md): the spurious wall friction that drives the Re = 1000 primary vortex too
    strong.  The viscous part, the mass and the normal-momentum rates do not depend on the option."""
    out = {}
    for flag in ("false", "true"):
        x, fluid, inv, full, mu, dx, delta = _lid_layer_rates(flag)
        col = fluid & (np.abs(x[:, 0] - 0.5) < 0.2)
        ncol = np.unique(np.round(x[col, 0], 10)).size
        per_length = dx / ncol                                  # sum of rates x dx^2 / (ncol dx)
        out[flag] = (inv[col, 1].sum() * per_length, (full - inv)[col, 1].sum() * per_length, full[col])
    shear = mu / delta
    assert abs(out["false"][0]) < 1e-3 * shear, (out["false"][0], shear)
    assert out["true"][0] > 1.0 * shear, (out["true"][0], shear)
    assert out["false"][1] == pytest.approx(out["true"][1], rel=1e-9)
    assert 0.5 * shear < out["false"][1] < 1.2 * shear, (out["false"][1], shear)
    np.testing.assert_allclose(out["false"][2][:, [0, 2]], out["true"][2][:, [0, 2]], rtol=0, atol=1e-10)


# --- boundary-integral walls (thesis eq. 4.24; docs/architecture.md decisions 54, 60, 61) ---------

BI = ("case.walls=boundary_integral", "case.n=10")


def _bi_problem(*overrides):
    return build_problem(config.load(CFG, [*QUIET, *BI, *overrides]))


@pytest.fixture(scope="module")
def bi10():
    """10 x 10 cavity with boundary-integral walls and p0 = 5 (a uniform pressure for the wall
    rows to balance), and its right-hand side ``rates(particles, params) -> (dvol, dq)``
    (compiled once; eos.gamma and the wall velocities are parameters)."""
    import jax

    from mlsph_jax import neighbors as nb
    from mlsph_jax.rhs import geometry, rhs

    pb = _bi_problem("eos.p0=5")
    p, sch = pb.particles, pb.scheme
    _, nl = nb.allocate(p.x, sch.beta * p.vol ** 0.5, pb.domain)
    f = jax.jit(lambda p, P: rhs(p, P, geometry(p.x, p.vol, nl, sch, pb.domain), sch, pb.boundary)[1:])
    return pb, lambda p, P: tuple(np.asarray(a) for a in f(p, P))


def _with_state(pb, rho, vel, params):
    """The problem's particles with the state (rho, vel) (Tait: p from rho)."""
    import jax.numpy as jnp

    from mlsph_jax.eos import get_eos, to_conservative

    U = to_conservative(jnp.asarray(rho), jnp.asarray(vel), None, get_eos(pb.scheme.eos), params)
    return pb.particles.replace(q=U * pb.particles.vol[:, None])


def test_boundary_integral_walls_span_the_cavity_corner_to_corner():
    """No ghosts; four segments of n midpoint-rule points each, lengths dx (each wall's length
    L exactly), normals out of the fluid, the lid's points moving at u_lid up to the corners (no
    vertex velocity: the quadrature never samples a corner, decision 61)."""
    pb = _bi_problem()
    assert pb.particles.n == 100 and not np.any(np.asarray(pb.particles.kind) != int(Kind.FLUID))
    bp = pb.boundary.points(pb.params)
    x, dg, nrm, vel, cid = (np.asarray(a) for a in (bp.x, bp.dgamma, bp.normal, bp.velocity, bp.curve))
    assert x.shape == (40, 2) and np.allclose(dg, 0.1, rtol=1e-14)
    for k, (axis, pos, out) in enumerate([(1, 0.0, -1), (1, 1.0, 1), (0, 0.0, -1), (0, 1.0, 1)]):
        on = cid == k
        assert on.sum() == 10 and np.all(x[on, axis] == pos)
        np.testing.assert_allclose(np.sort(x[on, 1 - axis]), (np.arange(10) + 0.5) * 0.1, atol=1e-15)
        np.testing.assert_array_equal(nrm[on], np.tile(np.eye(2)[axis] * out, (10, 1)))
        np.testing.assert_array_equal(vel[on], np.tile([1.0 if k == 1 else 0.0, 0.0], (10, 1)))
    assert pb.domain.lower == (0.0, 0.0) and pb.domain.upper == (1.0, 1.0)


def test_fluid_at_rest_in_a_closed_box_stays_at_rest(bi10):
    """Walls at rest (lid stopped) and a fluid at rest with a uniform pressure p0 = 5: every
    bracket of the boundary term vanishes on the wall's own velocity, corner rows included, and
    the rate is zero to round-off.  With the lid moving the same state is dragged along +x under
    the lid (the wall stress reaches the particles within the lid points' supports, 3 rows) and
    nowhere else."""
    pb, rates = bi10
    P = pb.params.updated({"boundary.wall_velocity": 0.0 * pb.params["boundary.wall_velocity"]})
    scale = 5.0 * 0.1                                # pressure force on one particle face
    dvol, dq = rates(pb.particles, P)
    assert np.abs(dq).max() < 1e-13 * scale and np.abs(dvol).max() == 0.0
    _, dq_lid = rates(pb.particles, pb.params)
    y = np.asarray(pb.particles.x[:, 1])
    assert np.all(dq_lid[y > 0.9, 1] > 1e-3) and np.abs(dq_lid[y < 0.6]).max() < 1e-13 * scale


def test_linear_pressure_is_exact_in_every_row_including_the_corners(bi10):
    """Linear consistency of the wall rows (decision 60) where two walls cut the support
    (decision 61): a fluid at rest with p = p0 + g . x (Tait with gamma = 1, so rho is linear too
    and every reconstruction is exact) has d(V u)/dt = -V g in every row to round-off, the
    corner particles included (measured at n = 16 without the first-moment correction: up to
    0.60 |g| V off in the corner rows, 0.41 |g| V in the straight-wall rows)."""
    from mlsph_jax.eos import tait_density

    pb, rates = bi10
    P = pb.params.updated({"boundary.wall_velocity": 0.0 * pb.params["boundary.wall_velocity"],
                           "eos.gamma": 1.0})
    x = np.asarray(pb.particles.x)
    g = np.array([0.3, -0.7])
    rho = np.asarray(tait_density(5.0 + x @ g, P))
    dvol, dq = rates(_with_state(pb, rho, np.zeros_like(x), P), P)
    V = np.asarray(pb.particles.vol)
    assert np.abs(dq[:, 0]).max() < 1e-13
    np.testing.assert_allclose(dq[:, 1:3], -V[:, None] * g, rtol=0, atol=1e-13 * 5.0 * 0.1)


def test_no_net_mass_flux_through_the_walls():
    """In the conservative form (scheme.self_flux = false) the pair terms are antisymmetric and
    the wall flux has no mass part: a run with the lid moving keeps the total mass to round-off.
    The cubic fits of the rows next to the walls fall back in degree on 12 x 12 (no ghosts complete
    their stencils; 36 % of the particles here), which the run reports as it should."""
    from mlsph_jax.errors import DegreeFallbackWarning
    from mlsph_jax.simulation import run_problem

    cfg = config.load(CFG, [*QUIET, *BI, "scheme.self_flux=false", "time.t_end=0.1", "output.snapshots=1"])
    with pytest.warns(DegreeFallbackWarning, match="degree fallback"):
        r = run_problem(build_problem(cfg), cfg, out_dir=None, quiet=True)
    assert r.summary["status"] == "ok" and r.summary["metrics"]["kinetic_energy"] > 1e-4
    assert abs(r.summary["conservation"]["mass"]) < 1e-13, r.summary["conservation"]


# --- runs --------------------------------------------------------------------------------------

#: Coarse Re = 100 run: 24 x 24 particles, CFL 0.6, outputs every second, steady_tol 2e-3 (the
#: config's), at most t = 12.
RUN24 = ["case.n=24", "time.t_end=12", "output.snapshots=12", "time.cfl=0.6", "case.steady_tol=2e-3"]
#: measured with the config's scheme (cubic reconstruction, Thornber's correction, mirror walls without the
#: inviscid wall friction, decision 87) 0.00664, 0.00639 (rms 0.00439, 0.00422); bounds + 25 %.  With the
#: ghosts' wall friction (scheme.ghost_shear_dissipation = true, the config before) 0.0115, 0.0110 (rms 0.0054,
#: 0.0056); without Thornber as well 0.0243, 0.0153 (rms 0.0125, 0.0072); quadratic 0.0702, 0.0670
U_BOUND, V_BOUND = 0.0083, 0.0080
U_RMS_BOUND, V_RMS_BOUND = 0.0055, 0.0053


@pytest.fixture(scope="module")
def run24():
    cfg = config.load(CFG, [*QUIET, *RUN24])
    pb = build_problem(cfg)
    return cfg, pb, run_problem(pb, cfg, out_dir=None, quiet=True)


@pytest.mark.slow   # 24 x 24 to t = 9: 485 s contended; the slow suite holds the 40 x 40 runs too (below)
def test_re100_centerlines_match_ghia(run24):
    """24 x 24, Re = 100 to the steady state, the config's cubic reconstruction with Thornber's
correction and mirror walls without the inviscid wall friction: max deviations from Ghia 0.0066 (u)
and 0.0064 (v), rms 0.0044 / 0.0042 (bounds: + 25 %; with the wall friction 0.0115 / 0.0110,
without Thornber as well 0.0243 / 0.0153 and with the quadratic reconstruction of the config before
issue 14 0.0702 / 0.0670, which the bounds reject);
compared with Ghia's Re = 400 / 1000 tables the same state deviates by more than the bounds."""
    cfg, pb, r = run24
    m = r.summary["metrics"]
    assert r.summary["status"] == "ok"
    assert m["ghia_u_max_abs_dev"] < U_BOUND and m["ghia_v_max_abs_dev"] < V_BOUND, m
    assert m["ghia_u_rms_dev"] < U_RMS_BOUND and m["ghia_v_rms_dev"] < V_RMS_BOUND, m
    assert -0.25 < m["u_min_centerline"] < -0.18, m     # Ghia: -0.2109
    # not vacuous: the same state misses Ghia's Re = 400 and Re = 1000 profiles by more
    for re in (400, 1000):
        other = cavity_metrics(r.particles, pb.params, pb.config, pb.scheme, re)
        assert other["ghia_u_max_abs_dev"] > U_BOUND and other["ghia_v_max_abs_dev"] > V_BOUND, other
    ts = r.summary["timeseries"]
    assert ts["ghia_u_max_abs_dev"][0] > 0.5 and ts["ghia_v_max_abs_dev"][0] > 0.2   # at rest


def test_steady_state_stop_on_a_coarse_cavity():
    """12 x 12 with case.steady_tol = 2e-2: the run stops at the first output time where the
    relative velocity change per second falls below the tolerance (t = 3.5 of t_end = 10, outputs
    every 0.5), records it, and every earlier rate after the start is at or above it."""
    cfg = config.load(CFG, [*QUIET, "case.n=12", "time.t_end=10", "output.snapshots=20", "time.cfl=0.6",
                            "case.steady_tol=2e-2"])
    r = run_problem(build_problem(cfg), cfg, out_dir=None, quiet=True)
    st = r.summary["steady_state"]
    assert st["converged"] and 2.0 <= st["t"] <= 6.0 and st["t"] == r.summary["t_final"] < 10.0, st
    assert st["residual"] < st["tolerance"] == 2e-2
    rate = r.summary["timeseries"]["velocity_change_rate"]
    assert rate[-1] == pytest.approx(st["residual"], rel=1e-9) and all(x >= 2e-2 for x in rate[1:-1])


@pytest.mark.slow   # shares the 24 x 24 run of the Ghia test
def test_steady_state_stop(run24):
    """The relative velocity change per second between outputs falls below case.steady_tol at
t = 9 (the config's scheme; with the ghosts' wall friction t = 10, cubic alone t = 9, quadratic
t = 6): the run stops before t_end = 12 and records it."""
    cfg, pb, r = run24
    st = r.summary["steady_state"]
    assert st["converged"] and 8.0 <= st["t"] <= 11.0 and st["t"] == r.summary["t_final"] < 12.0, st
    assert st["residual"] < st["tolerance"] == 2e-3
    rate = r.summary["timeseries"]["velocity_change_rate"]
    assert rate[-1] == pytest.approx(st["residual"], rel=1e-9) and all(x >= 2e-3 for x in rate[1:-1])


@pytest.mark.slow
def test_builtin_config_re100_meets_the_issue_14_target():
    """Issue 14: the shipped config (40 x 40, Re = 100, cubic reconstruction with Thornber's
    correction, mirror walls without the inviscid wall friction) within 0.01 of Ghia's centre lines;
    measured 0.0043 (u) and 0.0034 (v) (docs/validation.md, 2026-11-26, decision 87)."""
    cfg = config.load(CFG, QUIET)
    r = run_problem(build_problem(cfg), cfg, out_dir=None, quiet=True)
    m = r.summary["metrics"]
    assert r.summary["status"] == "ok" and r.summary["steady_state"]["converged"], r.summary.get("steady_state")
    assert m["ghia_u_max_abs_dev"] <= 0.01 and m["ghia_v_max_abs_dev"] <= 0.01, m


@pytest.mark.slow
def test_thesis_resolution_re100():
    """Thesis resolution (100 x 100, Re = 100; about an hour on 2 cores), the config's scheme.  The
deviations fall with refinement (with the quadratic reconstruction of the config before issue 14,
u: 0.0702, 0.0451, 0.0341 and v: 0.0670, 0.0324, 0.0190 at n = 24, 40, 50), so the 100 x 100 run
must do at least as well as issue 14's 40 x 40 target (0.01; the 40 x 40 run measured 0.0043 /
0.0034); not measured at 100 x 100 with the current scheme."""
    cfg = config.load(CFG, [*QUIET, "case.n=100"])
    r = run_problem(build_problem(cfg), cfg, out_dir=None, quiet=True)
    m = r.summary["metrics"]
    assert r.summary["status"] == "ok" and r.summary["steady_state"]["converged"], r.summary.get("steady_state")
    assert m["ghia_u_max_abs_dev"] <= 0.01 and m["ghia_v_max_abs_dev"] <= 0.01, m


@pytest.mark.slow
def test_boundary_integral_walls_re100_no_worse_than_mirror_ghosts():
    """Issue 17's target for the cavity: the built-in config (40 x 40, Re = 100, cubic) with
    boundary-integral walls deviates from Ghia no more than with mirror ghosts (measured, ghosts:
    max |u - Ghia| 0.0087, max |v - Ghia| 0.0065; boundary integral: 0.0056, 0.0040 since decision
    108, 0.0071, 0.0047 before, steady at t = 9; 4 min idle, 18-20 min on 2 contended cores).
    Both measured without Thornber's correction (the config's since 2026-11-26), so the walls are
    compared at that scheme."""
    cfg = config.load(CFG, [*QUIET, "case.walls=boundary_integral", 'scheme.low_mach_reconstruction="none"'])
    r = run_problem(build_problem(cfg), cfg, out_dir=None, quiet=True)
    m = r.summary["metrics"]
    assert r.summary["status"] == "ok" and r.summary["steady_state"]["converged"], r.summary.get("steady_state")
    assert m["ghia_u_max_abs_dev"] <= 0.0087 and m["ghia_v_max_abs_dev"] <= 0.0065, m


@pytest.mark.slow
@pytest.mark.parametrize(("re", "t_end", "steady_tol"), [(400, 40, 2e-3), (1000, 60, 5e-4)])
def test_re400_re1000_at_50x50_meet_the_issue_14_targets(re, t_end, steady_tol):
    """Issue 14: 50 x 50 particles, max |u - Ghia| <= 0.03 and max |v - Ghia| <= 0.05 along the
    centre lines, Ghia's table of the same Reynolds number.  Measured (docs/validation.md,
    2026-11-26, load 5-8): the config (Thornber's correction, no inviscid wall friction) Re = 400
    0.0155 / 0.0131 (meets, 34 min), Re = 1000 0.0305 / 0.0275 at its 2e-3 steady stop (68 min); with the
    ghosts' wall friction Re = 400 0.016 / 0.009 and Re = 1000 0.080 / 0.058; without Thornber as well
    Re = 400 0.055 / 0.025 and Re = 1000 0.159 / 0.109.  Re = 1000 is not steady at the config's
    steady_tol 2e-3 (stop at t = 33: 0.0305 / 0.0275, u still falling); with 5e-4 it runs on: 0.0293,
    0.0284, 0.0276 (u) and 0.0271, 0.0268, 0.0265 (v) at t = 34, 35, 36 (the same run's snapshots)
    and stops at t = 40 with 0.0258 / 0.0259 (36,337 steps, ~97 min at load 2-9).
    At 40 x 40 with quadratic reconstruction the deviations
    were 0.17 / 0.20 and 0.27 / 0.30."""
    cfg = config.load(CFG, [*QUIET, "case.n=50", f"case.re={re}", f"time.t_end={t_end}",
                            f"output.snapshots={t_end}", f"case.steady_tol={steady_tol}"])
    r = run_problem(build_problem(cfg), cfg, out_dir=None, quiet=True)
    m = r.summary["metrics"]
    assert r.summary["status"] == "ok", r.summary["status"]
    assert m["ghia_u_max_abs_dev"] <= 0.03 and m["ghia_v_max_abs_dev"] <= 0.05, m


@pytest.mark.slow
@pytest.mark.parametrize(("re", "t_end", "u_max", "v_max"), [(400, 40, 0.01, 0.02), (1000, 60, 0.02, 0.02)])
def test_re400_re1000_at_100x100_meet_the_issue_14_targets(re, t_end, u_max, v_max):
    """Issue 14: the thesis' 100 x 100, max |u - Ghia| <= 0.01 and max |v - Ghia| <= 0.02 at Re = 400,
    0.02 / 0.02 at Re = 1000, run to the steady stop at 5e-4.  Measured (docs/validation.md "Re = 400 at
    100 x 100" and "Re = 1000 at 100 x 100", 2026-12-05): Re = 400 at the config's 2e-3 steady stop
    (t = 22) 0.0104 / 0.0074, u still falling; at 5e-4 (t = 27, 49,476 steps) 0.0065 / 0.0039.
    Re = 1000 first within 0.02 / 0.02 at t = 26 (0.0198 / 0.0166), at the 5e-4 stop (t = 37,
    67,600 steps) 0.0070 / 0.0071.  About 1.5-2 h (Re = 400) and ~3.5 h (Re = 1000) alone on 2
    cores (1,832 steps per time unit, ~3-4 min each)."""
    cfg = config.load(CFG, [*QUIET, "case.n=100", f"case.re={re}", f"time.t_end={t_end}",
                            f"output.snapshots={t_end}", "case.steady_tol=5e-4"])
    r = run_problem(build_problem(cfg), cfg, out_dir=None, quiet=True)
    m = r.summary["metrics"]
    assert r.summary["status"] == "ok" and r.summary["steady_state"]["converged"], r.summary["status"]
    assert m["ghia_u_max_abs_dev"] <= u_max and m["ghia_v_max_abs_dev"] <= v_max, m
