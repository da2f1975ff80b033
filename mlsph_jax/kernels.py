"""Smoothing kernels W(r, h) = sigma_d / h^d * f(r / h) and their gradients.

* ``cubic_spline`` — Monaghan & Lattanzio M4 spline, thesis eq. (2.30) and appendix A:
  f(q) = 1 - 3/2 q^2 + 3/4 q^3 (q <= 1), 1/4 (2 - q)^3 (1 < q <= 2), support 2h,
  sigma_d = 2/3, 10/(7 pi), 1/pi (thesis L718, L2913, L2931, L2951).
* ``wendland_c2`` — Wendland C2 written with support 2h (Dehnen & Aly 2012 scaling):
  1D f = (1 - q/2)^3 (3q/2 + 1), sigma = 5/8;  2D/3D f = (1 - q/2)^4 (2q + 1),
  sigma = 7/(4 pi), 21/(16 pi).
* ``quintic_spline`` — Morris (1997) M6 spline, support 3h,
  sigma_d = 1/120, 7/(478 pi), 1/(120 pi).

``support`` is the kernel's support factor kappa: W = 0 for r >= kappa h.  Gradients are taken
with respect to the first argument, ``grad W(dx) = f'(q) sigma_d / h^(d+1) * dx / |dx|``, which
points from the centre towards ``dx`` scaled by f' < 0 (SPEC §3.1).  All functions are pure,
vectorised and safe at r = 0 (no NaN in values or derivatives, also under autodiff).

Derivatives at the origin.  |dx| has no derivative at dx = 0, so autodiff through r = |dx| (the
zero-derivative :func:`safe_norm`) sees a flat kernel there, while the kernel itself is smooth:
its Hessian at the origin is f''(0) sigma_d / h^(d+2) I (the limit of f'(q) / q).  ``grad`` is
therefore written as g(r) dx with g(r) = (dW/dr) / r and g(0) = that limit (``Kernel.f2_0``,
f''(0) of each kernel), and ``w_vec`` carries a custom JVP whose tangent is ``grad . t`` (plus
dW/dh for a differentiated h): the first and second autodiff derivatives of W (and the first of
grad W), in x, h or both and in any order, are the kernel's, also at dx = 0.  (Third derivatives
in x do not exist at the origin: every kernel here has a q^3 term.)  Values equal those of the
plain formulas (bit for bit except the sign of the zero gradient at r = 0).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable

import jax
import jax.numpy as jnp

from .registry import Registry


@dataclasses.dataclass(frozen=True)
class Kernel:
    """A radial smoothing kernel; hashable so it can be a static jit argument."""

    name: str
    support: float
    sigma: tuple[float, float, float]
    f: Callable[[jax.Array], jax.Array] = dataclasses.field(compare=False, repr=False)
    df: Callable[[jax.Array], jax.Array] = dataclasses.field(compare=False, repr=False)
    #: f''(0) in 1, 2, 3 dimensions: the limit of f'(q) / q at the origin (module docstring)
    f2_0: tuple[float, float, float]

    def norm(self, dim: int) -> float:
        return self.sigma[dim - 1]

    def w(self, r: jax.Array, h: jax.Array, dim: int) -> jax.Array:
        """Kernel value W(r, h) in ``dim`` dimensions."""
        return self.norm(dim) / h**dim * self.f(r / h)

    def dw_dr(self, r: jax.Array, h: jax.Array, dim: int) -> jax.Array:
        """Radial derivative dW/dr."""
        return self.norm(dim) / h ** (dim + 1) * self.df(r / h)

    def w_vec(self, dx: jax.Array, h: jax.Array) -> jax.Array:
        """W(|dx|, h) for separation vectors ``dx[..., d]``; its autodiff derivative with respect
        to dx is :meth:`grad` (also at dx = 0, where r = |dx| has none), with respect to h
        dW/dh = -(d W + r dW/dr) / h."""
        dx, h = jnp.asarray(dx), jnp.asarray(h)
        if not jnp.issubdtype(dx.dtype, jnp.inexact):
            dx = dx.astype(jnp.result_type(float))
        if not jnp.issubdtype(h.dtype, jnp.inexact):      # an integer h: no float0 tangent in the rule
            h = h.astype(dx.dtype)
        return _w_vec(self, dx, h)

    def radial_factor(self, dx: jax.Array, h: jax.Array) -> jax.Array:
        """g = (dW/dr) / r, shape ``dx.shape[:-1]``, with its limit f''(0) sigma_d / h^(d+2) at
        r = 0 (so that g dx is the gradient and its Jacobian the Hessian, also at the origin)."""
        d = dx.shape[-1]
        r = safe_norm(dx)
        rs = jnp.where(r > 0, r, 1.0)
        return jnp.where(r > 0, self.dw_dr(r, h, d) / rs, self.f2_0[d - 1] * self.norm(d) / h ** (d + 2))

    def grad(self, dx: jax.Array, h: jax.Array) -> jax.Array:
        """Gradient of W(|dx|, h) with respect to dx, shape ``[..., d]``: g(r) dx with
        g = :meth:`radial_factor`, so that the Jacobian of the gradient (the Hessian of W) is the
        kernel's also at dx = 0 (where the value is 0)."""
        return self.radial_factor(dx, h)[..., None] * dx


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def _w_vec(kernel: Kernel, dx, h):
    return kernel.w(safe_norm(dx), h, dx.shape[-1])


@_w_vec.defjvp
def _w_vec_jvp(kernel: Kernel, primals, tangents):
    """Tangent g dx . t_dx + dW/dh t_h with dW/dh = -(d W + g r^2) / h, everything written with
    W itself (this rule again) and g: the first and second derivatives, in either order (x then h
    or h then x), are the kernel's, also at dx = 0.  (Higher ones exist at the origin only as far
    as the kernel's odd powers of r allow: the r^3 term of the cubic spline and of the Wendland C2
    kernel has no third derivative there.)"""
    dx, h = primals
    t_dx, t_h = tangents
    d = dx.shape[-1]
    w = _w_vec(kernel, dx, h)
    g = kernel.radial_factor(dx, h)
    dw_dh = -(d * w + g * jnp.sum(dx * dx, axis=-1)) / h
    return w, g * jnp.sum(dx * t_dx, axis=-1) + dw_dh * t_h


def safe_norm(dx: jax.Array) -> jax.Array:
    """Euclidean norm over the last axis whose derivative is finite (zero) at dx = 0."""
    r2 = jnp.sum(dx * dx, axis=-1)
    pos = r2 > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, r2, 1.0)), 0.0)


KERNELS: Registry[Kernel] = Registry("scheme.kernel")


def _pos(a):
    return jnp.maximum(a, 0.0)


def _cubic_f(q):
    return jnp.where(q <= 1.0, 1.0 - 1.5 * q**2 + 0.75 * q**3, 0.25 * _pos(2.0 - q) ** 3)


def _cubic_df(q):
    return jnp.where(q <= 1.0, -3.0 * q + 2.25 * q**2, -0.75 * _pos(2.0 - q) ** 2)


KERNELS.register("cubic_spline")(
    Kernel("cubic_spline", 2.0, (2.0 / 3.0, 10.0 / (7.0 * math.pi), 1.0 / math.pi), _cubic_f, _cubic_df,
           (-3.0, -3.0, -3.0))
)


def _wendland_f(q):  # 2D/3D form; the 1D form is selected in Wendland.w via dim
    t = _pos(1.0 - 0.5 * q)
    return t**4 * (2.0 * q + 1.0)


def _wendland_df(q):
    t = _pos(1.0 - 0.5 * q)
    return -2.0 * t**3 * (2.0 * q + 1.0) + 2.0 * t**4  # = -5 q t^3


def _wendland1_f(q):
    t = _pos(1.0 - 0.5 * q)
    return t**3 * (1.5 * q + 1.0)


def _wendland1_df(q):
    t = _pos(1.0 - 0.5 * q)
    return -1.5 * t**2 * (1.5 * q + 1.0) + 1.5 * t**3  # = -3 q t^2


@dataclasses.dataclass(frozen=True)
class _WendlandC2(Kernel):
    """Wendland C2: the 1D member of the family differs from the 2D/3D one."""

    def w(self, r, h, dim):
        f = _wendland1_f if dim == 1 else _wendland_f
        return self.norm(dim) / h**dim * f(r / h)

    def dw_dr(self, r, h, dim):
        df = _wendland1_df if dim == 1 else _wendland_df
        return self.norm(dim) / h ** (dim + 1) * df(r / h)


KERNELS.register("wendland_c2")(
    _WendlandC2("wendland_c2", 2.0, (5.0 / 8.0, 7.0 / (4.0 * math.pi), 21.0 / (16.0 * math.pi)),
                _wendland_f, _wendland_df, (-3.0, -5.0, -5.0))
)


def _quintic_f(q):
    return _pos(3.0 - q) ** 5 - 6.0 * _pos(2.0 - q) ** 5 + 15.0 * _pos(1.0 - q) ** 5


def _quintic_df(q):
    return -5.0 * _pos(3.0 - q) ** 4 + 30.0 * _pos(2.0 - q) ** 4 - 75.0 * _pos(1.0 - q) ** 4


KERNELS.register("quintic_spline")(
    Kernel("quintic_spline", 3.0, (1.0 / 120.0, 7.0 / (478.0 * math.pi), 1.0 / (120.0 * math.pi)),
           _quintic_f, _quintic_df, (-120.0, -120.0, -120.0))
)


def get_kernel(name: str) -> Kernel:
    """Look up a kernel by name; unknown names raise InputError listing the valid ones."""
    return KERNELS.get(name, "kernel")
