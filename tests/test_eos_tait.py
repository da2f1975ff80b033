"""The Tait law (SPEC §2.1): p = rho0 c0^2 / gamma [(rho/rho0)^gamma - 1] + p0 and
c = c0 (rho/rho0)^((gamma - 1)/2), evaluated as exp(a log r) (``eos._power``, docs/performance.md
"The Tait power").  Checked against the closed form in numpy, the thermodynamic identity
c^2 = dp/drho of a barotropic fluid, the parameter derivative against central differences, the
inverse law, and NaN (not a clamp) for a non-positive density."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mlsph_jax.eos import get_eos, tait_density

TAIT = get_eos("tait")


def _params(gamma=7.0, c0=10.0, rho0=1000.0, p0=1.0e3):
    return {"eos.gamma": jnp.asarray(gamma), "eos.c0": jnp.asarray(c0), "eos.rho0": jnp.asarray(rho0),
            "eos.p0": jnp.asarray(p0)}


@pytest.mark.parametrize("gamma", [7.0, 1.4, 7.15])
def test_tait_pressure_and_sound_speed_equal_the_closed_form(gamma):
    """From 1e-3 to 1e3 rho0 and near rho0 (Mach 0.1 density changes of 1e-4 and below, where
    p - p0 is a small difference): p and c equal numpy's float64 power to 1.6e-13 of their scale
    (measured 5.5e-15; a 1e-12 change of an exponent moves p by 1e-11 of it)."""
    P = _params(gamma)
    r = np.concatenate([np.geomspace(1e-3, 1e3, 61), 1.0 + np.linspace(-1e-4, 1e-4, 41)])
    rho = r * 1000.0
    p = np.asarray(TAIT.pressure(jnp.asarray(rho), None, P))
    c = np.asarray(TAIT.sound_speed(jnp.asarray(rho), jnp.asarray(p), P))
    scale = 1000.0 * 100.0 / gamma
    p_exact = scale * (np.power(r, gamma) - 1.0) + 1.0e3
    c_exact = 10.0 * np.power(r, 0.5 * (gamma - 1.0))
    # relative to the pressure's own size where it is large, to the scale rho0 c0^2 / gamma near rho0
    assert np.all(np.abs(p - p_exact) <= 1e-14 * np.maximum(np.abs(p_exact - 1.0e3), scale) * 16)
    assert np.all(np.abs(c - c_exact) <= 1e-14 * c_exact * 16)


def test_tait_sound_speed_is_the_derivative_of_the_pressure():
    """A barotropic fluid's sound speed is c^2 = dp/drho (thermodynamic consistency)."""
    P = _params()
    rho = jnp.linspace(900.0, 1100.0, 21)
    dpdrho = jax.vmap(jax.grad(lambda x: TAIT.pressure(x, None, P)))(rho)
    c = TAIT.sound_speed(rho, TAIT.pressure(rho, None, P), P)
    np.testing.assert_allclose(np.asarray(dpdrho), np.asarray(c) ** 2, rtol=1e-13)


def test_tait_derivatives_in_gamma_match_central_differences():
    """d p / d gamma and d c / d gamma (what a calibration of the EOS differentiates) against the
    fourth-order central difference of step 1e-3: relative 1e-8 where the derivative is of the size of
    the values; next to rho0 (r = 1.0005, dp/dgamma = 1.25e-6 in the test's units) the difference's
    own round-off, ~1e-13 x 10 / 1e-3, is what atol 1e-11 admits."""
    rho = jnp.asarray([950.0, 1000.5, 1080.0])

    def pc(g):
        P = _params(g)
        p = TAIT.pressure(rho, None, P)
        return jnp.concatenate([p / 1e4, TAIT.sound_speed(rho, p, P)])

    g0, eps = 7.0, 1e-3
    ad = np.asarray(jax.jacfwd(pc)(g0))
    rev = np.asarray(jax.jacrev(pc)(g0))
    f = lambda k: np.asarray(pc(g0 + k * eps))  # noqa: E731
    fd = (8.0 * (f(1) - f(-1)) - (f(2) - f(-2))) / (12.0 * eps)
    np.testing.assert_allclose(ad, fd, rtol=1e-8, atol=1e-11)
    np.testing.assert_allclose(rev, ad, rtol=1e-12)


def test_tait_density_inverts_the_pressure():
    P = _params(7.15)
    rho = jnp.linspace(500.0, 2000.0, 31)
    back = tait_density(TAIT.pressure(rho, None, P), P)
    np.testing.assert_allclose(np.asarray(back), np.asarray(rho), rtol=1e-12)


def test_nonpositive_density_gives_nan_not_a_clamped_value():
    P = _params()
    rho = jnp.asarray([0.0, -1.0, 1000.0])
    p = TAIT.pressure(rho, None, P)
    c = TAIT.sound_speed(rho, p, P)
    assert np.isnan(np.asarray(p[:2])).all() and np.isnan(np.asarray(c[:2])).all()
    assert np.isfinite(np.asarray(p[2])) and np.isfinite(np.asarray(c[2]))
