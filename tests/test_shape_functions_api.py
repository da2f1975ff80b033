"""The one-call entry point ``mlsph_jax.shape_functions`` (point_cloud.py).

Shapes and padding of the result, polynomial reproduction through ``.interpolate`` /
``.gradient``, periodic and partially periodic boxes, and input validation (every bad input
raises :class:`mlsph_jax.InputError` naming the argument).  Results of the successful calls are
cached so that each point cloud is compiled and built once.
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np
import pytest

import mlsph_jax
from mlsph_jax import InputError, ShapeFunctions
from mlsph_jax import neighbors as nb
from mlsph_jax.approximation import basis
from mlsph_jax.state import Domain


def jittered(m: int, d: int, seed: int = 0, jitter: float = 0.3) -> np.ndarray:
    rng = np.random.default_rng(seed + 10 * d)
    dx = 1.0 / m
    axes = [(np.arange(m) + 0.5) * dx] * d
    x = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, d)
    return x + rng.uniform(-jitter, jitter, x.shape) * dx


RNG_POINTS = np.random.default_rng(42).uniform(0.0, 1.0, (300, 2))


@functools.cache
def default_2d() -> ShapeFunctions:
    return mlsph_jax.shape_functions(RNG_POINTS)


@functools.cache
def periodic_2d(shift: tuple[float, float] = (0.0, 0.0)) -> tuple[np.ndarray, ShapeFunctions]:
    x = np.mod(jittered(16, 2) + np.asarray(shift), 1.0)
    return x, mlsph_jax.shape_functions(x, box=(1.0, 1.0), periodic=True)


def quadratic(x: np.ndarray, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A random complete quadratic and its gradient at points x[N, d]."""
    d = x.shape[1]
    ex = basis.exponents(2, d)
    c = np.random.default_rng(seed).uniform(-1, 1, len(ex))
    f = sum(ci * np.prod(x**a, axis=1) for ci, a in zip(c, ex, strict=True))
    g = np.zeros_like(x)
    for ci, a in zip(c, ex, strict=True):
        for b in range(d):
            if a[b]:
                lo = a.copy()
                lo[b] -= 1
                g[:, b] += ci * a[b] * np.prod(x**lo, axis=1)
    return f, g


def check_layout(sf: ShapeFunctions, n: int, d: int, m: int) -> None:
    """Documented shapes and padding of a ShapeFunctions result."""
    idx, mask = np.asarray(sf.neighbors), np.asarray(sf.mask)
    K = idx.shape[1]
    assert idx.shape == mask.shape == (n, K) and np.issubdtype(idx.dtype, np.integer)
    assert np.asarray(sf.values).shape == (n, K)
    assert np.asarray(sf.gradients).shape == (n, K, d)
    assert np.asarray(sf.h).shape == (n,) and np.asarray(sf.degree).shape == (n,)
    np.testing.assert_array_equal(mask, idx < n)
    assert np.all(idx[~mask] == n)  # padding value N
    assert np.all(idx[mask] >= 0)
    assert np.all(np.asarray(sf.values)[~mask] == 0.0)
    assert np.all(np.asarray(sf.gradients)[~mask] == 0.0)
    # rows ascending, valid entries first, every particle its own neighbour
    assert np.all(np.diff(idx, axis=1) >= 0)
    assert np.all(mask[:, :-1] | ~mask[:, 1:])
    assert np.all((idx == np.arange(n)[:, None]).sum(axis=1) == 1)
    safe = np.asarray(sf.safe_neighbors)
    np.testing.assert_array_equal(safe, np.where(mask, idx, np.arange(n)[:, None]))
    coeffs = sf.operators.coeffs
    assert coeffs is not None and np.asarray(coeffs).shape == (n, m, K)
    assert np.all(np.isfinite(np.asarray(sf.values))) and np.all(
        np.isfinite(np.asarray(sf.gradients))
    )


def test_default_call_shapes_padding_and_neighbours():
    sf = default_2d()
    n = len(RNG_POINTS)
    check_layout(sf, n, 2, 6)
    assert (
        sf.spec.approximation == "mls" and sf.spec.degree == 2 and sf.spec.kernel == "cubic_spline"
    )
    assert sf.spec.derivative == "full"
    assert not any(sf.domain.periodic)
    # default volumes: (bounding-box volume) / N, h = 1.5 V^(1/2)
    vol = np.prod(sf.domain.length) / n
    np.testing.assert_allclose(np.asarray(sf.h), 1.5 * np.sqrt(vol), rtol=1e-12)
    assert np.all(np.asarray(RNG_POINTS) >= np.asarray(sf.domain.lower))
    assert np.all(np.asarray(RNG_POINTS) <= np.asarray(sf.domain.upper))
    # the stencils are exactly the neighbour sets of the library's reference search
    ref = nb.brute_force(RNG_POINTS, np.asarray(sf.h), sf.domain, support=2.0)
    idx, mask = np.asarray(sf.neighbors), np.asarray(sf.mask)
    for i in range(n):
        np.testing.assert_array_equal(idx[i][mask[i]], ref[i])
    deg = np.asarray(sf.degree)
    assert np.all((deg >= 0) & (deg <= 2)) and np.mean(deg == 2) >= 0.9


def test_quadratic_reproduction_via_interpolate_and_gradient():
    sf = default_2d()
    x = RNG_POINTS
    f, g = quadratic(x)
    full = np.asarray(sf.degree) == 2
    v = np.asarray(sf.interpolate(f))
    gr = np.asarray(sf.gradient(f))
    assert v.shape == (len(x),) and gr.shape == (len(x), 2)
    fmax = np.abs(f).max()
    h = np.asarray(sf.h)
    assert np.abs(v - f)[full].max() < 1e-10 * fmax
    assert (np.abs(gr - g).max(axis=1) * h)[full].max() < 1e-10 * fmax
    # partition of unity / nullity on every particle
    assert np.abs(np.asarray(sf.values).sum(axis=1) - 1).max() < 1e-12
    assert (np.abs(np.asarray(sf.gradients).sum(axis=1)).max(axis=1) * h).max() < 1e-12
    # vector-valued fields keep their trailing axes: [N, 3] -> [N, 3] and [N, d, 3]
    F = np.stack([f, 2 * f, np.ones_like(f)], axis=1)
    V = np.asarray(sf.interpolate(F))
    G = np.asarray(sf.gradient(F))
    assert V.shape == (len(x), 3) and G.shape == (len(x), 2, 3)
    np.testing.assert_allclose(V[:, 1], 2 * v, rtol=1e-14, atol=1e-14 * fmax)
    np.testing.assert_allclose(G[:, :, 0], gr, rtol=1e-14, atol=1e-14 * fmax / h.min())
    assert np.abs(V[:, 2] - 1).max() < 1e-12


def test_one_dimensional_input_and_three_dimensional_linear_basis():
    """A 1D array is read as d = 1; in 3D a linear basis reproduces linear fields."""
    x1 = np.sort(np.random.default_rng(1).uniform(0.0, 2.0, 80))
    sf1 = mlsph_jax.shape_functions(x1, degree=2)
    check_layout(sf1, 80, 1, 3)
    f = 0.5 - x1 + 3.0 * x1**2
    full = np.asarray(sf1.degree) == 2
    assert full.mean() >= 0.9
    np.testing.assert_allclose(
        np.asarray(sf1.interpolate(f))[full], f[full], rtol=0, atol=1e-10 * 13
    )
    np.testing.assert_allclose(
        np.asarray(sf1.gradient(f))[full, 0],
        (-1 + 6 * x1)[full],
        rtol=0,
        atol=1e-10 * 13 / np.asarray(sf1.h).min(),
    )

    x3 = jittered(7, 3)
    sf3 = mlsph_jax.shape_functions(x3, degree=1, derivative="fixed_centre")
    check_layout(sf3, len(x3), 3, 4)
    assert np.all(np.asarray(sf3.degree) == 1)
    A = np.array([[1.0, -2.0, 0.5], [0.0, 1.0, 3.0], [2.0, 0.0, -1.0]])
    f3 = x3 @ A.T + np.array([1.0, 2.0, 3.0])  # three linear fields
    np.testing.assert_allclose(
        np.asarray(sf3.interpolate(f3)), f3, rtol=0, atol=1e-10 * np.abs(f3).max()
    )
    G = np.asarray(sf3.gradient(f3))  # [N, d, 3]: G[n, a, c] = d f_c / d x_a = A[c, a]
    np.testing.assert_allclose(G, np.broadcast_to(A.T, G.shape), rtol=0, atol=1e-9)


def test_periodic_box_wraps_stencils_and_reproduces_in_minimum_image_coordinates():
    x, sf = periodic_2d()
    n = len(x)
    check_layout(sf, n, 2, 6)
    assert sf.domain.periodic == (True, True) and sf.domain.length == (1.0, 1.0)
    idx, mask = np.asarray(sf.neighbors), np.asarray(sf.mask)
    h = np.asarray(sf.h)
    np.testing.assert_allclose(h, 1.5 / 16, rtol=1e-12)  # V = box / N = 1/256
    # a particle next to the corner sees neighbours across both periodic boundaries
    i = int(np.argmin(np.linalg.norm(x, axis=1)))
    nbrs = x[idx[i][mask[i]]]
    assert np.any(nbrs[:, 0] > 0.8) and np.any(nbrs[:, 1] > 0.8)
    # no boundary anywhere: every particle keeps the quadratic basis
    assert np.all(np.asarray(sf.degree) == 2)
    # reproduction of local monomials in minimum-image coordinates (B98 eq. 5-9)
    safe = np.asarray(sf.safe_neighbors)
    dx = x[safe] - x[:, None, :]
    dx = np.where(mask[..., None], dx - np.round(dx), 0.0) / h[:, None, None]
    vals, grads = np.asarray(sf.values), np.asarray(sf.gradients) * h[:, None, None]
    for a in basis.exponents(2, 2):
        mono = np.prod(dx**a, axis=-1)
        ev = 1.0 if a.sum() == 0 else 0.0
        eg = np.eye(2)[int(np.argmax(a))] if a.sum() == 1 else np.zeros(2)
        assert np.abs((vals * mono).sum(axis=1) - ev).max() < 1e-10
        assert np.abs(np.einsum("nkd,nk->nd", grads, mono) - eg).max() < 1e-10
    # a smooth periodic field: its gradient is approximated to O(h^2)
    f = np.sin(2 * np.pi * x[:, 0]) * np.cos(2 * np.pi * x[:, 1])
    g = (
        2
        * np.pi
        * np.stack(
            [
                np.cos(2 * np.pi * x[:, 0]) * np.cos(2 * np.pi * x[:, 1]),
                -np.sin(2 * np.pi * x[:, 0]) * np.sin(2 * np.pi * x[:, 1]),
            ],
            axis=1,
        )
    )
    err = np.abs(np.asarray(sf.gradient(f)) - g).max() / (2 * np.pi)
    assert err < 0.1, err


def test_periodic_translation_invariance():
    """Translating every particle (mod the box) leaves all shape functions unchanged."""
    x0, sf0 = periodic_2d()
    x1, sf1 = periodic_2d((0.37, 0.61))
    np.testing.assert_array_equal(np.asarray(sf0.neighbors), np.asarray(sf1.neighbors))
    np.testing.assert_allclose(
        np.asarray(sf1.values), np.asarray(sf0.values), rtol=1e-10, atol=1e-13
    )
    scale = np.abs(np.asarray(sf0.gradients)).max()
    np.testing.assert_allclose(
        np.asarray(sf1.gradients), np.asarray(sf0.gradients), rtol=1e-10, atol=1e-12 * scale
    )


def test_partially_periodic_channel():
    """periodic=(True, False) with a (lower, upper) box: stencils wrap in x only."""
    x = jittered(12, 2, seed=3) * np.array([2.0, 1.0]) + np.array([-1.0, 0.0])  # [-1, 1] x [0, 1]
    sf = mlsph_jax.shape_functions(
        x, degree=1, box=((-1.0, 0.0), (1.0, 1.0)), periodic=(True, False)
    )
    n = len(x)
    check_layout(sf, n, 2, 3)
    assert sf.domain.periodic == (True, False) and sf.domain.lower == (-1.0, 0.0)
    mask = np.asarray(sf.mask)
    safe = np.asarray(sf.safe_neighbors)
    raw = x[safe] - x[:, None, :]
    assert np.any(np.abs(raw[..., 0])[mask] > 1.0)  # pairs across the periodic x boundary
    assert np.all(np.abs(raw[..., 1])[mask] < 0.5)  # never across the walls in y
    assert np.all(np.asarray(sf.degree) == 1)
    dx = raw.copy()
    dx[..., 0] -= 2.0 * np.round(dx[..., 0] / 2.0)
    dx = np.where(mask[..., None], dx, 0.0)
    vals, grads = np.asarray(sf.values), np.asarray(sf.gradients)
    np.testing.assert_allclose(np.einsum("nk,nkd->nd", vals, dx), 0.0, atol=1e-12)
    np.testing.assert_allclose(
        np.einsum("nka,nkb->nab", grads, dx), np.broadcast_to(np.eye(2), (n, 2, 2)), atol=1e-10
    )
    # y is not periodic: a linear field in y is reproduced with global coordinates
    np.testing.assert_allclose(np.asarray(sf.interpolate(x[:, 1])), x[:, 1], atol=1e-12)
    np.testing.assert_allclose(
        np.asarray(sf.gradient(x[:, 1])), np.tile([0.0, 1.0], (n, 1)), atol=1e-10
    )


# ----------------------------------------------------------------------------------------------
# input validation: InputError naming the argument (raised before any compilation)
# ----------------------------------------------------------------------------------------------

PTS = np.random.default_rng(7).uniform(size=(30, 2))


def _with_bad_point(value, i=7):
    p = PTS.copy()
    p[i, 1] = value
    return p


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_non_finite_points_name_argument_and_index(value):
    with pytest.raises(InputError) as exc:
        mlsph_jax.shape_functions(_with_bad_point(value))
    msg = str(exc.value)
    assert "points" in msg and "7" in msg and "finite" in msg


@pytest.mark.parametrize(
    "call,argument",
    [
        (lambda: mlsph_jax.shape_functions(PTS[:5]), "points"),  # N = 5 < m = 6 (quadratic, 2D)
        (lambda: mlsph_jax.shape_functions(PTS[:2], approximation="corrected"), "points"),  # N < 3
        (lambda: mlsph_jax.shape_functions(np.zeros((10, 4))), "points"),
        (lambda: mlsph_jax.shape_functions(np.zeros((0, 2))), "points"),
        (lambda: mlsph_jax.shape_functions("abc"), "points"),
        (lambda: mlsph_jax.shape_functions(PTS, degree=4), "degree"),
        (lambda: mlsph_jax.shape_functions(PTS, degree=-1), "degree"),
        (lambda: mlsph_jax.shape_functions(PTS, degree=2.0), "degree"),
        (lambda: mlsph_jax.shape_functions(PTS, degree=True), "degree"),
        (lambda: mlsph_jax.shape_functions(PTS, kernel="gaussian"), "kernel"),
        (lambda: mlsph_jax.shape_functions(PTS, approximation="rbf"), "approximation"),
        (lambda: mlsph_jax.shape_functions(PTS, derivative="diffuse"), "derivative"),
        (lambda: mlsph_jax.shape_functions(PTS, beta=0.0), "beta"),
        (lambda: mlsph_jax.shape_functions(PTS, beta=float("nan")), "beta"),
        (lambda: mlsph_jax.shape_functions(PTS, periodic=True), "box"),
        (lambda: mlsph_jax.shape_functions(PTS, periodic=(True, False)), "box"),
        (
            lambda: mlsph_jax.shape_functions(PTS, box=(1.0, 1.0), periodic=(True, False, True)),
            "periodic",
        ),
        (lambda: mlsph_jax.shape_functions(PTS, box=(1.0, 1.0, 1.0)), "box"),
        (lambda: mlsph_jax.shape_functions(PTS, box=((0.0, 0.0), (1.0, 0.0))), "box"),
        (lambda: mlsph_jax.shape_functions(PTS, volumes=np.ones(29)), "volumes"),
        (lambda: mlsph_jax.shape_functions(PTS, volumes=np.ones((30, 1))), "volumes"),
        (lambda: mlsph_jax.shape_functions(PTS, volumes=np.r_[np.ones(29), 0.0]), "volumes"),
        (lambda: mlsph_jax.shape_functions(PTS, volumes=np.r_[np.ones(29), -1.0]), "volumes"),
        (lambda: mlsph_jax.shape_functions(PTS, volumes=np.r_[np.ones(29), np.nan]), "volumes"),
    ],
)
def test_bad_input_raises_input_error_naming_the_argument(call, argument):
    with pytest.raises(InputError) as exc:
        call()
    assert argument in str(exc.value), str(exc.value)


def test_error_messages_list_allowed_names():
    with pytest.raises(InputError) as exc:
        mlsph_jax.shape_functions(PTS, kernel="gauss")
    assert all(k in str(exc.value) for k in ("cubic_spline", "quintic_spline", "wendland_c2"))
    with pytest.raises(InputError) as exc:
        mlsph_jax.shape_functions(PTS, approximation="sph")
    assert all(k in str(exc.value) for k in ("corrected", "kernel", "mls", "shepard"))
    with pytest.raises(InputError) as exc:
        mlsph_jax.shape_functions(PTS, volumes=np.r_[np.ones(29), 0.0])
    assert "29" in str(exc.value)  # the offending index
    with pytest.raises(InputError) as exc:
        mlsph_jax.shape_functions(PTS[:5])
    assert "N=5" in str(exc.value) and "6" in str(exc.value)


def test_result_is_usable_with_jnp_fields():
    """interpolate/gradient accept jax arrays and agree with the raw arrays."""
    sf = default_2d()
    f = jnp.asarray(RNG_POINTS[:, 0])
    manual = (np.asarray(sf.values) * RNG_POINTS[:, 0][np.asarray(sf.safe_neighbors)]).sum(axis=1)
    np.testing.assert_allclose(np.asarray(sf.interpolate(f)), manual, rtol=1e-14, atol=1e-15)
    assert isinstance(sf.domain, Domain)


@pytest.mark.parametrize(
    "kwargs,argument",
    [
        (dict(beta=None), "beta"),
        (dict(beta="1.5"), "beta"),
        (dict(volumes=["a"] * 30), "volumes"),
        (dict(box=("a", "b")), "box"),
        (dict(rcond="small"), "rcond"),
    ],
)
def test_non_numeric_arguments_raise_input_error(kwargs, argument):
    with pytest.raises(InputError) as exc:
        mlsph_jax.shape_functions(PTS, **kwargs)
    assert argument in str(exc.value)
