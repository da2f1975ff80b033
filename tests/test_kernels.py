"""Smoothing kernels (SPEC §3.1, thesis eq. 2.30 and appendix A).

Properties checked for every registered kernel in 1D, 2D and 3D: unit integral, compact support,
analytic gradient == autodiff of the value, direction of grad W, autodiff safety at r = 0, and
the cubic-spline partial integrals of appendix A.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import quad

import mlsph_jax  # noqa: F401  (enables float64)
from mlsph_jax import InputError
from mlsph_jax.kernels import KERNELS, get_kernel

NAMES = ("cubic_spline", "wendland_c2", "quintic_spline")
DIMS = (1, 2, 3)
H = 0.7  # a non-unit smoothing length, so that the h^-d scaling is exercised


def _measure(d: int, r: float) -> float:
    """Surface measure of the sphere of radius r in d dimensions (2, 2 pi r, 4 pi r^2)."""
    return {1: 2.0, 2: 2.0 * math.pi * r, 3: 4.0 * math.pi * r * r}[d]


def _w_scalar(kern, h: float, d: int):
    """A jitted scalar r -> W(r, h) (eager dispatch per quadrature node would be slow)."""
    f = jax.jit(lambda r: kern.w(r, h, d))
    return lambda r: float(f(r))


def _knots(kern, h: float) -> list[float]:
    return [k * h for k in range(1, int(round(kern.support)))]


def test_registry_holds_the_three_kernels():
    assert set(NAMES) == set(KERNELS.names())
    assert get_kernel("cubic_spline").support == 2.0
    assert get_kernel("wendland_c2").support == 2.0
    assert get_kernel("quintic_spline").support == 3.0


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("name", NAMES)
def test_kernel_integrates_to_one(name, d):
    kern = get_kernel(name)
    w = _w_scalar(kern, H, d)
    val, err = quad(
        lambda r: w(r) * _measure(d, r),
        0.0,
        kern.support * H,
        points=_knots(kern, H),
        epsabs=1e-13,
        epsrel=1e-13,
        limit=200,
    )
    assert err < 1e-11
    assert val == pytest.approx(1.0, abs=1e-10)


def test_cubic_spline_appendix_a_partial_integrals():
    """SPEC §3.1: 1D 11h/16 + h/16; 2D annuli 11 pi h^2/20 + 3 pi h^2/20; 3D first octant
    19 pi h^3/240 + 11 pi h^3/240; times the normalisation alpha_d / h^d they sum to one."""
    kern = get_kernel("cubic_spline")
    h = H

    f = jax.jit(kern.f)

    def shape(r):  # f(r/h), the kernel without its normalisation
        return float(f(r / h))

    def integral(lo, hi, weight):
        return quad(lambda r: shape(r) * weight(r), lo, hi, epsabs=1e-14, epsrel=1e-13)[0]

    one_d = [integral(0, h, lambda r: 1.0), integral(h, 2 * h, lambda r: 1.0)]
    assert one_d == pytest.approx([11 * h / 16, h / 16], rel=1e-12)
    assert kern.norm(1) / h * 2 * sum(one_d) == pytest.approx(1.0, rel=1e-12)
    assert kern.norm(1) == pytest.approx(2.0 / 3.0, rel=1e-15)

    two_d = [
        integral(0, h, lambda r: 2 * math.pi * r),
        integral(h, 2 * h, lambda r: 2 * math.pi * r),
    ]
    assert two_d == pytest.approx([11 * math.pi * h**2 / 20, 3 * math.pi * h**2 / 20], rel=1e-12)
    assert kern.norm(2) / h**2 * sum(two_d) == pytest.approx(1.0, rel=1e-12)
    assert kern.norm(2) == pytest.approx(10.0 / (7.0 * math.pi), rel=1e-15)

    octant = [
        integral(0, h, lambda r: 0.5 * math.pi * r * r),
        integral(h, 2 * h, lambda r: 0.5 * math.pi * r * r),
    ]
    assert octant == pytest.approx(
        [19 * math.pi * h**3 / 240, 11 * math.pi * h**3 / 240], rel=1e-12
    )
    assert kern.norm(3) / h**3 * 8 * sum(octant) == pytest.approx(1.0, rel=1e-12)
    assert kern.norm(3) == pytest.approx(1.0 / math.pi, rel=1e-15)


NPTS = 256  # every batch of separations has this length, so each jitted bundle compiles once


@functools.cache
def _bundle(name: str, d: int):
    """One jitted function per (kernel, d): W, analytic grad W, autodiff grad W and dW/dr."""
    kern = get_kernel(name)

    @jax.jit
    def f(dx):
        r = jnp.sqrt(jnp.sum(dx * dx, axis=-1))
        auto = jax.vmap(jax.grad(lambda v: kern.w_vec(v, H)))(dx)
        return kern.w_vec(dx, H), kern.grad(dx, H), auto, kern.dw_dr(r, H, d), kern.w(r, H, d)

    return lambda dx: tuple(np.asarray(a) for a in f(jnp.asarray(dx, jnp.float64)))


def _random_offsets(d: int, radius: float, seed: int, lo=0.01, hi=0.999) -> np.ndarray:
    """NPTS separations with uniformly random directions and |dx| in (lo, hi) * radius."""
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((NPTS, d))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    r = radius * rng.uniform(lo, hi, NPTS)
    return u * r[:, None]


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("name", NAMES)
def test_gradient_matches_autodiff_of_value(name, d):
    kern = get_kernel(name)
    dx = _random_offsets(d, kern.support * H, seed=d)
    _, analytic, auto, dwdr, _ = _bundle(name, d)(dx)
    scale = np.abs(analytic).max()
    assert scale > 0
    np.testing.assert_allclose(analytic, auto, rtol=1e-12, atol=1e-13 * scale)
    # the vector gradient has magnitude |dW/dr| (dW/dr < 0 inside the support)
    assert np.all(dwdr < 0)
    np.testing.assert_allclose(
        np.linalg.norm(analytic, axis=1), -dwdr, rtol=1e-12, atol=1e-13 * scale
    )


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("name", NAMES)
def test_gradient_points_from_i_to_j(name, d):
    """grad_i W(x_i - x_j) = f'(q) ... (x_i - x_j)/r with f' < 0: it points from i towards j."""
    kern = get_kernel(name)
    rng = np.random.default_rng(10 + d)
    xi = rng.uniform(size=(NPTS, d))
    xj = xi + _random_offsets(d, kern.support * H, seed=20 + d)
    _, g, _, _, _ = _bundle(name, d)(xi - xj)
    e = (xj - xi) / np.linalg.norm(xj - xi, axis=1, keepdims=True)
    along = np.sum(g * e, axis=1)
    assert np.all(along > 0)
    # parallel to x_j - x_i: no transverse component
    np.testing.assert_allclose(g, along[:, None] * e, rtol=0, atol=1e-12 * along.max())


@functools.cache
def _at_origin(name: str, d: int):
    """Value, gradient, autodiff gradient, Jacobian of grad, Hessian of W at dx = 0, and the
    reverse-mode gradient of a stencil sum that contains the particle itself (one jit)."""
    kern = get_kernel(name)
    pts = jnp.asarray(np.random.default_rng(d).uniform(-0.5, 0.5, (6, d)) * H).at[0].set(0.0)

    def total(x0):
        dx = x0[None, :] - pts
        return jnp.sum(kern.w_vec(dx, H)) + jnp.sum(kern.grad(dx, H) ** 2)

    @jax.jit
    def f(z):
        return (
            kern.w_vec(z, H),
            kern.grad(z, H),
            jax.grad(lambda v: kern.w_vec(v, H))(z),
            jax.jacfwd(lambda v: kern.grad(v, H))(z),
            jax.hessian(lambda v: kern.w_vec(v, H))(z),
            jax.grad(total)(z),
        )

    return tuple(np.asarray(a) for a in f(jnp.zeros(d)))


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("name", NAMES)
def test_value_and_gradient_safe_at_origin(name, d):
    kern = get_kernel(name)
    w0, g0, auto0, jac, hess, gtotal = _at_origin(name, d)
    assert float(w0) == pytest.approx(kern.norm(d) / H**d * float(kern.f(0.0)), rel=1e-14)
    assert np.all(g0 == 0.0)
    assert np.all(auto0 == 0.0)
    # higher-order autodiff (Jacobian of grad W, Hessian of W, reverse mode through a stencil
    # sum that contains the particle itself) stays finite: no NaN from r = 0
    for a in (jac, hess, gtotal):
        assert np.all(np.isfinite(a))


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("name", NAMES)
def test_hessian_at_origin_matches_second_derivative(name, d):
    """|dx| has no derivative at 0, and autodiff through the zero-derivative safe_norm used to see
    a flat kernel there (Hessian 0); the kernel is smooth, its Hessian at the origin is
    f''(0) sigma_d / h^(d+2) I, the limit of (dW/dr) / r (from the analytic dW/dr at r = 1e-7 h)."""
    kern = get_kernel(name)
    _, _, _, jac, hess, _ = _at_origin(name, d)
    r = 1e-7 * H
    d2 = float(kern.dw_dr(jnp.asarray(r), H, d)) / r
    assert d2 < 0
    assert d2 == pytest.approx(kern.f2_0[d - 1] * kern.norm(d) / H ** (d + 2), rel=1e-6)
    np.testing.assert_allclose(hess, d2 * np.eye(d), rtol=1e-6)
    np.testing.assert_allclose(jac, d2 * np.eye(d), rtol=1e-6)


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("name", NAMES)
def test_hessian_and_h_derivative_away_from_the_origin(name, d):
    """Autodiff of w_vec (its custom JVP) against the closed form of the radial kernel,
    W'' x^ x^T + (W' / r) (I - x^ x^T), on both sides of the knots, and dW/dh against a
    central difference in h (h carries gradients: it follows the particle volumes)."""
    kern = get_kernel(name)
    rng = np.random.default_rng(7 * d)
    for q in (0.3, 0.9, 1.4, 2.2 if kern.support > 2 else 1.9):
        e = rng.normal(size=d)
        e /= np.linalg.norm(e)
        x = jnp.asarray(q * H * e)
        hess = np.asarray(jax.hessian(lambda v: kern.w_vec(v, H))(x))
        rr = q * H
        w1 = float(kern.dw_dr(jnp.asarray(rr), H, d))
        w2 = float(jax.grad(lambda s: kern.dw_dr(s, H, d))(jnp.asarray(rr)))
        exact = w2 * np.outer(e, e) + w1 / rr * (np.eye(d) - np.outer(e, e))
        np.testing.assert_allclose(hess, exact, rtol=1e-12, atol=1e-12 * np.abs(exact).max())
        np.testing.assert_allclose(np.asarray(jax.jacfwd(lambda v: kern.grad(v, H))(x)), exact, rtol=1e-12,
                                   atol=1e-12 * np.abs(exact).max())
        dwdh = float(jax.grad(lambda hh, x=x: kern.w_vec(x, hh))(H))
        eps = 1e-6 * H
        fd = (float(kern.w_vec(x, H + eps)) - float(kern.w_vec(x, H - eps))) / (2 * eps)
        assert dwdh == pytest.approx(fd, rel=1e-7)


@pytest.mark.parametrize("name", NAMES)
def test_mixed_derivatives_in_h_and_x_commute_at_the_origin(name):
    """d/dh of the Hessian at dx = 0 and the Hessian of dW/dh are both
    -(d + 2) f''(0) sigma_d / h^(d+3) I (d = 2); an integer h (no tangent of its own) differentiates
    as the float."""
    kern = get_kernel(name)
    d = 2
    z = jnp.zeros(d)
    exact = -(d + 2) * kern.f2_0[d - 1] * kern.norm(d) / H ** (d + 3) * np.eye(d)
    h_of_hess = jax.jacfwd(lambda hh: jax.hessian(lambda v: kern.w_vec(v, hh))(z))(H)
    hess_of_h = jax.hessian(lambda v: jax.grad(lambda hh: kern.w_vec(v, hh))(H))(z)
    np.testing.assert_allclose(np.asarray(h_of_hess), exact, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(hess_of_h), exact, rtol=1e-12)
    x = jnp.asarray([0.3, -0.2])
    np.testing.assert_array_equal(np.asarray(jax.grad(lambda v: kern.w_vec(v, 1))(x)),
                                  np.asarray(jax.grad(lambda v: kern.w_vec(v, 1.0))(x)))


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("name", NAMES)
def test_compact_support(name, d):
    kern = get_kernel(name)
    R = kern.support * H
    scale = kern.norm(d) / H**d
    bundle = _bundle(name, d)
    rng = np.random.default_rng(30 + d)
    u = rng.standard_normal((NPTS, d))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    # r = support * h exactly, just outside and far outside
    r_out = np.concatenate([[R, R], [R * (1 + 1e-12)], R * rng.uniform(1.0, 3.0, NPTS - 3)])
    w, g, _, _, _ = bundle(u * r_out[:, None])
    # at r = support * h itself q = r / h may round to just below the support: W is then a
    # round-off residue (~(1e-16)^3..5), not an exact zero
    assert np.all(np.abs(w[:2]) < 1e-40 * scale)
    assert np.all(np.abs(g[:2]) < 1e-25 * scale / H)
    assert np.all(w[2:] == 0.0)
    assert np.all(g[2:] == 0.0)
    # strictly positive and non-increasing inside the support (along one direction)
    r_in = np.sort(R * rng.uniform(0.0, 1.0 - 1e-6, NPTS))
    w_in, _, _, _, w_radial = bundle(u[:1] * r_in[:, None])
    assert np.all(w_in > 0)
    assert np.all(np.diff(w_in) <= 0)
    np.testing.assert_allclose(w_in, w_radial, rtol=1e-14)


@pytest.mark.parametrize("d", DIMS)
@pytest.mark.parametrize("name", NAMES)
def test_piecewise_definition_is_c1_at_the_knots(name, d):
    """Values and radial derivatives agree on both sides of the knots q = 1, 2 (, 3)."""
    kern = get_kernel(name)
    knots = np.arange(1, int(round(kern.support)) + 1) * H
    r = np.zeros(NPTS)
    r[: 2 * knots.size] = np.stack(
        [np.nextafter(knots, 0.0), np.nextafter(knots, np.inf)], 1
    ).ravel()
    dx = np.zeros((NPTS, d))
    dx[:, 0] = r
    w, _, _, dw, _ = _bundle(name, d)(dx)
    scale = kern.norm(d) / H**d
    w, dw = w[: 2 * knots.size].reshape(-1, 2), dw[: 2 * knots.size].reshape(-1, 2)
    assert np.all(np.abs(w[:, 1] - w[:, 0]) < 1e-12 * scale)
    assert np.all(np.abs(dw[:, 1] - dw[:, 0]) < 1e-10 * scale / H)


@pytest.mark.parametrize("bad", ["gaussian", "Cubic_Spline", "", None, 3])
def test_unknown_kernel_name_lists_allowed(bad):
    with pytest.raises(InputError) as exc:
        get_kernel(bad)
    msg = str(exc.value)
    assert "kernel" in msg
    for name in NAMES:
        assert name in msg
