"""Complete monomial bases ordered by total degree (SPEC §4.1).

The basis of degree q in d dimensions holds every monomial xi^alpha with |alpha| <= q, ordered
by total degree and then lexicographically: 1; x, y, z; x^2, xy, xz, y^2, yz, z^2; ...
Sizes m = 1, d+1, (d+1)(d+2)/2, (d+1)(d+2)(d+3)/6 for q = 0..3.  Because lower degrees are a
leading prefix of higher ones, a fit "of degree l" on a degree-q basis is obtained by keeping
the first ``basis_size(l, d)`` monomials — this is what the per-particle degree fallback uses.

The MLS uses the shifted, h-scaled argument xi = (y - x_e) / h_e (CF04 eq. 15, B98 §4.3), so
p(0) = e_0 and grad p(0) = e_1..e_d / h_e.
"""

from __future__ import annotations

import functools
import itertools
import math

import jax.numpy as jnp
import numpy as np


@functools.cache
def exponents(degree: int, dim: int) -> np.ndarray:
    """Integer exponent table ``[m, dim]`` of the monomial basis, ordered by total degree."""
    rows = []
    for total in range(degree + 1):
        block = [a for a in itertools.product(range(total + 1), repeat=dim) if sum(a) == total]
        block.sort(reverse=True)  # x^2 before xy before y^2
        rows.extend(block)
    return np.asarray(rows, dtype=np.int32).reshape(-1, dim)


def basis_size(degree: int, dim: int) -> int:
    """Number of monomials of total degree <= ``degree`` in ``dim`` dimensions."""
    return math.comb(degree + dim, dim)


@functools.cache
def monomial_degrees(degree: int, dim: int) -> np.ndarray:
    return exponents(degree, dim).sum(axis=1)


def evaluate(xi, degree: int):
    """Monomials p(xi) for points ``xi[..., d]`` -> ``[..., m]``."""
    e = exponents(degree, xi.shape[-1])
    return _monomials(xi, e)


def _monomials(xi, e):
    d = xi.shape[-1]
    maxp = int(e.max()) if e.size else 0
    # powers[a][p] = xi_a ** p, built by repeated multiplication (exact, autodiff friendly)
    cols = []
    for a in range(d):
        pw = [jnp.ones_like(xi[..., a])]
        for _ in range(maxp):
            pw.append(pw[-1] * xi[..., a])
        cols.append(pw)
    out = []
    for row in e:
        v = cols[0][row[0]]
        for a in range(1, d):
            v = v * cols[a][row[a]]
        out.append(v)
    return jnp.stack(out, axis=-1)


def gradient(xi, degree: int):
    """Gradients of the monomials with respect to xi: ``[..., m, d]``."""
    d = xi.shape[-1]
    e = exponents(degree, d)
    grads = []
    for a in range(d):
        de = e.copy()
        coef = de[:, a].astype(np.float64)
        de[:, a] = np.maximum(de[:, a] - 1, 0)
        grads.append(_monomials(xi, de) * jnp.asarray(coef, xi.dtype))
    return jnp.stack(grads, axis=-1)


@functools.cache
def gradient_at_origin(degree: int, dim: int) -> np.ndarray:
    """grad_xi p(0): ``[m, d]`` with ones at the linear monomials (zero if degree 0)."""
    e = exponents(degree, dim)
    g = np.zeros((len(e), dim))
    for k, row in enumerate(e):
        if row.sum() == 1:
            g[k, int(np.argmax(row))] = 1.0
    return g


@functools.cache
def hessian_at_origin(degree: int, dim: int) -> np.ndarray:
    """Second derivatives d^2 p / dxi_a dxi_b at 0: ``[m, d, d]`` (2 for xi_a^2, 1 for xi_a xi_b)."""
    e = exponents(degree, dim)
    H = np.zeros((len(e), dim, dim))
    for k, row in enumerate(e):
        if row.sum() == 2:
            idx = np.flatnonzero(row)
            if len(idx) == 1:
                H[k, idx[0], idx[0]] = 2.0
            else:
                H[k, idx[0], idx[1]] = H[k, idx[1], idx[0]] = 1.0
    return H
