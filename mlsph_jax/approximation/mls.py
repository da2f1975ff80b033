"""Moving-least-squares shape functions on a fixed-capacity stencil (SPEC §4, thesis eq. 3.8-3.10).

For an evaluation particle e with stencil S_e (its neighbour row, itself included) and offsets
dx_k = x_k - x_e, the MLS shape functions are (thesis eq. 3.8-3.10, CF04 eq. 5-17)

    N^T(x) = p^T(0) M^{-1}(x) P_x W(x),   M(x) = P_x W(x) P_x^T,

with the shifted, h-scaled basis p((y - x)/h_e) and the *classical* weight matrix
W = diag(W(|x_k - x|, h_e)) (SPEC §13.1 items 1-3: cubic-spline weight, gather smoothing length).

The per-particle functions work on one particle's stencil (``vmap``-able); ``build`` uses the
batched :func:`operators_block` (blocks of particles as structure-of-arrays planes) for basis
sizes up to UNROLL_MAX and the vmapped per-particle path above that (3D cubic).

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
* ``derivative="full"`` differentiates N(x) including M^{-1}(x) and W(x) with respect to the
  evaluation point (SPEC §4.4 item 1).  :func:`particle_operators` does it by forward-mode
  autodiff of :func:`shape_values_full`; the batched :func:`operators_block` (used by
  ``build``) uses the closed form with the same factor,

      z = M^{-1} e_0,  N_k = w_k p_k.z,
      grad N_k = (grad w_k) p_k.z + w_k (grad p_k).z + w_k p_k.(grad z),
      grad_a z = -M^{-1} (grad_a M) z,
      (grad_a M) z = sum_k [p_k (dw_k t_k + w_k u_k) + dp_k w_k t_k]

  with t_k = p_k.z and u_k = (grad_a p_k).z (one solve for z and d more; restricted to the
  active monomials exactly as the autodiff of the masked factor is);
  ``derivative="fixed_centre"`` freezes C_e = M_e^{-1} P_e W_e and differentiates only the basis
  (the cheaper "diffuse" derivative, SPEC §4.4 item 2).
* In :func:`operators_block` the unrolled factor of a row block ([B, 1] arrays) is computed
  inside a conditional (:func:`per_row_once`, docs/architecture.md decision 94).  XLA:CPU's
  fusion otherwise copies these cheap elementwise producers into every fused consumer over the
  [B, K] stencil planes, which multiplies the compiled program's size and its compile time; the
  results were measured to be the same bits.
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
    active_degree = jnp.sum(level_ok, dtype=jnp.int32) - 1  # level 0 always ok
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


# ----------------------------------------------------------------------------------------------
# Batched ("structure of arrays") operators: used by ``build`` for basis sizes <= UNROLL_MAX.
#
# A block of B particles is processed at once: per-particle scalars are [B, 1] arrays, per-slot
# quantities [B, K] "planes", and the small matrices nested Python lists of those.  Every sum
# over the stencil is one variadic ``lax.reduce`` (all moments in one pass over the planes),
# which XLA:CPU compiles to a single fused loop; batched tiny matmuls (``einsum`` under
# ``vmap``) and the per-particle ``jacfwd`` are avoided.  Results equal
# :func:`particle_operators` to round-off (tests/test_rhs_equivalence_perf.py).
# ----------------------------------------------------------------------------------------------


def stencil_sums(terms):
    """``[t.sum(-1) for t in terms]`` as one variadic reduction (a single fused loop on CPU).

    Differentiable: the tangents are summed with ``jnp.sum`` (the generic variadic ``reduce``
    has no autodiff rules).
    """
    return list(_stencil_sums(tuple(terms)))


@jax.custom_jvp
def _stencil_sums(terms):
    axis = terms[0].ndim - 1
    zero = tuple(jnp.zeros((), t.dtype) for t in terms)
    return jax.lax.reduce(terms, zero, lambda a, b: tuple(x + y for x, y in zip(a, b, strict=True)),
                          (axis,))


@_stencil_sums.defjvp
def _stencil_sums_jvp(primals, tangents):
    (terms,), (dterms,) = primals, tangents
    return _stencil_sums(terms), tuple(jnp.sum(t, axis=-1) for t in dterms)


def _power_table(xi, maxp):
    cols = []
    for x in xi:
        pw = [None, x]
        for _ in range(2, maxp + 1):
            pw.append(pw[-1] * x)
        cols.append(pw)
    return cols


def _power_product(cols, row):
    v = None
    for a, p in enumerate(row):
        if p:
            v = cols[a][p] if v is None else v * cols[a][p]
    return v


def monomial_planes(xi, degree: int):
    """Monomials p_a(xi) of the components ``xi`` (a list of d equally shaped arrays), in the
    order of :func:`basis.exponents`; ``None`` stands for the constant monomial 1."""
    e = basis.exponents(degree, len(xi))
    cols = _power_table(xi, int(e.max()) if e.size else 0)
    return [_power_product(cols, row) for row in e]


def monomial_gradient_planes(xi, degree: int):
    """``[alpha][a]`` = d p_a / d xi_alpha: an array, a float constant, or ``None`` for zero."""
    e = basis.exponents(degree, len(xi))
    cols = _power_table(xi, int(e.max()) if e.size else 0)
    out = []
    for al in range(len(xi)):
        row_out = []
        for row in e:
            if row[al] == 0:
                row_out.append(None)
                continue
            lower = row.copy()
            lower[al] -= 1
            v = _power_product(cols, lower)
            c = float(row[al])
            row_out.append(c if v is None else (v if c == 1.0 else v * c))
        out.append(row_out)
    return out


def cholesky_lists(M, rcond):
    """Unrolled Cholesky of a nested-list matrix ``M[i][j]`` (arrays, lower triangle read).

    Returns ``(L, ok)``: the factor with the guard of ``cholesky_pivots(M, 0)`` and the pivot
    flags of ``cholesky_pivots(M, rcond)``.  The flags agree up to the first failing pivot (the
    factors coincide until then), and that pivot alone decides the active degree.
    """
    m = len(M)
    L = [[None] * m for _ in range(m)]
    ok = []
    for j in range(m):
        s = M[j][j]
        for k in range(j):
            s = s - L[j][k] * L[j][k]
        ok.append(jax.lax.stop_gradient(s > rcond * jnp.maximum(M[j][j], 1e-300)))
        ljj = jnp.sqrt(jnp.where(s > 0.0, s, 1.0))
        L[j][j] = ljj
        for i in range(j + 1, m):
            t = M[i][j]
            for k in range(j):
                t = t - L[i][k] * L[j][k]
            L[i][j] = t / ljj
    return L, ok


def chol_solve_lists(L, B):
    """Solve (L L^T) X = B for a nested-list factor and a list ``B`` of m arrays (``None`` = 0)."""
    m = len(L)
    y = []
    for i in range(m):
        t = B[i]
        for k in range(i):
            if y[k] is not None:
                t = -(L[i][k] * y[k]) if t is None else t - L[i][k] * y[k]
        y.append(None if t is None else t / L[i][i])
    x = [None] * m
    for i in reversed(range(m)):
        t = y[i]
        for k in range(i + 1, m):
            if x[k] is not None:
                t = -(L[k][i] * x[k]) if t is None else t - L[k][i] * x[k]
        x[i] = None if t is None else t / L[i][i]
    return x


def per_row_once(fn, *operands):
    """``fn(*operands)``, computed once: inside a ``lax.cond`` (docs/architecture.md decision 94).

    XLA:CPU's fusion duplicates cheap elementwise producers into every fused consumer: the
    unrolled factor of a row block ([B, 1] arrays) was recomputed inside each fusion over the
    [B, K] stencil planes that reads it (a 2D cubic block with the full derivative: 26,267 HLO
    instructions, ~11 copies of the factor).  A conditional is not fused into its consumers, so
    its results are computed once and read from memory.  Operands (distinct arrays only: the
    symmetric M holds each off-diagonal sum twice) and results cross the conditional stacked, one
    array per shape and dtype.  Both branches are ``fn`` and the predicate is a traced value (not
    folded at compile time), so whichever branch runs computes ``fn``; the outputs were measured
    bit for bit equal to the inlined ``fn`` (all config fingerprints, tests/test_rhs_equivalence_
    perf.py), which the moved fusion boundaries do not guarantee by construction.  Under ``vmap``
    with a batched predicate JAX evaluates both branches (twice the work, the same results); the
    package calls this on row blocks, never under ``vmap``.  On other backends than the CPU ``fn``
    is called inline: a conditional on a GPU may read its predicate on the host, not measured here.
    """
    if jax.default_backend() != "cpu":
        return fn(*operands)
    operands = tuple(jnp.asarray(a) if isinstance(a, (int, float)) else a for a in operands)
    leaves, tree = jax.tree.flatten(operands)
    out_leaves, out_tree = jax.tree.flatten(jax.eval_shape(fn, *operands))
    first_of = {}
    unique = [first_of.setdefault(id(a), i) == i for i, a in enumerate(leaves)]

    def groups(avals, keep):
        g = {}
        for i, a in enumerate(avals):
            if keep[i]:
                g.setdefault((a.shape, jnp.dtype(a.dtype)), []).append(i)
        return list(g.values())

    in_groups, out_groups = groups(leaves, unique), groups(out_leaves, [True] * len(out_leaves))

    def unstack(stacks, index_groups, n):
        flat = [None] * n
        for idx, st in zip(index_groups, stacks, strict=True):
            for k, i in enumerate(idx):
                flat[i] = st[k]
        return flat

    def branch(*stacks):
        flat = unstack(stacks, in_groups, len(leaves))
        flat = [flat[first_of[id(a)]] for a in leaves]           # the duplicates
        out = jax.tree.leaves(fn(*jax.tree.unflatten(tree, flat)))
        return tuple(jnp.stack([out[i] for i in idx]) for idx in out_groups)

    stacks = [jnp.stack([leaves[i] for i in idx]) for idx in in_groups]
    head = jnp.ravel(stacks[0])[:1]                                # (empty for B = 0)
    res = jax.lax.cond(jnp.all(head == head), branch, branch, *stacks)
    return jax.tree.unflatten(out_tree, unstack(res, out_groups, len(out_leaves)))


def operators_block(dx, mask, h, *, kernel: Kernel, degree: int, rcond: float, derivative: str,
                    with_coeffs: bool, vol_j=None, thresholds=None):
    """:func:`particle_operators` for a block of particles at once.

    dx[B, K, d] offsets x_k - x_e, mask[B, K], h[B]; ``rcond`` a float or per-particle
    thresholds [B]; or, with the neighbour volumes ``vol_j[B, K]``, the thresholds
    ``thresholds(fill)[B]`` of the kernel sums fill = sum_k V_k W(|dx_k|, h) (decision 77).
    Returns values[B, K], gradients[B, K, d],
    coefficients[B, m, K] (or None) and the active degree[B].
    """
    out_dtype = dx.dtype
    # moment matrices and their solves in float64 whatever the state's precision (a float32 run,
    # run.precision): M is ill-conditioned for degree 2-3; outputs return in the input precision
    dx, h = dx.astype(jnp.float64), h.astype(jnp.float64)
    d = dx.shape[-1]
    mdeg = basis.monomial_degrees(degree, d)
    m = len(mdeg)
    hb = h[:, None]
    y = [jnp.where(mask, dx[..., a], 0.0) for a in range(d)]
    r2 = y[0] * y[0]
    for a in range(1, d):
        r2 = r2 + y[a] * y[a]
    pos = r2 > 0
    r = jnp.where(pos, jnp.sqrt(jnp.where(pos, r2, 1.0)), 0.0)      # kernels.safe_norm
    w = kernel.w(r, hb, d) * mask
    xi = [t / hb for t in y]
    P = monomial_planes(xi, degree)
    wP = [w if p is None else w * p for p in P]
    tri = [(a, b) for a in range(m) for b in range(a + 1)]
    sums = stencil_sums([wP[a] if P[b] is None else wP[a] * P[b] for a, b in tri])
    M = [[None] * m for _ in range(m)]
    for (a, b), s in zip(tri, sums, strict=True):
        M[a][b] = M[b][a] = s[:, None]
    if thresholds is not None:
        rcond = thresholds(jnp.sum(w * vol_j.astype(w.dtype), axis=1))
    L, ok = per_row_once(cholesky_lists, M, rcond if jnp.ndim(rcond) == 0 else jnp.reshape(rcond, (-1, 1)))
    run, levels = None, []
    for lev in range(degree + 1):               # prefix by degree level (active_monomials)
        for j in np.flatnonzero(mdeg == lev):
            run = ok[j] if run is None else run & ok[j]
        levels.append(run.astype(jnp.int32))
    active_degree = jax.lax.stop_gradient(sum(levels) - 1)          # [B, 1]
    active = [active_degree >= int(mdeg[a]) for a in range(m)]
    Lm = [[jnp.where(active[i] & active[j], L[i][j], 1.0 if i == j else 0.0) if j <= i else None
           for j in range(m)] for i in range(m)]                    # _masked_factor
    C = chol_solve_lists(Lm, [jnp.where(active[a], wP[a], 0.0) for a in range(m)])
    values = jnp.where(mask, C[0], 0.0)
    if derivative == "full":
        z = chol_solve_lists(Lm, [jnp.ones_like(hb)] + [None] * (m - 1))
        z = [jnp.zeros_like(hb) if v is None else v for v in z]
        t = z[0]
        for a in range(1, m):
            t = t + P[a] * z[a]
        coef = kernel.dw_dr(r, hb, d) / jnp.where(r > 0, r, 1.0)   # kernel.grad / r
        dP_xi = monomial_gradient_planes(xi, degree)
        wt = w * t
        q, terms = [], []
        for al in range(d):
            # derivatives with respect to the evaluation point: y = dx - s, xi = y / h
            dw = -(coef * y[al]) * mask
            dP = [None if g is None else -(g / hb) for g in dP_xi[al]]
            u = None
            for a in range(m):
                if dP[a] is not None:
                    u = dP[a] * z[a] if u is None else u + dP[a] * z[a]
            qa = dw * t if u is None else dw * t + w * u
            q.append(qa)
            for a in range(m):
                term = qa if P[a] is None else P[a] * qa
                terms.append(term if dP[a] is None else term + dP[a] * wt)
        dMz = stencil_sums(terms)
        grads = []
        for al in range(d):
            dz = chol_solve_lists(Lm, [jnp.where(active[a], dMz[al * m + a][:, None], 0.0)
                                       for a in range(m)])
            pdz = dz[0]
            for a in range(1, m):
                pdz = pdz + P[a] * dz[a]
            grads.append(jnp.where(mask, q[al] - w * pdz, 0.0))
    else:
        g0 = basis.gradient_at_origin(degree, d)
        grads = []
        for al in range(d):
            rows = np.flatnonzero(g0[:, al])
            g = C[int(rows[0])] / hb if rows.size else jnp.zeros_like(w)
            grads.append(jnp.where(mask, g, 0.0))
    coeffs = jnp.stack([jnp.broadcast_to(c, w.shape) for c in C], axis=1).astype(out_dtype) if with_coeffs else None
    return values.astype(out_dtype), jnp.stack(grads, axis=-1).astype(out_dtype), coeffs, active_degree[:, 0]
