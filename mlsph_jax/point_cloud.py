"""Shape functions of a point cloud in one call (the public convenience entry point).

>>> import numpy as np, mlsph_jax
>>> pts = np.random.default_rng(0).uniform(size=(400, 2))
>>> sf = mlsph_jax.shape_functions(pts, approximation="mls", degree=2)
>>> f = pts[:, 0] ** 2 + pts[:, 1]                    # any quadratic is reproduced exactly
>>> approx = (sf.values * f[sf.safe_neighbors]).sum(1)  # == f to round-off
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from . import neighbors as nb
from .approximation import (
    APPROXIMATIONS,
    DERIVATIVES,
    ApproxSpec,
    ShapeOperators,
    build,
    smoothing_length,
)
from .approximation.basis import basis_size
from .errors import InputError
from .kernels import get_kernel
from .state import Domain


@dataclasses.dataclass(frozen=True)
class ShapeFunctions:
    """Result of :func:`shape_functions`.

    ``neighbors[N, K]`` (padded with N), ``mask[N, K]``, ``values[N, K]`` = N_j(x_i) and
    ``gradients[N, K, d]`` = grad N_j(x_i) for j = neighbors[i, k]; ``h[N]`` smoothing lengths,
    ``degree[N]`` the active MLS degree after fallback (``corrected``: 1 for the renormalised
    gradient, 0 where it fell back to the kernel gradient; ``kernel``: -1),
    ``operators`` the underlying :class:`ShapeOperators` (with MLS coefficients),
    ``domain`` and ``spec`` as used.
    """

    neighbors: jax.Array
    mask: jax.Array
    values: jax.Array
    gradients: jax.Array
    h: jax.Array
    degree: jax.Array
    operators: ShapeOperators
    domain: Domain
    spec: ApproxSpec

    @property
    def safe_neighbors(self) -> jax.Array:
        """Neighbour indices with padding replaced by the row's own index (safe for gathers;
        padded entries have zero values and gradients)."""
        n = self.neighbors.shape[0]
        return jnp.where(self.mask, self.neighbors, jnp.arange(n)[:, None])

    def interpolate(self, field):
        """sum_j N_j(x_i) f_j for ``field[N, ...]``."""
        f = jnp.asarray(field)
        return jnp.einsum("nk,nk...->n...", self.values, f[self.safe_neighbors])

    def gradient(self, field):
        """sum_j grad N_j(x_i) f_j for ``field[N, ...]`` -> ``[N, d, ...]``."""
        f = jnp.asarray(field)
        return jnp.einsum("nkd,nk...->nd...", self.gradients, f[self.safe_neighbors])


def shape_functions(points, approximation: str = "mls", degree: int = 2, kernel: str = "cubic_spline",
                    beta: float = 1.5, volumes=None, box=None, periodic=None,
                    derivative: str = "full", rcond: float = 1e-6) -> ShapeFunctions:
    """Shape-function values and gradients of a point cloud (SPEC §4; thesis eq. 3.8-3.10).

    points:        ``[N, d]`` array, d = 1, 2, 3 (a 1D array is read as d = 1).
    approximation: ``mls`` | ``shepard`` | ``kernel`` | ``corrected``.
    degree:        MLS basis degree 0..3.
    kernel:        ``cubic_spline`` | ``wendland_c2`` | ``quintic_spline`` (MLS weight / SPH kernel).
    beta:          smoothing-length factor, h_i = beta V_i^(1/d) (thesis eq. 4.34).
    volumes:       ``[N]`` particle volumes; default: box (or bounding-box) volume / N.
    box:           ``(lower, upper)`` pair of length-d sequences, or a length-d sequence of box
                   lengths (lower = 0); required when any axis is periodic.
    periodic:      bool or length-d sequence of bools (minimum-image convention).
    derivative:    ``full`` (differentiates M^{-1}(x) and W(x) too) | ``fixed_centre``.
    rcond:         pivot-ratio threshold for the per-particle MLS degree fallback.

    Raises :class:`~mlsph_jax.errors.InputError` naming the argument for non-finite positions,
    N smaller than the stencil size, degree outside 0..3 and unknown names.
    """
    x = _points(points)
    n, d = x.shape
    APPROXIMATIONS.get(approximation, "approximation")
    kern = get_kernel(kernel)
    if derivative not in DERIVATIVES:
        raise InputError(f"invalid derivative={derivative!r}; allowed: {', '.join(DERIVATIVES)}")
    if isinstance(degree, bool) or not isinstance(degree, int | np.integer) or not 0 <= degree <= 3:
        raise InputError(f"invalid degree={degree!r}; allowed: an integer in 0..3")
    degree = int(degree)
    beta = _positive_float(beta, "beta")
    rcond = _positive_float(rcond, "rcond")
    m = basis_size(degree if approximation == "mls" else (1 if approximation == "corrected" else 0), d)
    if n < m:
        raise InputError(f"invalid points: N={n} particles is smaller than the stencil size m={m} "
                         f"of approximation={approximation!r}, degree={degree} in {d}D; allowed: N >= {m}")
    domain = _domain(x, box, periodic)
    if volumes is None:
        vol = np.full(n, float(np.prod(domain.length)) / n)
    else:
        try:
            vol = np.asarray(volumes, dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError(f"invalid volumes of type {type(volumes).__name__}; "
                             f"allowed: {n} finite numbers > 0") from None
        if vol.shape != (n,):
            raise InputError(f"invalid volumes with shape {vol.shape}; allowed: shape ({n},)")
        bad = np.flatnonzero(~np.isfinite(vol) | (vol <= 0))
        if bad.size:
            raise InputError(f"invalid volumes[{bad[0]}]={vol[bad[0]]!r}; allowed: finite values > 0")
    h = np.asarray(smoothing_length(vol, beta, d))
    nspec, nl = nb.allocate(x, h, domain, support=kern.support)
    nspec, nl = nb.update_or_grow(jnp.asarray(x), jnp.asarray(h), nspec)
    spec = ApproxSpec(approximation, degree, kernel, derivative, rcond, with_coeffs=approximation in ("mls", "shepard"))
    L = jnp.asarray(domain.length) if domain.any_periodic else None
    per = jnp.asarray(domain.periodic) if domain.any_periodic else None
    ops = build(jnp.asarray(x), jnp.asarray(h), jnp.asarray(vol), nl.idx, nl.mask, spec, L, per)
    return ShapeFunctions(nl.idx, nl.mask, ops.values, ops.gradients, ops.h, ops.degree, ops, domain, spec)


def _positive_float(value, name: str) -> float:
    """``value`` as a finite float > 0, or an InputError naming ``name``."""
    if isinstance(value, bool | str) or value is None:
        raise InputError(f"invalid {name}={value!r}; allowed: a finite number > 0")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"invalid {name}={value!r}; allowed: a finite number > 0") from None
    if not (np.isfinite(v) and v > 0):
        raise InputError(f"invalid {name}={value!r}; allowed: a finite number > 0")
    return v


def _points(points) -> np.ndarray:
    try:
        x = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"invalid points of type {type(points).__name__}; allowed: an array of shape (N, d)") from None
    if x.ndim == 1:
        x = x[:, None]
    if x.ndim != 2 or x.shape[1] not in (1, 2, 3) or x.shape[0] == 0:
        raise InputError(f"invalid points with shape {x.shape}; allowed: shape (N, d) with N >= 1, d in 1..3")
    bad = np.flatnonzero(~np.isfinite(x).all(axis=1))
    if bad.size:
        raise InputError(f"invalid points: non-finite position at index {bad[0]} ({x[bad[0]].tolist()}); "
                         "allowed: finite coordinates")
    return x


def _domain(x: np.ndarray, box, periodic) -> Domain:
    d = x.shape[1]
    if periodic is None or periodic is False:
        per = (False,) * d
    elif periodic is True:
        per = (True,) * d
    else:
        per = tuple(bool(p) for p in np.atleast_1d(periodic))
        if len(per) != d:
            raise InputError(f"invalid periodic={periodic!r}; allowed: a bool or {d} bools")
    if box is None:
        if any(per):
            raise InputError(f"invalid box=None with periodic={periodic!r}; allowed: a box is required "
                             "when an axis is periodic")
        lo, hi = x.min(axis=0), x.max(axis=0)
        span = np.maximum(hi - lo, 1e-12 * max(1.0, float(np.abs(x).max())))
        # bounding box of the cloud, widened by one mean spacing so that volumes are sensible
        pad = span / max(1.0, x.shape[0] ** (1.0 / d))
        lower, upper = lo - 0.5 * pad, hi + 0.5 * pad
    else:
        try:
            b = np.asarray(box, dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError(f"invalid box={box!r}; allowed: {d} box lengths or a (lower, upper) pair of "
                             f"{d}-sequences of numbers") from None
        if b.shape == (d,):
            lower, upper = np.zeros(d), b
        elif b.shape == (2, d):
            lower, upper = b[0], b[1]
        else:
            raise InputError(f"invalid box with shape {b.shape}; allowed: ({d},) lengths or (2, {d}) lower/upper")
        if not np.all(np.isfinite(b)) or np.any(upper <= lower):
            raise InputError(f"invalid box={b.tolist()}; allowed: finite bounds with upper > lower")
    return Domain(tuple(map(float, lower)), tuple(map(float, upper)), per)
