"""Far-field treatments of the frozen outer particles (issue 17 item 3; mlsph_jax/far_field.py):
the Riemann-invariant (characteristic) state against its definition, the free stream kept
exactly, the run of the cylinder with it, gradients and bad input."""

import dataclasses

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from mlsph_jax import config as config_mod  # noqa: E402
from mlsph_jax.cases import build_problem  # noqa: E402
from mlsph_jax.eos import get_eos  # noqa: E402
from mlsph_jax.errors import ConfigError, InputError  # noqa: E402
from mlsph_jax.far_field import FAR_FIELDS, characteristic_state  # noqa: E402
from mlsph_jax.state import Kind, Params  # noqa: E402
from mlsph_jax.testing import CONFIG_DIR  # noqa: E402

GAMMA = 1.4
EOS_PARAMS = {
    "ideal_gas": Params({"eos.gamma": GAMMA}),
    "stiffened_gas": Params({"eos.gamma": 4.4, "eos.pc": 6.0}),
    "tait": Params({"eos.gamma": 7.0, "eos.rho0": 1.0, "eos.c0": 10.0, "eos.p0": 0.0}),
}


def _states(eos: str, n: int, seed: int, mach: float):
    """``(rho, vel[n, 2], p, c)`` of random states with |u| / c up to ``mach``."""
    rng = np.random.default_rng(seed)
    P, E = EOS_PARAMS[eos], get_eos(eos)
    rho = rng.uniform(0.8, 1.2, n) if eos != "tait" else rng.uniform(0.99, 1.01, n)
    pres = rng.uniform(0.6, 1.0, n) if eos != "tait" else E.pressure(jnp.asarray(rho), 0.0, P)
    c = E.sound_speed(jnp.asarray(rho), jnp.asarray(pres), P)
    ang = rng.uniform(0, 2 * np.pi, n)
    speed = mach * rng.uniform(0.0, 1.0, n) * np.asarray(c)
    vel = np.stack([speed * np.cos(ang), speed * np.sin(ang)], axis=1)
    return jnp.asarray(rho), jnp.asarray(vel), jnp.asarray(pres), c


def _normals(n: int, seed: int):
    a = np.random.default_rng(seed).uniform(0, 2 * np.pi, n)
    return jnp.asarray(np.stack([np.cos(a), np.sin(a)], axis=1))


def _invariants(state, normal, eos):
    rho, vel, pres, c = state
    g = EOS_PARAMS[eos]["eos.gamma"]
    un = jnp.sum(vel * normal, axis=-1)
    ut = vel - un[:, None] * normal
    pc = EOS_PARAMS[eos]["eos.pc"] if eos == "stiffened_gas" else 0.0
    s = (pres + pc) / rho ** g
    return un + 2 * c / (g - 1), un - 2 * c / (g - 1), un, ut, s


@pytest.mark.parametrize("eos", sorted(EOS_PARAMS))
def test_characteristic_state_of_the_free_stream_is_the_free_stream(eos):
    """Interior = free stream: the characteristic state is that state to round-off (a uniform
    stream stays uniform), for every EOS and any normal."""
    st = _states(eos, 64, 1, 0.8)
    n = _normals(64, 2)
    rho, vel, pres = characteristic_state(st, st, n, eos, EOS_PARAMS[eos])
    assert float(jnp.max(jnp.abs(rho - st[0]))) <= 1e-13
    assert float(jnp.max(jnp.abs(vel - st[1]))) <= 1e-12 * float(jnp.max(st[3]))
    if eos != "tait":
        assert float(jnp.max(jnp.abs(pres - st[2]))) <= 1e-13 * float(jnp.max(st[2]) + 6.0)


@pytest.mark.parametrize("eos", sorted(EOS_PARAMS))
def test_invariants_come_from_where_they_start(eos):
    """Subsonic normal speeds: the result carries the interior's outgoing invariant R+ and the
    free stream's incoming R-; where it flows out (u_n >= 0) the interior's tangential velocity
    and entropy, where it flows in the free stream's.  An outgoing simple wave (interior with the
    free stream's R-, entropy and tangential velocity) passes unchanged: nothing is reflected."""
    P, E = EOS_PARAMS[eos], get_eos(eos)
    inner, outer = _states(eos, 200, 3, 0.5), _states(eos, 200, 4, 0.5)
    n = _normals(200, 5)
    rho, vel, pres = characteristic_state(inner, outer, n, eos, P)
    pres = E.pressure(rho, 0.0, P) if eos == "tait" else pres
    res = (rho, vel, pres, E.sound_speed(rho, pres, P))
    rp, rm, un, ut, s = _invariants(res, n, eos)
    rp_i, _, _, ut_i, s_i = _invariants(inner, n, eos)
    _, rm_o, _, ut_o, s_o = _invariants(outer, n, eos)
    scale = float(jnp.max(jnp.abs(rp_i)))
    assert float(jnp.max(jnp.abs(rp - rp_i))) <= 1e-12 * scale
    assert float(jnp.max(jnp.abs(rm - rm_o))) <= 1e-12 * scale
    out = np.asarray(un >= 0)
    assert 0 < out.sum() < out.size       # both branches are exercised
    assert np.allclose(np.asarray(ut)[out], np.asarray(ut_i)[out], rtol=0, atol=1e-12 * scale)
    assert np.allclose(np.asarray(ut)[~out], np.asarray(ut_o)[~out], rtol=0, atol=1e-12 * scale)
    if eos != "tait":
        assert np.allclose(np.asarray(s)[out], np.asarray(s_i)[out], rtol=1e-12)
        assert np.allclose(np.asarray(s)[~out], np.asarray(s_o)[~out], rtol=1e-12)
    # an outgoing simple wave into a stream that leaves the domain (normal component of the
    # free stream made >= 0): the interior rebuilt with the free stream's R-, s and u_t
    g = P["eos.gamma"]
    k = 2.0 / (g - 1.0)
    un_o = jnp.sum(outer[1] * n, axis=-1)
    outer = (outer[0], outer[1] - 2.0 * jnp.minimum(un_o, 0.0)[:, None] * n, outer[2], outer[3])
    _, rm_o, un_o, ut_o, s_o = _invariants(outer, n, eos)
    c_w = outer[3] * 1.05                                    # a compression leaving the domain
    un_w = rm_o + k * c_w
    assert bool(jnp.all((un_w > 0) & (un_w < c_w)))
    vel_w = ut_o + un_w[:, None] * n
    if eos == "tait":
        rho_w, p_w = P["eos.rho0"] * (c_w / P["eos.c0"]) ** k, None
    else:
        pc = P["eos.pc"] if eos == "stiffened_gas" else 0.0
        rho_w = (c_w ** 2 / (g * s_o)) ** (1 / (g - 1))
        p_w = rho_w * c_w ** 2 / g - pc
    wave = (rho_w, vel_w, E.pressure(rho_w, 0.0, P) if eos == "tait" else p_w, c_w)
    rho2, vel2, _ = characteristic_state(wave, outer, n, eos, P)
    assert float(jnp.max(jnp.abs(rho2 / rho_w - 1))) <= 1e-12
    assert float(jnp.max(jnp.abs(vel2 - vel_w))) <= 1e-12 * float(jnp.max(c_w))


def test_supersonic_normal_speeds_take_one_side():
    """|u_n| >= c: supersonic outflow keeps the interior state, supersonic inflow the free stream."""
    eos, P = "ideal_gas", EOS_PARAMS["ideal_gas"]
    n = jnp.asarray([[1.0, 0.0], [1.0, 0.0]])
    inner = (jnp.asarray([1.0, 1.1]), jnp.asarray([[1.5, 0.2], [0.3, 0.1]]), jnp.asarray([0.7, 0.8]), None)
    outer = (jnp.asarray([0.9, 1.0]), jnp.asarray([[0.2, 0.0], [-1.6, 0.3]]), jnp.asarray([0.75, 0.7]), None)
    E = get_eos(eos)
    inner = (*inner[:3], E.sound_speed(inner[0], inner[2], P))
    outer = (*outer[:3], E.sound_speed(outer[0], outer[2], P))
    assert float(inner[1][0, 0]) > float(inner[3][0]) and -float(outer[1][1, 0]) > float(outer[3][1])
    rho, vel, pres = characteristic_state(inner, outer, n, eos, P)
    np.testing.assert_allclose([rho[0], *vel[0], pres[0]], [inner[0][0], *inner[1][0], inner[2][0]], rtol=1e-13)
    np.testing.assert_allclose([rho[1], *vel[1], pres[1]], [outer[0][1], *outer[1][1], outer[2][1]], rtol=1e-13)


def test_characteristic_state_gradient_matches_finite_differences():
    """d(state)/d(interior, free stream) by forward-mode autodiff against central differences."""
    eos, P = "ideal_gas", EOS_PARAMS["ideal_gas"]
    inner, outer = _states(eos, 6, 7, 0.5), _states(eos, 6, 8, 0.5)
    n = _normals(6, 9)
    E = get_eos(eos)

    def f(z):
        ri, ui, pi, ro, uo, po = z[0:6], z[6:18].reshape(6, 2), z[18:24], z[24:30], z[30:42].reshape(6, 2), z[42:48]
        st = characteristic_state((ri, ui, pi, E.sound_speed(ri, pi, P)), (ro, uo, po, E.sound_speed(ro, po, P)),
                                  n, eos, P)
        return jnp.concatenate([st[0], st[1].ravel(), st[2]])

    z = jnp.concatenate([inner[0], inner[1].ravel(), inner[2], outer[0], outer[1].ravel(), outer[2]])
    J = jax.jacfwd(f)(z)
    v = jnp.asarray(np.random.default_rng(10).normal(size=z.shape))
    eps = 1e-6
    fd = (f(z + eps * v) - f(z - eps * v)) / (2 * eps)
    np.testing.assert_allclose(np.asarray(J @ v), np.asarray(fd), rtol=1e-7, atol=1e-9)


def _cylinder(*overrides):
    cfg = config_mod.load(CONFIG_DIR / "cylinder.toml", ["case.n_theta=32", "case.r_far=3.0", "output.plots=false",
                                                         "output.progress=false", "case.far_field=characteristic",
                                                         *overrides])
    return cfg, build_problem(cfg)


@pytest.mark.parametrize("force", [None, "physics.body_force=[0.0, -1.0]"])
def test_cylinder_far_field_keeps_the_free_stream(force):
    """The cylinder's characteristic far field pairs each frozen particle with the fluid particle
    inward on its ray (radial normal) and leaves the set-up free stream unchanged: the uniform
    stream, and the stream through the hydrostatic atmosphere of a body force (whose pressure
    varies along the normal; the invariants compare the interior with the free stream at the
    interior particle)."""
    _, pb = _cylinder(*([force, "case.mach=0.1"] if force else []))
    far = pb.boundary.far
    p = pb.particles
    x = np.asarray(p.x)
    assert np.all(np.asarray(p.kind)[np.asarray(far.frozen)] == int(Kind.FROZEN))
    assert np.all(np.asarray(p.kind)[np.asarray(far.source)] == int(Kind.FLUID))
    radial = x[np.asarray(far.frozen)] / np.linalg.norm(x[np.asarray(far.frozen)], axis=1)[:, None]
    np.testing.assert_allclose(np.asarray(far.normal), radial, atol=1e-12)
    q = pb.boundary.apply(p, pb.params).q
    assert float(jnp.max(jnp.abs(q - p.q))) <= 1e-14 * float(jnp.max(jnp.abs(p.q)))


def _pulse_reflection(far_field: str, n: int = 100) -> float:
    """An acoustic pulse (simple wave, amplitude 1e-3 p0) carried out of a 1D tube at u0 = 0.5 c
    (ideal gas, c = 1): the largest pressure disturbance left in the fluid at t = 0.6, when the
    pulse has left through the right end (speed 1.5), over the pulse's amplitude."""
    from mlsph_jax.eos import to_conservative, to_primitive
    from mlsph_jax.simulation import Simulation

    cfg = config_mod.load(CONFIG_DIR / "sod_ideal_gas.toml", [f"case.n={n}", "scheme.frame=eulerian",
                                                              "scheme.limiter=none", "time.t_end=0.6"])
    pb = build_problem(cfg)
    eos, p0, u0, eps = get_eos("ideal_gas"), 1.0 / GAMMA, 0.5, 1e-3
    x = np.asarray(pb.particles.x[:, 0])
    fluid = np.asarray(pb.particles.kind) == int(Kind.FLUID)
    dp = jnp.asarray(eps * p0 * np.exp(-((x - 0.5) / 0.05) ** 2) * fluid)
    U = to_conservative(1.0 + dp, (u0 + dp)[:, None], p0 + dp, eos, pb.params)    # rho c = 1: u' = p', rho' = p'
    p = pb.particles.replace(q=pb.particles.vol[:, None] * U)

    def stream(xf, P):
        return jnp.ones(len(xf)), jnp.full((len(xf), 1), u0), jnp.full(len(xf), p0)

    far = FAR_FIELDS.get(far_field).setup(p, "ideal_gas", stream)
    pb = dataclasses.replace(pb, particles=p, boundary=far, metrics=lambda *a: {}, plot=lambda *a: None)
    out = Simulation(pb, cfl=0.3).run(None, snapshots=1, progress=False, plots=False).particles
    if far is not None:   # applied after the last step: the frozen ends hold the state of the final interior
        again = np.asarray(far.apply(out, pb.params).q)
        assert np.max(np.abs(again - np.asarray(out.q))) <= 1e-14 * np.max(np.abs(np.asarray(out.q)))
    pres = np.asarray(to_primitive(out.q / out.vol[:, None], eos, pb.params).p)
    return float(np.max(np.abs(pres[fluid] - p0)) / (eps * p0))


def test_acoustic_pulse_leaves_through_the_characteristic_far_field():
    """Non-reflection (issue 17 item 3): a pulse leaving through the characteristic (or the
    frozen) far field leaves < 1e-3 of itself behind (measured 1.5e-4 for both: with a Riemann
    flux the frozen state is itself an upwind, non-reflecting boundary for acoustic waves); the
    pressure outlet of ``inflow_outflow`` reflects it (measured 42 %: p' = 0 at the outlet),
    which shows the measurement can fail."""
    assert _pulse_reflection("characteristic") < 1e-3
    assert _pulse_reflection("frozen") < 1e-3
    assert _pulse_reflection("inflow_outflow") > 0.2


@pytest.mark.slow
def test_cylinder_run_through_the_far_field():
    """A short coarse cylinder run with the characteristic far field: finite, the far-field rings
    follow the interior (their state leaves the free stream), the walls' fixed searches and the
    far field compose (``WithFarField.fix``)."""
    from mlsph_jax.simulation import Simulation

    _, pb = _cylinder("case.mach=0.2", "time.t_end=0.1")
    out = Simulation(pb, cfl=0.6).run(None, snapshots=1, progress=False, plots=False)
    frozen = np.asarray(pb.particles.kind) == int(Kind.FROZEN)
    q_end, q0 = np.asarray(out.particles.q), np.asarray(pb.particles.q)
    assert np.all(np.isfinite(q_end)) and out.summary["metrics"]["cd"] > 0
    assert np.max(np.abs(q_end[frozen] - q0[frozen])) > 1e-6 * np.max(np.abs(q0))
    # applied after the step: the far-field rings hold the characteristic state of the final interior
    again = np.asarray(pb.boundary.apply(out.particles, pb.params).q)
    assert np.max(np.abs(again - q_end)) <= 1e-13 * np.max(np.abs(q0))


def test_float32_states_through_the_far_field():
    """``run.precision = "float32"``: the far field writes float32 states into float32 particles
    (no float64 scatter, which JAX warns about and will refuse)."""
    import warnings

    from mlsph_jax.state import with_precision  # the run's own cast (Simulation)

    _, pb = _cylinder("case.mach=0.2")
    p32, P32 = with_precision(pb.particles, "float32"), with_precision(pb.params, "float32")
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message=".*scatter inputs have incompatible types.*")
        q = pb.boundary.apply(p32, P32).q
    assert q.dtype == jnp.float32 and np.all(np.isfinite(np.asarray(q)))


@pytest.mark.slow
def test_drag_gradient_through_the_characteristic_far_field():
    """d C_D / d (mu, gamma) through a short run with the characteristic far field against
    central differences (measured 3.8e-11 and 1.7e-8 relative, 92 s)."""
    from mlsph_jax.sensitivity import sensitivity

    _, pb = _cylinder("case.mach=0.2")
    res = sensitivity(pb, ["physics.mu", "eos.gamma"], "cd", check_fd=True, n_steps=25, t_end=0.1)
    for k in ("physics.mu", "eos.gamma"):
        g = res["gradients"][k]
        assert g["gradient"] != 0.0 and max(np.ravel(g["rel_disagreement"])) < 1e-6, (k, g)


def test_bad_input_names_the_key():
    with pytest.raises(ConfigError, match=r"case\.far_field.*characteristic"):
        config_mod.load(CONFIG_DIR / "cylinder.toml", ["case.far_field=riemann"])
    _, pb = _cylinder()
    with pytest.raises(InputError, match=r"eos\.kind='my_gas'.*case\.far_field=\"characteristic\""):
        FAR_FIELDS.get("characteristic").setup(pb.particles, "my_gas", None)
    fluid_only = pb.particles.replace(kind=jnp.zeros_like(pb.particles.kind))
    with pytest.raises(InputError, match="0 frozen"):
        FAR_FIELDS.get("characteristic").setup(fluid_only, "ideal_gas", None)


def test_inflow_outflow_takes_velocity_in_and_pressure_out():
    """``inflow_outflow``: where the free stream enters (u_inf . n < 0) the free stream's velocity
    and density with the interior's pressure; where it leaves the interior's velocity and density
    with the free stream's pressure."""
    from mlsph_jax.far_field import inflow_outflow_state

    eos, P = "ideal_gas", EOS_PARAMS["ideal_gas"]
    inner, outer = _states(eos, 100, 11, 0.5), _states(eos, 100, 12, 0.5)
    n = _normals(100, 13)
    rho, vel, pres = inflow_outflow_state(inner, outer, n, eos, P)
    inflow = np.asarray(jnp.sum(outer[1] * n, axis=-1) < 0)
    assert 0 < inflow.sum() < inflow.size
    for got, fin, fout in ((rho, inner[0], outer[0]), (vel, inner[1], outer[1]), (pres, inner[2], outer[2])):
        want_in = fout if got is not pres else fin
        want_out = fin if got is not pres else fout
        assert np.array_equal(np.asarray(got)[inflow], np.asarray(want_in)[inflow])
        assert np.array_equal(np.asarray(got)[~inflow], np.asarray(want_out)[~inflow])
