"""O(N) fixed-capacity neighbour lists (cell lists by hashing and sorting) in JAX.

Pair criterion
--------------
Every particle carries a smoothing length ``h_i`` (callers use ``h_i = beta * V_i**(1/d)``).
The neighbour relation is *symmetric*::

    j in list(i)  <=>  |r_ij| < support * max(h_i, h_j)        (strictly less)

with ``r_ij`` the minimum-image separation on periodic axes (:func:`mlsph_jax.state.minimum_image`)
and ``support`` the kernel support factor (2 for the cubic spline).  Every particle is its own
neighbour.  Hence ``j in list(i) <=> i in list(j)``.

Algorithm (hashing by sorting, no dense grid)
---------------------------------------------
1. Integer cell coordinates ``c[i, a]`` with cell width ``w_a >= cell_size >= support * max h``.
   Non-periodic axes: ``w_a = cell_size``, ``c = floor((x - lower) / w_a)`` clamped into
   ``[0, n_a)`` (clamping is non-expansive, so particles outside the bounds are still handled
   exactly; they only crowd the boundary cells).  Periodic axes: ``n_a = max(1, floor(L_a /
   cell_size))`` cells of width ``L_a / n_a`` and coordinates wrapped modulo ``n_a``.
2. A linear int64 cell id ``sum_a c_a * stride_a``.  The cell grid is never materialised: the
   ids are merely sort keys, so a 1D tube, a long thin channel or a sparse cloud in a huge box
   cost the same as a compact block.  (If the per-axis cell counts would overflow int64 the
   non-periodic coordinates are folded modulo ``2**(61 // d)``, i.e. a spatial hash; collisions
   only add far-away candidates that fail the distance test, so results stay exact.)
3. ``argsort`` of the ids; particles are then processed in this cell-sorted order (locality),
   and the members of every cell are contiguous in the sorted copies of ``x``, ``h`` and the
   particle index (structure of arrays).
4. For every particle and each static neighbour-cell offset (``3**d`` of them; only 0 on a
   non-periodic axis with one cell, and the de-duplicated set ``range(n_a)`` on a periodic
   axis with 1 or 2 cells so that no cell is visited twice), ``jnp.searchsorted`` finds the
   start of that cell in the sorted id array and a run-end table its length.  One contiguous
   window of ``cell_capacity`` members per cell is read (``dynamic_slice``) as candidates and
   tested against the pair criterion.
5. Hits are compacted into ``capacity`` (K) slots without a long prefix sum: the window is cut
   into 32-bit words whose bit masks give in-word ranks by ``population_count``, and a short
   prefix sum over the words gives the output slot.  Each row is sorted (K entries), padded
   with ``N``, and the rows are permuted back to input order.
6. The reverse-slot map ``rev[i, k]`` (slot of ``i`` in row ``idx[i, k]``) by a vectorised
   binary search in the sorted rows (``searchsorted`` semantics, O(N K log K)).

Complexity: time O(N log N + N 3**d (log N + C) + N K log K) with C = ``cell_capacity``, i.e.
linear in N up to the sort; memory O(N K) plus a batch buffer of ``batch * 3**d * C``
candidates: particles are processed in batches (a ``lax.scan`` over ``vmap``-ed batches, like
``jax.lax.map(..., batch_size=...)``; ``NeighborSpec.batch_size``), which bounds the buffer.
Nothing is ever sized by the box volume.

Allocation versus update
------------------------
Shapes must be static under ``jit``, so sizing happens on the host in :func:`allocate` (and
:func:`grow`) and produces a hashable :class:`NeighborSpec`.  :func:`update` is pure and
jit-able with the spec static (``jax.jit(update, static_argnames="spec")``), performs no host
synchronisation and never fails silently: ``NeighborList.overflow`` is set when a row needs more
than K slots, a cell holds more than ``cell_capacity`` particles, or some ``support * h_i``
exceeds ``cell_size``; ``NeighborList.overflow_bits`` says which (:data:`OVERFLOW_ROW`,
:data:`OVERFLOW_CELL`, :data:`OVERFLOW_REACH`), so a caller can grow the right limit.
:func:`update_or_grow` is the host helper that regrows and retries.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np

from .errors import InputError, NeighborOverflowError
from .state import Domain, minimum_image

__all__ = [
    "OVERFLOW_CELL",
    "OVERFLOW_REACH",
    "OVERFLOW_ROW",
    "NeighborList",
    "NeighborSpec",
    "allocate",
    "brute_force",
    "grow",
    "overflow_causes",
    "plan",
    "update",
    "update_jit",
    "update_or_grow",
]

#: Relative enlargement of the automatically chosen cell size over ``support * max(h)``; with
#: an absolute term proportional to the coordinate magnitude (see :func:`_auto_cell_size`) it
#: guards "pairs closer than the cell size lie in adjacent cells" against round-off.
_CELL_MARGIN = 1e-8
#: Candidate slots (particles x offsets x cell capacity) per batch of the kernel; small enough
#: for the batch buffers to stay cache resident (measured: 256-512 particles per batch in 3D).
_CANDIDATE_BUDGET = 1 << 19
#: Entries (rows x K) per batch of the reverse-slot search.
_REV_BUDGET = 1 << 16
#: Below this many candidate pairs allocation counts neighbours with numpy (no compilation);
#: above, with the compiled counting kernel.
_HOST_PAIRS = 1 << 22
#: Largest cell count per non-periodic axis before clamping (exact integers in float64).
_MAX_AXIS_CELLS = 1 << 52


def _axis_cap(d: int) -> int:
    """Per-axis bound on hashed cell coordinates so that linear ids fit in int64."""
    return 1 << (61 // d)


@dataclasses.dataclass(frozen=True)
class NeighborSpec:
    """Static (hashable) sizes and geometry of a neighbour list; a static ``jit`` argument.

    Attributes:
        capacity: K, neighbour slots per particle (self included).
        cell_capacity: C, members gathered per visited cell.
        cell_size: lower bound of the cell width; must be >= ``support * max(h)``.
        n_cells: cells per axis (periodic: ``max(1, floor(L / cell_size))``, capped so ids fit
            int64; non-periodic: ``max(1, ceil(L / cell_size))``).
        lower, upper, periodic: the domain box (see :class:`mlsph_jax.state.Domain`).
        support: kernel support factor; pairs need ``|r| < support * max(h_i, h_j)``.
        batch_size: particles per ``lax.map`` batch, ``None`` for a single ``vmap``.
    """

    capacity: int
    cell_capacity: int
    cell_size: float
    n_cells: tuple[int, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    periodic: tuple[bool, ...]
    support: float
    batch_size: int | None

    def __post_init__(self):
        d = len(self.n_cells)
        if not (d in (1, 2, 3) and len(self.lower) == len(self.upper) == len(self.periodic) == d):
            raise InputError(f"invalid NeighborSpec geometry n_cells={self.n_cells}, lower="
                             f"{self.lower}, upper={self.upper}, periodic={self.periodic}; "
                             "allowed: tuples of equal length 1..3")
        for name in ("capacity", "cell_capacity"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < 1:
                raise InputError(f"invalid {name}={v!r}; allowed: an integer >= 1")
        if any(int(n) < 1 for n in self.n_cells):
            raise InputError(f"invalid n_cells={self.n_cells}; allowed: integers >= 1")
        if not (math.isfinite(self.cell_size) and self.cell_size > 0):
            raise InputError(f"invalid cell_size={self.cell_size!r}; allowed: a finite number > 0")
        if not (math.isfinite(self.support) and self.support > 0):
            raise InputError(f"invalid support={self.support!r}; allowed: a finite number > 0")
        b = self.batch_size
        if b is not None and (isinstance(b, bool) or not isinstance(b, int | np.integer) or b < 1):
            raise InputError(f"invalid batch_size={self.batch_size!r}; allowed: None or an "
                             "integer >= 1")

    @property
    def dim(self) -> int:
        return len(self.n_cells)

    @property
    def domain(self) -> Domain:
        return Domain(self.lower, self.upper, self.periodic)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class NeighborList:
    """Fixed-capacity neighbour list (a pytree).

    Attributes:
        idx: ``[N, K]`` int32 neighbour indices, each row ascending, padded with ``N``.
        mask: ``[N, K]`` bool, ``idx < N``.
        rev: ``[N, K]`` int32 reverse slots: ``idx[idx[i, k], rev[i, k]] == i`` for valid
            entries, 0 on padding.
        count: ``[N]`` int32 true number of neighbours (self included); may exceed K (then
            ``overflow`` is set).  A lower bound if a cell overflowed.
        overflow_bits: scalar int32 array, the causes of an overflow as bits
            (:data:`OVERFLOW_ROW` | :data:`OVERFLOW_CELL` | :data:`OVERFLOW_REACH`), 0 if the list
            is complete.

    ``overflow`` (scalar bool array, ``overflow_bits != 0``): the list is incomplete and must be
    regrown; the bits say which limit to grow.
    """

    idx: jax.Array
    mask: jax.Array
    rev: jax.Array
    count: jax.Array
    overflow_bits: jax.Array

    @property
    def overflow(self) -> jax.Array:
        return self.overflow_bits != 0


#: ``NeighborList.overflow_bits``: a particle has more neighbours than ``capacity`` (K).
OVERFLOW_ROW = 1
#: ``NeighborList.overflow_bits``: a cell holds more particles than ``cell_capacity``.
OVERFLOW_CELL = 2
#: ``NeighborList.overflow_bits``: some support radius ``support * h_i`` exceeds ``cell_size``.
OVERFLOW_REACH = 4


def overflow_causes(bits: int) -> list[str]:
    """Names of the spec limits an ``overflow_bits`` value exceeded (host side)."""
    bits = int(bits)
    return [name for bit, name in ((OVERFLOW_ROW, "capacity"), (OVERFLOW_CELL, "cell_capacity"),
                                   (OVERFLOW_REACH, "cell_size")) if bits & bit]


# --------------------------------------------------------------------------------------------
# geometry derived from a spec (shared by the numpy sizing pass and the JAX kernel)
# --------------------------------------------------------------------------------------------

def _n_cells(domain: Domain, cell_size: float) -> tuple[int, ...]:
    cap = _axis_cap(domain.dim)
    out = []
    for a, L in enumerate(domain.length):
        r = L / cell_size
        if domain.periodic[a]:
            out.append(int(max(1, min(math.floor(r), cap))) if math.isfinite(r) else cap)
        else:
            out.append(int(max(1, math.ceil(r))) if r < _MAX_AXIS_CELLS else _MAX_AXIS_CELLS)
    return tuple(out)


@functools.lru_cache(maxsize=256)
def _geometry(spec: NeighborSpec) -> dict[str, np.ndarray]:
    """Cell-grid description of ``spec`` as small read-only numpy arrays.

    ``width``/``n``: cell width and count per axis (coordinates live in ``[0, n)``);
    ``m``: hash modulus per axis (``n`` unless a huge non-periodic axis is folded);
    ``strides``: linear-id strides; ``offsets[n_off, d]``: the de-duplicated static
    neighbour-cell offsets, ``zero`` the row of the zero offset.
    """
    d = spec.dim
    cap = _axis_cap(d)
    length = np.array([u - lo for lo, u in zip(spec.lower, spec.upper, strict=True)], np.float64)
    n = np.array(spec.n_cells, np.int64)
    per = np.array(spec.periodic, bool)
    width = np.where(per, length / n, spec.cell_size)
    m = np.where(per, n, np.minimum(n, cap))
    strides = np.ones(d, np.int64)
    for a in range(d - 2, -1, -1):
        strides[a] = strides[a + 1] * m[a + 1]
    per_axis = []
    for a in range(d):
        if per[a]:
            per_axis.append(tuple(range(n[a])) if n[a] < 3 else (-1, 0, 1))
        else:
            per_axis.append((0,) if n[a] == 1 else (-1, 0, 1))
    offsets = np.array(list(itertools.product(*per_axis)), np.int64).reshape(-1, d)
    geo = dict(lower=np.array(spec.lower, np.float64), length=length, width=width, n=n, m=m,
               strides=strides, periodic=per, offsets=offsets,
               zero=np.array(np.flatnonzero((offsets == 0).all(axis=1))[0], np.int32),
               support=np.array(spec.support, np.float64),
               cell_size=np.array(spec.cell_size, np.float64))
    for v in geo.values():
        v.flags.writeable = False
    return geo


def _cell_coords(x, g, xp):
    """Integer cell coordinates ``[N, d]`` in ``[0, n)`` (int64); ``xp`` is numpy or jnp."""
    s = x - g["lower"]
    L = g["length"]
    s = xp.where(g["periodic"], s - L * xp.floor(s / L), s)
    c = xp.clip(xp.floor(s / g["width"]), 0, g["n"] - 1)
    return c.astype(xp.int64)


def _linear_ids(c, g, xp):
    """Linear (hashed) ids of cell coordinates ``c[..., d]`` that may lie one cell outside
    ``[0, n)``: periodic axes wrap, out-of-range non-periodic cells get id -1 (empty)."""
    inside = (c >= 0) & (c < g["n"])
    valid = xp.all(g["periodic"] | inside, axis=-1)
    lin = xp.sum(xp.mod(c, g["m"]) * g["strides"], axis=-1)
    return xp.where(valid, lin, -1)


# --------------------------------------------------------------------------------------------
# the jit-able kernel
# --------------------------------------------------------------------------------------------

def _word_layout(cell_capacity: int) -> tuple[int, int]:
    """Split the ``cell_capacity`` slots of a cell into ``nw`` bit words of ``wd <= 32`` slots
    (``nw * wd >= cell_capacity``, as few padding slots as possible)."""
    nw = -(-cell_capacity // 32)
    return nw, -(-cell_capacity // nw)


def _rows(x, h, g, cell_capacity: int, capacity: int | None, batch_size: int | None):
    """Candidate search, distance test and compaction for all particles.

    Particles are processed in cell-sorted order (good locality).  The members of a cell are
    contiguous in the sorted arrays, so the candidates of each visited cell are read as one
    window (``dynamic_slice``) from structure-of-arrays copies of ``x`` and ``h``.  Hits are
    compacted without a long prefix sum: each cell window is split into 32-bit words whose
    bit masks give in-word ranks by ``population_count``; an exclusive sum over the (few) words
    gives the output slots, and a scatter places the hits.  Rows are then sorted (K entries)
    and returned in input order.

    Returns ``(idx [N, K], count [N], own-cell occupancy [N])``; with ``capacity=None`` only
    the counts are computed and ``idx`` is ``None``.
    """
    n, d = x.shape
    K = capacity
    nw, wd = _word_layout(cell_capacity)
    Cw = nw * wd
    n_off = g["offsets"].shape[0]
    coords = _cell_coords(x, g, jnp)
    ids = _linear_ids(coords, g, jnp)
    order = jnp.argsort(ids, stable=True).astype(jnp.int32)
    sorted_ids = ids[order]
    sorted_coords = coords[order]
    # run_end[p]: one past the last sorted position holding the id sorted_ids[p]
    is_last = jnp.concatenate([sorted_ids[1:] != sorted_ids[:-1], jnp.ones(1, bool)])
    run_end = jax.lax.cummin(jnp.where(is_last, jnp.arange(1, n + 1, dtype=jnp.int32), n),
                             reverse=True)

    def padded(a, fill):  # sorted copy with Cw trailing pad entries so windows never clamp
        return jnp.concatenate([a[order], jnp.full(Cw, fill, a.dtype)])

    cols = [padded(x[:, a], 0.0) for a in range(d)]
    hs = padded(h, 0.0)
    js = padded(jnp.arange(n, dtype=jnp.int32), n)
    slot = jnp.arange(Cw, dtype=jnp.int32)
    bit = jnp.arange(wd, dtype=jnp.uint32)
    below = (jnp.uint32(1) << bit) - jnp.uint32(1)             # mask of the lower bits
    # earlier[w, w'] = w' < w: exclusive prefix sum over the few words as a masked sum
    # (a cumsum lowers to a reduce-window that is slow to compile on CPU)
    earlier = np.tri(n_off * nw, k=-1, dtype=bool)
    periodic = g["periodic"]
    length = g["length"]

    def one(p):
        nid = _linear_ids(sorted_coords[p] + g["offsets"], g, jnp)              # [n_off]
        start = jnp.searchsorted(sorted_ids, nid).astype(jnp.int32)
        sc = jnp.minimum(start, n - 1)
        cnt = jnp.where(sorted_ids[sc] == nid, run_end[sc] - start, 0)          # [n_off]

        def window(a):
            return jax.vmap(lambda s: jax.lax.dynamic_slice_in_dim(a, s, Cw))(start)

        r2 = jnp.zeros((n_off, Cw), x.dtype)
        for a in range(d):
            # minimum image on periodic axes (identity elsewhere; applied unconditionally so
            # that one compiled kernel serves every combination of periodic axes)
            da = minimum_image(cols[a][p] - window(cols[a]), length[a], periodic[a])
            r2 = r2 + da * da
        cut = g["support"] * jnp.maximum(hs[p], window(hs))
        hit = ((slot < cnt[:, None]) & (r2 < cut * cut)).reshape(n_off * nw, wd)
        word = jnp.sum(hit.astype(jnp.uint32) << bit, axis=1, dtype=jnp.uint32)
        in_word = jax.lax.population_count(word).astype(jnp.int32)             # [n_off*nw]
        if K is None:
            return jnp.sum(in_word, dtype=jnp.int32), cnt[g["zero"]]
        first = jnp.sum(jnp.where(earlier, in_word, 0), axis=1)                 # exclusive
        rank = first[:, None] + jax.lax.population_count(word[:, None] & below).astype(jnp.int32)
        target = jnp.where(hit, rank, K).reshape(-1)
        row = jnp.full(K, n, jnp.int32).at[target].set(window(js).reshape(-1), mode="drop")
        return jnp.sort(row), jnp.sum(in_word, dtype=jnp.int32), cnt[g["zero"]]

    out = _batched(one, n, batch_size)
    inv = jnp.zeros(n, jnp.int32).at[order].set(jnp.arange(n, dtype=jnp.int32),
                                                 unique_indices=True)
    out = tuple(a[inv] for a in out)
    return out if K is not None else (None, *out)


def _rev_batch(n: int, capacity: int, batch_size: int | None) -> int | None:
    """Rows per batch of the reverse-slot search (cache-sized), ``None`` if unbatched."""
    if batch_size is None:
        return None
    b = max(1, _REV_BUDGET // capacity)
    return None if b >= n else b


def _batched(f, n: int, batch_size: int | None):
    """``vmap(f)(arange(n))`` evaluated ``batch_size`` indices at a time (a ``lax.scan`` over
    batches, like ``lax.map(..., batch_size=...)`` but without a separately compiled remainder:
    the last batch repeats index ``n - 1`` and the surplus is dropped)."""
    if batch_size is None or batch_size >= n:
        return jax.vmap(f)(jnp.arange(n, dtype=jnp.int32))
    nb = -(-n // batch_size)
    lane = jnp.arange(batch_size, dtype=jnp.int32)

    def body(carry, b):
        return carry, jax.vmap(f)(jnp.minimum(b * batch_size + lane, n - 1))

    _, out = jax.lax.scan(body, None, jnp.arange(nb, dtype=jnp.int32))
    return jax.tree_util.tree_map(lambda a: a.reshape(nb * batch_size, *a.shape[2:])[:n], out)


def _reverse_slots(idx: jax.Array, n: int, batch_size: int | None) -> jax.Array:
    """``rev[i, k]`` = slot of ``i`` in row ``j = idx[i, k]``: a vectorised lower-bound binary
    search in the sorted rows (``searchsorted(idx[j], i)`` without materialising ``idx[j]``),
    O(N K log K) time, O(N K) memory, rows processed in batches of ``batch_size``.  0 on padding
    (and where ``i`` is absent from row ``j``, which only happens after an overflow)."""
    K = idx.shape[1]
    flat = idx.reshape(-1)

    def one(i):
        row = idx[i]
        valid = row < n
        base = jnp.where(valid, row, 0).astype(jnp.int64) * K  # N * K may exceed int32

        def step(_, lohi):
            lo, hi = lohi
            mid = (lo + hi) // 2
            right = flat[base + jnp.minimum(mid, K - 1)] < i
            return jnp.where(right, jnp.minimum(mid + 1, hi), lo), jnp.where(right, hi, mid)

        lo, _ = jax.lax.fori_loop(0, max(1, math.ceil(math.log2(K + 1))), step,
                                  (jnp.zeros(K, jnp.int32), jnp.full(K, K, jnp.int32)),
                                  unroll=True)
        hit = valid & (lo < K) & (flat[base + jnp.minimum(lo, K - 1)] == i)
        return jnp.where(hit, lo, 0).astype(jnp.int32)

    return _batched(one, idx.shape[0], batch_size)


@functools.partial(jax.jit, static_argnames=("capacity", "cell_capacity", "batch_size"))
def _update_kernel(x, h, g, *, capacity: int, cell_capacity: int,
                   batch_size: int | None) -> NeighborList:
    n = x.shape[0]
    idx, count, occ = _rows(x, h, g, cell_capacity, capacity, batch_size)
    bits = (jnp.where(jnp.max(count) > capacity, OVERFLOW_ROW, 0)
            | jnp.where(jnp.max(occ) > cell_capacity, OVERFLOW_CELL, 0)
            | jnp.where(jnp.any(g["support"] * h > g["cell_size"]), OVERFLOW_REACH, 0)).astype(jnp.int32)
    rev = _reverse_slots(idx, n, _rev_batch(n, capacity, batch_size))
    return NeighborList(idx=idx, mask=idx < n, rev=rev, count=count, overflow_bits=bits)


def update(x: jax.Array, h: jax.Array, spec: NeighborSpec) -> NeighborList:
    """Build the neighbour list of positions ``x[N, d]`` with smoothing lengths ``h[N]``.

    Pure and jit-able with ``spec`` static: ``jax.jit(update, static_argnames="spec")`` (also
    available as :data:`update_jit`).  Called outside ``jit`` it runs a compiled kernel that is
    cached by array shapes and ``(capacity, cell_capacity, batch_size)`` only, so specs that
    differ in cell size or box reuse it.  Output shapes are fixed, ``[N, spec.capacity]``; no
    host synchronisation and no input validation (use :func:`update_or_grow` for that).
    Always check ``overflow``: when set, a row, a cell or a support radius exceeded the spec
    and the list is incomplete.
    """
    x = jnp.asarray(x, float)
    return _update_kernel(x, jnp.asarray(h, x.dtype), _geometry(spec), capacity=spec.capacity,
                          cell_capacity=spec.cell_capacity, batch_size=spec.batch_size)


#: ``jax.jit(update, static_argnames="spec")``.
update_jit = jax.jit(update, static_argnames="spec")


def cell_candidates(points: jax.Array, x: jax.Array, spec: NeighborSpec) -> tuple[jax.Array, jax.Array]:
    """Particles in the cells around query points (walls, probes): ``(cand[Nb, n_off * C],
    complete[Nb])``.

    ``cand[b]`` lists, ascending and padded with ``N``, every particle of ``x[N, d]`` in the
    (de-duplicated, periodic-wrapped) ``3**d`` cells around ``points[b]`` on the grid of ``spec``
    (``C = spec.cell_capacity``; ``spec.capacity`` is not used).  Every particle within
    ``spec.cell_size`` of a point is among its candidates as long as ``complete[b]`` (no visited
    cell holds more than ``C`` particles).  Jit-able with ``spec`` static; O((N + Nb) log N).
    """
    g = _geometry(spec)
    n = x.shape[0]
    C = spec.cell_capacity
    ids = _linear_ids(_cell_coords(x, g, jnp), g, jnp)
    order = jnp.argsort(ids, stable=True).astype(jnp.int32)
    sorted_ids = ids[order]
    js = jnp.concatenate([order, jnp.full(C, n, jnp.int32)])
    nid = _linear_ids(_cell_coords(points, g, jnp)[:, None, :] + g["offsets"], g, jnp)   # [Nb, n_off]
    start = jnp.searchsorted(sorted_ids, nid, side="left").astype(jnp.int32)
    end = jnp.searchsorted(sorted_ids, nid, side="right").astype(jnp.int32)
    cnt = jnp.where(nid >= 0, end - start, 0)
    slot = jnp.arange(C, dtype=jnp.int32)
    cand = jnp.where(slot < cnt[..., None], js[start[..., None] + slot], n)             # [Nb, n_off, C]
    return jnp.sort(cand.reshape(cand.shape[0], -1), axis=-1), jnp.all(cnt <= C, axis=-1)



# --------------------------------------------------------------------------------------------
# host side: validation, sizing, regrowth
# --------------------------------------------------------------------------------------------

def _check_xh(x, h, dim: int) -> tuple[np.ndarray, np.ndarray]:
    """Validate positions and smoothing lengths on the host; return float64 numpy copies."""
    xa = np.asarray(x)
    if xa.ndim != 2 or xa.shape[1] != dim or xa.shape[0] < 1:
        raise InputError(f"invalid x with shape {xa.shape}; allowed: an array of shape (N, {dim}) "
                         f"with N >= 1 (the domain has dimension {dim})")
    if not (np.issubdtype(xa.dtype, np.floating) or np.issubdtype(xa.dtype, np.integer)):
        raise InputError(f"invalid x of dtype {xa.dtype}; allowed: real numbers")
    xa = xa.astype(np.float64)
    bad = np.flatnonzero(~np.isfinite(xa).all(axis=1))
    if bad.size:
        raise InputError(f"non-finite x at particle {int(bad[0])} (x={xa[bad[0]].tolist()}, "
                         f"{bad.size} particles); allowed: finite positions")
    n = xa.shape[0]
    ha = np.asarray(h)
    if ha.shape != (n,):
        raise InputError(f"invalid h with shape {ha.shape}; allowed: shape ({n},), one smoothing "
                         "length per particle")
    if not (np.issubdtype(ha.dtype, np.floating) or np.issubdtype(ha.dtype, np.integer)):
        raise InputError(f"invalid h of dtype {ha.dtype}; allowed: real numbers")
    ha = ha.astype(np.float64)
    bad = np.flatnonzero(~(np.isfinite(ha) & (ha > 0)))
    if bad.size:
        raise InputError(f"invalid h={float(ha[bad[0]])!r} at particle {int(bad[0])} "
                         f"({bad.size} particles); allowed: finite values > 0")
    return xa, ha


def _check_number(name: str, value, minimum: float, strict: bool) -> float:
    allowed = f"allowed: a finite number {'>' if strict else '>='} {minimum}"
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"invalid {name}={value!r}; {allowed}") from None
    if not math.isfinite(v) or (v <= minimum if strict else v < minimum):
        raise InputError(f"invalid {name}={value!r}; {allowed}")
    return v


def _batch_size(n: int, n_off: int, cell_capacity: int) -> int | None:
    b = max(1, _CANDIDATE_BUDGET // (n_off * cell_capacity))
    return None if b >= n else int(b)


@functools.partial(jax.jit, static_argnames=("cell_capacity", "batch_size"))
def _count_kernel(x, h, g, *, cell_capacity: int, batch_size: int | None):
    _, count, occ = _rows(x, h, g, cell_capacity, None, batch_size)
    return count, occ


def measure(xa: np.ndarray, ha: np.ndarray, spec: NeighborSpec) -> tuple[np.ndarray, int]:
    """Exact neighbour counts and the maximum cell occupancy of a configuration (host side).

    The cell occupancy comes from numpy.  Counts too: a numpy cell-list pass when there are
    few candidate pairs (no compilation, the common case in tests and small runs), else the
    compiled counting kernel with ``cell_capacity`` equal to the measured occupancy.
    """
    g = _geometry(spec)
    n = xa.shape[0]
    coords = _cell_coords(xa, g, np)
    ids = _linear_ids(coords, g, np)
    order = np.argsort(ids, kind="stable")
    cells, first, occ = np.unique(ids[order], return_index=True, return_counts=True)
    max_occ = int(occ.max())
    # start / length of every visited cell, per (particle, offset)
    nid = _linear_ids(coords[:, None, :] + g["offsets"][None, :, :], g, np)    # [N, n_off]
    k = np.minimum(np.searchsorted(cells, nid), cells.size - 1)
    cnt = np.where(cells[k] == nid, occ[k], 0)
    total = int(cnt.sum())
    if total > _HOST_PAIRS:
        count, _ = _count_kernel(jnp.asarray(xa), jnp.asarray(ha), g, cell_capacity=max_occ,
                                 batch_size=_batch_size(n, len(g["offsets"]), max_occ))
        return np.asarray(count).astype(np.int64), max_occ
    cnt, start = cnt.reshape(-1), first[k].reshape(-1)
    ii = np.repeat(np.repeat(np.arange(n), len(g["offsets"])), cnt)
    within = np.arange(total) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    j = order[np.repeat(start, cnt) + within]
    dx = xa[ii] - xa[j]
    L = g["length"]
    dx = np.where(g["periodic"], dx - L * np.round(dx / L), dx)
    cut = spec.support * np.maximum(ha[ii], ha[j])
    hit = np.sum(dx * dx, axis=-1) < cut * cut
    return np.bincount(ii[hit], minlength=n), max_occ


def _auto_cell_size(need: float, xa: np.ndarray, domain: Domain) -> float:
    """``support * max(h)`` enlarged by a relative margin and by a multiple of the round-off of
    the cell coordinates ``(x - lower) / w`` (which grows with the coordinate magnitude)."""
    span = max(max(domain.length), float(np.max(np.abs(xa - np.asarray(domain.lower)))))
    return need * (1.0 + _CELL_MARGIN) + 16.0 * float(np.finfo(np.float64).eps) * span


def _size(xa: np.ndarray, ha: np.ndarray, domain: Domain, support: float, headroom: float,
          cell_size: float, capacity: int | None, min_capacity: int = 1,
          min_cell_capacity: int = 1) -> NeighborSpec:
    """Measure occupancy and neighbour counts of the configuration and size a spec."""
    n = xa.shape[0]
    spec = NeighborSpec(capacity=1, cell_capacity=1, cell_size=float(cell_size),
                        n_cells=_n_cells(domain, cell_size),
                        lower=tuple(float(v) for v in domain.lower),
                        upper=tuple(float(v) for v in domain.upper),
                        periodic=tuple(bool(p) for p in domain.periodic),
                        support=float(support), batch_size=None)
    count, occ = measure(xa, ha, spec)
    C = min(n, max(min_cell_capacity, math.ceil(occ * headroom)))
    if capacity is None:
        capacity = min(n, max(min_capacity, math.ceil(int(count.max()) * headroom)))
    return dataclasses.replace(spec, capacity=int(capacity), cell_capacity=int(C),
                               batch_size=_batch_size(n, len(_geometry(spec)["offsets"]), C))


def plan(x, h, domain: Domain, support: float = 2.0, headroom: float = 1.3,
         capacity: int | None = None, cell_size: float | None = None) -> NeighborSpec:
    """Size a :class:`NeighborSpec` for the configuration ``(x, h)`` without building a list.

    Host side (numpy; not jit-able).  ``cell_size`` defaults to ``support * max(h) * (1 +
    1e-8)``; pass a larger value so that particles may move and ``h`` grow without regrowth.
    ``cell_capacity = ceil(max cell occupancy * headroom)`` and, unless ``capacity`` is given,
    ``capacity = ceil(max neighbour count * headroom)``; both are at most N.

    Raises :class:`InputError` for non-finite positions, ``h <= 0`` or non-finite, shape or
    dimension mismatches with ``domain``, and invalid ``support``, ``headroom``, ``capacity``
    or ``cell_size``.
    """
    if not isinstance(domain, Domain):
        raise InputError(f"invalid domain={domain!r}; allowed: a mlsph_jax.state.Domain")
    xa, ha = _check_xh(x, h, domain.dim)
    support = _check_number("support", support, 0.0, strict=True)
    headroom = _check_number("headroom", headroom, 1.0, strict=False)
    if capacity is not None:
        if isinstance(capacity, bool) or not isinstance(capacity, int | np.integer) or capacity < 1:
            raise InputError(f"invalid capacity={capacity!r}; allowed: None or an integer >= 1")
        capacity = int(capacity)
    need = support * float(ha.max())
    if cell_size is None:
        cs = _auto_cell_size(need, xa, domain)
    else:
        cs = _check_number("cell_size", cell_size, 0.0, strict=True)
        if cs < need:
            raise InputError(f"invalid cell_size={cell_size!r}; allowed: >= support * max(h) = "
                             f"{need!r}")
    return _size(xa, ha, domain, support, headroom, cs, capacity)


def allocate(x, h, domain: Domain, support: float = 2.0, headroom: float = 1.3,
             capacity: int | None = None,
             cell_size: float | None = None) -> tuple[NeighborSpec, NeighborList]:
    """Size a :class:`NeighborSpec` for ``(x, h)`` (see :func:`plan`) and build the first list.

    Host side.  Returns ``(spec, update(x, h, spec))``; check ``overflow`` if ``capacity`` was
    given explicitly.  Raises :class:`InputError` for bad input (see :func:`plan`).
    """
    spec = plan(x, h, domain, support=support, headroom=headroom, capacity=capacity,
                cell_size=cell_size)
    return spec, update(np.asarray(x, np.float64), np.asarray(h, np.float64), spec)


def grow(spec: NeighborSpec, x, h, headroom: float = 1.3) -> NeighborSpec:
    """Host side: a new spec sized from the current configuration (with ``headroom``).

    Never shrinks: capacities and cell size are at least those of ``spec``.
    """
    xa, ha = _check_xh(x, h, spec.dim)
    headroom = _check_number("headroom", headroom, 1.0, strict=False)
    cs = max(spec.cell_size, _auto_cell_size(spec.support * float(ha.max()), xa, spec.domain))
    return _size(xa, ha, spec.domain, spec.support, headroom, cs, None,
                 min_capacity=spec.capacity, min_cell_capacity=spec.cell_capacity)


def update_or_grow(x, h, spec: NeighborSpec, max_tries: int = 3,
                   headroom: float = 1.3) -> tuple[NeighborSpec, NeighborList]:
    """Host helper: validate the input, :func:`update`, and on overflow :func:`grow` and redo.

    Returns the (possibly new) spec and a list without overflow.  Raises :class:`InputError`
    for bad input and :class:`NeighborOverflowError` (naming counts and capacities) if the list
    still overflows after ``max_tries`` regrowths.
    """
    xa, ha = _check_xh(x, h, spec.dim)
    nl = update(xa, ha, spec)
    for _ in range(max_tries):
        if not bool(nl.overflow):
            return spec, nl
        spec = grow(spec, xa, ha, headroom=headroom)
        nl = update(xa, ha, spec)
    if not bool(nl.overflow):
        return spec, nl
    _, occ = measure(xa, ha, spec)
    raise NeighborOverflowError(
        f"neighbour list still overflows after {max_tries} regrowths: max count "
        f"{int(np.max(np.asarray(nl.count)))} vs capacity={spec.capacity}, max cell occupancy "
        f"{occ} vs cell_capacity={spec.cell_capacity}, support*max(h)="
        f"{spec.support * float(ha.max())!r} vs cell_size={spec.cell_size!r}")


# --------------------------------------------------------------------------------------------
# reference
# --------------------------------------------------------------------------------------------

def brute_force(x, h, domain: Domain, support: float = 2.0) -> list[np.ndarray]:
    """O(N^2) numpy reference: the sorted neighbour indices (self included) of every particle."""
    x = np.asarray(x, np.float64)
    h = np.asarray(h, np.float64)
    n = x.shape[0]
    L = np.asarray(domain.length, np.float64)
    per = np.asarray(domain.periodic, bool)
    out = []
    chunk = max(1, 1_000_000 // max(n, 1))
    for s in range(0, n, chunk):
        dx = x[s:s + chunk, None, :] - x[None, :, :]
        dx = np.where(per, dx - L * np.round(dx / L), dx)
        cut = support * np.maximum(h[s:s + chunk, None], h[None, :])
        hit = np.sum(dx * dx, axis=-1) < cut * cut
        out.extend(np.flatnonzero(row) for row in hit)
    return out
