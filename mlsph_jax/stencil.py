"""Index helpers on the fixed-capacity (N, K) stencil shared by the pair terms.

Every pair term is stored once per ordered pair (i, k) with j = idx[i, k]; the value of the
reverse pair (j, i) sits in slot ``rev[i, k]`` of row j (:mod:`mlsph_jax.neighbors`).  Reading it
is one flat gather, whose index needs int64 once N K reaches 2^31.
"""

from __future__ import annotations

import jax.numpy as jnp


def safe_index(idx, mask):
    """Neighbour indices with padding slots pointing at the row's own particle (always in range)."""
    n = idx.shape[0]
    return jnp.where(mask, idx, jnp.arange(n, dtype=idx.dtype)[:, None])


def flat_reverse_index(jsafe, rev, k: int):
    """Flat index ``j K + rev`` of the reverse pair's slot (int64 when N K >= 2^31)."""
    dt = jnp.int64 if jsafe.shape[0] * k >= 2**31 else jnp.int32
    return jsafe.astype(dt) * k + rev.astype(dt)


def reverse_gather(a, jsafe, rev):
    """``a[j, rev[i, k]]`` for ``a[N, K, ...]`` (the value of the reverse pair) as a flat gather."""
    n, k = a.shape[:2]
    flat = a.reshape((n * k,) + a.shape[2:])
    return flat[flat_reverse_index(jsafe, rev, k)]


def columns(a, axis: int = -1):
    """``[a[..., c] for c in range(a.shape[axis])]`` (along ``axis``) as one split.

    The values are the same slices; what differs is reverse mode: the transpose of a split is one
    concatenate of the cotangents, where that of each separate index is a zero array of the whole
    shape plus an add, i.e. cost quadratic in the number of columns (docs/performance.md,
    "Gradients")."""
    axis = axis % a.ndim
    if a.shape[axis] == 0:
        return []
    return [jnp.squeeze(c, axis) for c in jnp.split(a, a.shape[axis], axis=axis)]
