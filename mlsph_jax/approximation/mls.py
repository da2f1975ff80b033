"""Moving-least-squares shape functions on a fixed-capacity stencil (SPEC §4, thesis eq. 3.8-3.10).

For an evaluation particle e with stencil S_e (its neighbour row, itself included) and offsets
dx_k = x_k - x_e, the MLS shape functions are (thesis eq. 3.8-3.10, CF04 eq. 5-17)

    N^T(x) = p^T(0) M^{-1}(x) P_x W(x),   M(x) = P_x W(x) P_x^T,

with the shifted, h-scaled basis p((y - x)/h_e) and the *classical* weight matrix
W = diag(W(|x_k - x|, h_e)) (SPEC §13.1 items 1-3: cubic-spline weight, gather smoothing length).

Everything here works on one particle's stencil and is ``vmap``-ed by the caller.

Numerics
--------
* The moment matrix is factorised by a Cholesky decomposition unrolled over the (tiny) basis
  size m, which vectorises over particles without batched LAPACK calls.  Because the basis is
  ordered by degree, the leading principal blocks of M are the moment matrices of the lower
  degrees, and their Cholesky factors are leading blocks of the same factor.
* Per-particle degree fallback (CF04 §6): the pivot ratio s_j / M_jj (Schur complement of
  monomial j relative to its own weighted norm) measures how far monomial j is from the span of
  the previous ones.  The active degree is the largest l whose monomials all have pivot ratio
  >= ``rcond``; monomials above it are dropped (identity rows), down to Shepard (degree 0),
  which is always well posed because the particle itself is in its stencil.  The choice carries
  no gradient and no NaN can appear in either branch.
* ``derivative="full"`` differentiates N(x) including M^{-1}(x) and W(x) by forward-mode
  autodiff with respect to the evaluation point (SPEC §4.4 item 1);
  ``derivative="fixed_centre"`` freezes C_e = M_e^{-1} P_e W_e and differentiates only the basis
  (the cheaper "diffuse" derivative, SPEC §4.4 item 2).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..kernels import Kernel
from . import basis


UNROLL_MAX = 10  # basis sizes up to this are unrolled; larger ones (3D cubic, m = 20) use loops


def cholesky_pivots(M, rcond):
    """Cholesky of symmetric ``M[m, m]`` with guarded pivots (unrolled for small m).

    Returns ``(L, ok)``: the lower factor (rows after a failed pivot are finite but meaningless)
    and ``ok[m]``, whether each pivot ratio s_j / M_jj is >= rcond.
    """
    if M.shape[-1] > UNROLL_MAX:
        return _cholesky_pivots_loop(M, rcond)
    return _cholesky_pivots_unrolled(M, rcond)


def _cholesky_pivots_loop(M, rcond):
    m = M.shape[-1]
    rows = jnp.arange(m)

    def body(j, carry):
        L, ok = carry
        Lj = L[j]
        s = M[j, j] - jnp.dot(Lj, Lj)
        good = s > rcond * jnp.maximum(M[j, j], 1e-300)
        ljj = jnp.sqrt(jnp.where(good, s, 1.0))
        col = (M[:, j] - L @ Lj) / ljj
        col = jnp.where(rows > j, col, jnp.where(rows == j, ljj, 0.0))
        return L.at[:, j].set(col), ok.at[j].set(good)

    L0 = jnp.zeros_like(M)
    return jax.lax.fori_loop(0, m, body, (L0, jnp.zeros(m, bool)))


def _cholesky_pivots_unrolled(M, rcond):
    """Unrolled version of :func:`cholesky_pivots`.

    Returns ``(L, ok)``: the lower factor (rows after a failed pivot are finite but meaningless)
    and ``ok[m]``, whether each pivot ratio s_j / M_jj is >= rcond.
    """
    m = M.shape[-1]
    L = [[None] * m for _ in range(m)]
    ok = []
    for j in range(m):
        s = M[j, j]
        for k in range(j):
            s = s - L[j][k] * L[j][k]
        good = s > rcond * jnp.maximum(M[j, j], 1e-300)
        ok.append(good)
        ljj = jnp.sqrt(jnp.where(good, s, 1.0))
        L[j][j] = ljj
        for i in range(j + 1, m):
            t = M[i, j]
            for k in range(j):
                t = t - L[i][k] * L[j][k]
            L[i][j] = t / ljj
    zero = jnp.zeros_like(M[0, 0])
    rows = [jnp.stack([L[i][j] if j <= i else zero for j in range(m)]) for i in range(m)]
    return jnp.stack(rows), jnp.stack(ok)


def active_monomials(ok, degree: int, dim: int):
    """Active-set mask ``[m]`` and active degree from the pivot flags (prefix by degree level)."""
    mdeg = basis.monomial_degrees(degree, dim)
    level_ok = []
    run = jnp.asarray(True)
    for lev in range(degree + 1):
        run = run & jnp.all(jnp.where(jnp.asarray(mdeg == lev), ok, True))
        level_ok.append(run)
    level_ok = jnp.stack(level_ok)
    active_degree = jnp.sum(level_ok.astype(jnp.int32)) - 1  # level 0 always ok
    active = jnp.asarray(mdeg) <= active_degree
    return active, active_degree


def chol_solve(L, B):
    """Solve (L L^T) X = B for lower-triangular ``L[m, m]`` and ``B[m, ...]``."""
    m = L.shape[0]
    if m > UNROLL_MAX:
        return _chol_solve_loop(L, B)
    y = []
    for i in range(m):
        t = B[i]
        for k in range(i):
            t = t - L[i, k] * y[k]
        y.append(t / L[i, i])
    x = [None] * m
    for i in reversed(range(m)):
        t = y[i]
        for k in range(i + 1, m):
            t = t - L[k, i] * x[k]
        x[i] = t / L[i, i]
    return jnp.stack(x)


def _chol_solve_loop(L, B):
    m = L.shape[0]
    Bf = B.reshape(m, -1)

    def fwd(i, y):
        return y.at[i].set((Bf[i] - L[i] @ y) / L[i, i])

    y = jax.lax.fori_loop(0, m, fwd, jnp.zeros_like(Bf))

    def bwd(t, x):
        i = m - 1 - t
        return x.at[i].set((y[i] - L[:, i] @ x) / L[i, i])

    x = jax.lax.fori_loop(0, m, bwd, jnp.zeros_like(Bf))
    return x.reshape(B.shape)


def _moments(dx, mask, h, kernel: Kernel, degree: int):
    """Weights w[K], basis P[K, m] and moment matrix M[m, m] for offsets dx[K, d] from the centre."""
    w = kernel.w_vec(dx, h) * mask
    P = basis.evaluate(dx / h, degree)
    M = jnp.einsum("k,ka,kb->ab", w, P, P)
    return w, P, M


def _masked_factor(M, active):
    L, _ = cholesky_pivots(M, 0.0)
    act2 = active[:, None] & active[None, :]
    return jnp.where(act2, L, jnp.eye(M.shape[0], dtype=M.dtype))


def stencil_fit(dx, mask, h, *, kernel: Kernel, degree: int, rcond: float):
    """Fixed-centre MLS data of one particle.

    Returns ``(C, active_degree, active)`` with ``C[m, K] = M^{-1} P^T W`` restricted to the
    active monomials (rows of dropped monomials are zero).  ``p(xi)^T C u_S`` is the fitted
    polynomial of the stencil data ``u_S`` at the scaled offset xi (thesis eq. 4.39 as read in
    SPEC §13.1 item 6).
    """
    dx = jnp.where(mask[:, None], dx, 0.0)
    w, P, M = _moments(dx, mask, h, kernel, degree)
    _, ok = cholesky_pivots(jax.lax.stop_gradient(M), rcond)
    active, active_degree = active_monomials(ok, degree, dx.shape[-1])
    active = jax.lax.stop_gradient(active)
    L = _masked_factor(M, active)
    B = jnp.where(active[:, None], (P * w[:, None]).T, 0.0)
    C = chol_solve(L, B)
    return C, active_degree, active


def shape_values_full(dx, mask, h, active, *, kernel: Kernel, degree: int, shift):
    """N_k(x_e + shift) for the stencil with the active set fixed (used for autodiff)."""
    y = jnp.where(mask[:, None], dx, 0.0) - shift
    w, P, M = _moments(y, mask, h, kernel, degree)
    L = _masked_factor(M, active)
    e0 = jnp.zeros(M.shape[0], M.dtype).at[0].set(1.0)
    z = chol_solve(L, e0)
    return w * (P @ z)


def particle_operators(dx, mask, h, *, kernel: Kernel, degree: int, rcond: float, derivative: str,
                       with_coeffs: bool):
    """Values N_k(x_e), gradients grad N_k(x_e) and (optionally) coefficients for one particle."""
    d = dx.shape[-1]
    C, active_degree, active = stencil_fit(dx, mask, h, kernel=kernel, degree=degree, rcond=rcond)
    values = C[0]
    if derivative == "full":
        f = lambda s: shape_values_full(dx, mask, h, active, kernel=kernel, degree=degree, shift=s)
        grads = jax.jacfwd(f)(jnp.zeros(d, dx.dtype))  # [K, d]
    else:
        g0 = jnp.asarray(basis.gradient_at_origin(degree, d))  # [m, d]
        grads = jnp.einsum("md,mk->kd", g0, C) / h
    grads = jnp.where(mask[:, None], grads, 0.0)
    values = jnp.where(mask, values, 0.0)
    return values, grads, (C if with_coeffs else None), active_degree


def hessians_fixed_centre(C, h, degree: int, dim: int):
    """Fixed-centre Hessians of the shape functions ``[K, d, d]`` from the coefficients C."""
    H0 = jnp.asarray(basis.hessian_at_origin(degree, dim))
    return jnp.einsum("mab,mk->kab", H0, C) / h**2


def monomial_count(degree: int, dim: int) -> int:
    return int(np.asarray(basis.basis_size(degree, dim)))
