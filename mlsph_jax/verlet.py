"""Verlet-skin neighbour lists for moving particles: rebuilt only when a particle has moved far
enough to matter, the stencil of every stage still exactly the list :func:`mlsph_jax.neighbors.update`
would build.

A *candidate* list is built with every reach enlarged by a skin ``s``: pairs with
``|r| < support max(h_i, h_j) + s`` at the reference positions ``x_ref`` and smoothing lengths
``h_ref`` (one :func:`~mlsph_jax.neighbors.update` with ``h_ref + s / support``).  While

    2 max_i |x_i - x_ref,i| + support max_i max(h_i - h_ref,i, 0)  <=  s

every pair of the current stencil, ``|r| < support max(h_i, h_j)``, is a candidate (triangle
inequality).  Each stage then *restricts* the candidates to the current stencil
(:func:`restrict`: the pair criterion of the neighbour kernel evaluated with the same
floating-point expression, kept slots compacted in their ascending order by one scatter, reverse
slots carried over through the prefix counts), which gives the list ``update`` would return at the current
positions, slot for slot: same indices, reverse slots, counts and capacity.  The right-hand
side therefore sees the same stencil in the same order, and the trajectory is the one of
per-stage rebuilds (tests/test_moving_particles.py).  The rebuild test runs inside ``jit``
(``lax.cond``); no host synchronisation.

Sizing (host, :func:`candidate_spec`): the skin is ``VERLET_SKIN`` times ``support max h``,
capped at build time (in ``jit``) by the room the cell size leaves, ``cell_size - support max h``
(so a skin never causes a reach overflow the plain list would not have), and the candidate
capacity is ``ceil(K (1 + VERLET_SKIN)^d)``.  Overflow stays detected: the restricted list sets
the row bit when a particle has more than K neighbours, and the bits of the candidate build
(row: more than ``K (1 + skin)^d`` candidates, cell, reach) are reported as they are, so the
driver regrows the named limit (the candidate capacity grows with K).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp

from . import neighbors as nb
from .state import minimum_image
from .stencil import flat_reverse_index

__all__ = ["VERLET_SKIN", "VerletList", "build", "candidate_spec", "refresh", "restrict", "stale"]

#: Skin of the candidate lists as a fraction of ``support * max(h)`` (at most the room the cell
#: size leaves).  At Taylor-Green's Courant number a skin of 0.3 lasts about ten steps.
VERLET_SKIN = 0.3

#: The rebuild test uses this fraction of the skin (the skin enters the candidate build as
#: ``support * (h + s / support)``, which may round below ``support * h + s``).
_SKIN_SAFETY = 0.99


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class VerletList:
    """Candidate list and what it was built from (a pytree carried through the stages)."""

    cand: nb.NeighborList
    x_ref: jax.Array
    h_ref: jax.Array
    skin: jax.Array


def candidate_spec(spec: nb.NeighborSpec, skin: float = VERLET_SKIN) -> nb.NeighborSpec:
    """The spec of the candidate lists: capacity ``ceil(K (1 + skin)^d)``, same cells."""
    return dataclasses.replace(spec, capacity=math.ceil(spec.capacity * (1.0 + skin) ** spec.dim))


def restrict(cand: nb.NeighborList, x, h, spec: nb.NeighborSpec) -> nb.NeighborList:
    """The list ``nb.update(x, h, spec)`` would build, from a candidate list that holds every
    neighbour of the current stencil (rows ascending).  Overflow bits: the row bit when a count
    exceeds ``spec.capacity``, else 0 (the caller adds the build's cell and reach bits)."""
    n, kv = cand.idx.shape
    k = spec.capacity
    g = nb._geometry(spec)
    self_i = jnp.arange(n, dtype=cand.idx.dtype)[:, None]
    jsafe = jnp.where(cand.mask, cand.idx, self_i)
    r2 = jnp.zeros(cand.idx.shape, x.dtype)
    for a in range(x.shape[1]):             # the expression of the neighbour kernel (bitwise)
        da = minimum_image(x[:, a][:, None] - x[:, a][jsafe], g["length"][a], g["periodic"][a])
        r2 = r2 + da * da
    cut = g["support"] * jnp.maximum(h[:, None], h[jsafe])
    keep = cand.mask & (r2 < cut * cut)
    pos = prefix_counts(keep) - 1                                   # slot in the compacted row
    count = pos[:, -1] + 1
    # one scatter of (index, reverse slot) pairs to flat slots i K + pos (dropped past the row)
    it = jnp.int64 if n * max(k, kv) >= 2**31 else jnp.int32
    target = jnp.where(keep & (pos < k), self_i.astype(it) * k + pos, n * k).reshape(-1)
    rev_new = pos.reshape(-1)[flat_reverse_index(jsafe, cand.rev, kv)]   # slot of i in j's compacted row
    payload = jnp.stack([cand.idx.reshape(-1), rev_new.reshape(-1).astype(cand.idx.dtype)], axis=-1)
    init = jnp.stack([jnp.full((n * k,), n, cand.idx.dtype), jnp.zeros((n * k,), cand.idx.dtype)], axis=-1)
    out = init.at[target].set(payload, mode="drop")
    idx, rev = out[:, 0].reshape(n, k), out[:, 1].reshape(n, k).astype(jnp.int32)
    bits = jnp.where(jnp.max(count) > k, nb.OVERFLOW_ROW, 0).astype(jnp.int32)
    return nb.NeighborList(idx=idx, mask=idx < n, rev=rev, count=count, overflow_bits=bits)


#: Columns per block of :func:`prefix_counts` (rows of up to twice this are one block).
PREFIX_BLOCK = 64


def prefix_counts(keep):
    """``cumsum(keep, axis=1)`` (int32) as matrix products of 0/1 values: within blocks of
    ``s`` columns, ``keep @ U`` with the upper-triangular ones ``U[s, s]``, plus the exclusive
    prefix of the block totals (a second product); one block when K <= 2 :data:`PREFIX_BLOCK`.
    Sums of at most K ones are exact in float32, so the counts are the integers of any order of
    summation.  Why products: inside :func:`restrict` XLA:CPU fused the pair test into every
    level of a ``lax.associative_scan`` (recomputing it log2 K times; 17 of 32 ms a call at
    Taylor-Green 100 x 100, K = 75 candidates), ``cumsum`` is a reduce-window of the row's full
    length and a chain of K column additions is duplicated into every output column, O(K^2)
    instructions (docs/performance.md).  A dot materialises its operand once, and costs
    K s multiply-adds per row."""
    n, kv = keep.shape
    if kv == 0:
        return jnp.zeros((n, 0), jnp.int32)
    s = kv if kv <= 2 * PREFIX_BLOCK else PREFIX_BLOCK
    nb_ = -(-kv // s)
    kf = keep.astype(jnp.float32)
    if nb_ > 1:
        kf = jnp.pad(kf, ((0, 0), (0, nb_ * s - kv)))
    kf = kf.reshape(n, nb_, s)
    exact = jax.lax.Precision.HIGHEST   # full float32 products on GPUs/TPUs too (no TF32/bf16 passes)
    inner = jnp.einsum("nbs,st->nbt", kf, jnp.triu(jnp.ones((s, s), jnp.float32)), precision=exact)
    if nb_ > 1:     # + the counts of the earlier blocks
        inner = inner + jnp.einsum("nb,bc->nc", inner[..., -1],
                                   jnp.triu(jnp.ones((nb_, nb_), jnp.float32), 1), precision=exact)[..., None]
    return inner.reshape(n, nb_ * s)[:, :kv].astype(jnp.int32)


def build(x, h, spec: nb.NeighborSpec, cspec: nb.NeighborSpec, skin_fraction: float = VERLET_SKIN) -> VerletList:
    """Candidate list at ``x`` with the skin ``skin_fraction support max h`` (capped by the cell
    room)."""
    s = spec.support
    hmax = jnp.max(h)
    skin = jnp.clip(jnp.minimum(skin_fraction * s * hmax, _SKIN_SAFETY * (spec.cell_size - s * hmax)), 0.0, None)
    return VerletList(nb.update(x, h + skin / s, cspec), x, h, skin)


def stale(x, h, cspec: nb.NeighborSpec) -> VerletList:
    """A state that :func:`refresh` rebuilds at its first call (negative skin): lets a loop build
    its first candidate list inside the loop body, so that the neighbour kernel is compiled once."""
    n = x.shape[0]
    zero = jnp.zeros((n, cspec.capacity), jnp.int32)
    cand = nb.NeighborList(idx=zero, mask=zero > 0, rev=zero, count=jnp.zeros(n, jnp.int32),
                           overflow_bits=jnp.zeros((), jnp.int32))
    return VerletList(cand, x, h, -jnp.ones((), x.dtype))


def refresh(v: VerletList, x, h, spec: nb.NeighborSpec, cspec: nb.NeighborSpec,
            skin_fraction: float = VERLET_SKIN) -> tuple[nb.NeighborList, VerletList]:
    """``(list of the current stencil, candidate state)``: the candidates rebuilt first if a
    particle moved (or its reach grew) by more than the skin allows (module docstring)."""
    disp = jnp.sqrt(jnp.max(jnp.sum((x - v.x_ref) ** 2, axis=1)))
    grow = spec.support * jnp.max(jnp.maximum(h - v.h_ref, 0.0))
    stale = 2.0 * disp + grow > _SKIN_SAFETY * v.skin
    v = jax.lax.cond(stale, lambda: build(x, h, spec, cspec, skin_fraction), lambda: v)
    nl = restrict(v.cand, x, h, spec)
    bits = nl.overflow_bits | v.cand.overflow_bits   # (a candidate row overflow: regrow, although K may suffice)
    return dataclasses.replace(nl, overflow_bits=bits.astype(jnp.int32)), v
