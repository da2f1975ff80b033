"""Spatial domain decomposition of an Eulerian run (``run.decomposition = "spatial"``, decision 64).

``run.devices = D`` with the default ``run.decomposition = "index"`` shards the particle arrays as
index ranges and lets XLA's SPMD partitioner all-gather the per-particle fields every stage
(:mod:`mlsph_jax.sharding`).  The spatial decomposition built here sends only the particles a
shard's stencils touch:

* **ordering** (host, numpy, at setup): the particles are ranked along a Morton (Z-order) curve
  of their positions quantised on a ``2^b`` grid of the bounding box; shard ``k`` owns the ``k``-th
  of ``D`` contiguous blocks of that order (sizes differ by at most one), a compact region.  A
  mirror ghost is not counted in the blocks: it is owned by the shard of its parent (its image
  across the wall, within the ghost band of it), so the ghosts a shard regenerates read only
  particles it owns.
* **halo**: the rows of a shard are its owned particles, then ``H1`` (their neighbours owned
  elsewhere), then ``H2`` (the neighbours of ``H1`` not yet present), then padding (at least
  one row).  Two stencil hops, not one: the j-side midpoint state of a pair is the i-side state
  of the reverse pair (:mod:`mlsph_jax.rhs`), i.e. the fit of ``j``, which reads ``j``'s whole
  stencil.  The rows of ``H2`` have incomplete stencils (their foreign neighbours are masked
  off); what they compute is never read by an owned row and is overwritten by the next exchange.
* **geometry**: the run's fixed geometry is computed once on the host for all particles (as on
  one device), then its rows are copied to the shards with the neighbour indices rewritten to
  local rows; reverse slots are unchanged, since every row keeps its slot order.
* **halo exchange** inside the jitted chunk (``jax.shard_map``): before every stage and after the
  step the halo rows are refreshed from their owners by one ``jax.lax.ppermute`` per device shift
  ``s`` (device ``k`` sends to ``k + s``) of a fixed-size padded send list computed at setup; only
  the conserved quantities ``q`` travel (positions, volumes, kinds and degrees are fixed in the
  Eulerian frame and every copy evolves bit for bit like its owner).
* **reductions**: the CFL step by ``pmin``, the status word by an all-gather of ``D`` ints (OR),
  the failing particle's original index by ``pmin``, the degree-fallback and MOOD statistics by
  ``psum`` over owned rows only.

Every owned row sees exactly the neighbours and the geometry it has on one device, so the run
computes the one-device numbers (to round-off: XLA may fuse a shard's arrays differently).  The
user never sees the permutation: :meth:`SpatialSharding.place` takes arrays in the original
particle order and :meth:`SpatialSharding.gather` returns them in it.

Supported: Eulerian frames (the neighbour list and geometry fixed for the whole run), periodic
boxes, mirror-ghost walls, frozen particles.  Refused (``InputError`` naming the key): moving
frames (``scheme.frame``), MOOD (``scheme.limiter``), boundary-integral walls
(``case.walls``), local time stepping (``time.local_time_stepping``), and the differentiated
and diffrax run paths (:func:`refuse_in`), which run on one device.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from .errors import InputError
from .sharding import AXIS, ParticleSharding, check_devices

__all__ = ["DECOMPOSITIONS", "SpatialGeometry", "SpatialSharding", "check_spatial", "morton_order",
           "refuse_in", "spatial_sharding"]

#: The values of ``run.decomposition``.
DECOMPOSITIONS = ("index", "spatial")


def morton_order(x: np.ndarray, bits: int | None = None) -> np.ndarray:
    """Permutation sorting the points ``x[N, d]`` along a Morton (Z-order) curve of their
    positions quantised on a ``2^bits`` grid per axis of their bounding box (ties by index)."""
    x = np.asarray(x, float)
    n, d = x.shape
    bits = bits or (21 if d == 3 else 31 if d == 2 else 62)
    lo, hi = x.min(axis=0), x.max(axis=0)
    span = np.where(hi > lo, hi - lo, 1.0)
    cells = np.minimum(((x - lo) / span * (2 ** bits)).astype(np.int64), 2 ** bits - 1).astype(np.uint64)
    key = np.zeros(n, np.uint64)
    for b in range(bits):
        for a in range(d):
            key |= ((cells[:, a] >> np.uint64(b)) & np.uint64(1)) << np.uint64(b * d + a)
    return np.argsort(key, kind="stable")


def check_spatial(scheme, boundary, *, local_time_stepping: bool = False):
    """Refuse (``InputError`` naming the key and value) what the spatial decomposition does not
    support: moving frames, MOOD, walls other than mirror ghosts, mirror ghosts without their
    inviscid shear dissipation (``scheme.ghost_shear_dissipation = false``), the conservation
    projection (``scheme.conservation_projection``), local time stepping."""
    from .boundaries import MirrorWalls
    from .far_field import CharacteristicFarField, WithFarField

    ok = 'allowed with run.decomposition="spatial": '
    if scheme.moving:
        raise InputError(f"invalid scheme.frame={scheme.frame!r} with run.decomposition=\"spatial\": the spatial "
                         "decomposition needs particles that do not move (fixed neighbour list and geometry); "
                         f"{ok}scheme.frame=\"eulerian\" (or run.decomposition=\"index\" for moving frames)")
    if scheme.limiter != "none":
        raise InputError(f"invalid scheme.limiter={scheme.limiter!r} with run.decomposition=\"spatial\": MOOD is "
                         f"not built for the spatial decomposition; {ok}scheme.limiter=\"none\" (or "
                         "run.decomposition=\"index\")")
    if isinstance(boundary, (WithFarField, CharacteristicFarField)):
        raise InputError("invalid far field (case.far_field=\"characteristic\"/\"inflow_outflow\", or an open "
                         "channel's case.inlet) with run.decomposition=\"spatial\": each far-field particle reads a "
                         f"fluid particle that may sit on another shard; {ok}case.far_field=\"frozen\" or "
                         "case.inlet=0 (or run.decomposition=\"index\")")
    if boundary is not None and not isinstance(boundary, MirrorWalls):
        what = ("boundary-integral walls (case.walls=\"boundary_integral\", or a case whose body is one, "
                "such as the cylinder)" if getattr(boundary, "wall_terms", None) is not None
                else f"walls of type {type(boundary).__name__}")
        raise InputError(f"invalid {what} with run.decomposition=\"spatial\": {ok}no walls or "
                         "case.walls=\"mirror_ghosts\" (or run.decomposition=\"index\")")
    if not scheme.ghost_shear_dissipation:
        raise InputError("invalid scheme.ghost_shear_dissipation=false with run.decomposition=\"spatial\": the "
                         "shards' halo boundary does not carry the mirror ghosts' wall-tangential mask (decision "
                         f"81); {ok}scheme.ghost_shear_dissipation=true (or run.decomposition=\"index\")")
    if scheme.conservation_projection:
        raise InputError("invalid scheme.conservation_projection=true with run.decomposition=\"spatial\": its "
                         "sum over all fluid particles is not built across the shards; "
                         f"{ok}scheme.conservation_projection=false (or run.decomposition=\"index\")")
    if local_time_stepping:
        raise InputError("invalid time.local_time_stepping=true with run.decomposition=\"spatial\"; "
                         f"{ok}time.local_time_stepping=false (or run.decomposition=\"index\")")


def refuse_in(problem, path: str):
    """Refuse (``InputError``) a problem whose config asks for ``run.decomposition = "spatial"``
    on a run path that runs on one device (``path``: the differentiated runs, the diffrax path)."""
    run = ((getattr(problem, "config", None) or {}).get("run") or {})
    if run.get("decomposition", "index") == "spatial":
        raise InputError(f"invalid run.decomposition='spatial' for {path}: it runs on one device (the spatial "
                         "decomposition is built for the chunked driver, mlsph run / Simulation); allowed: 'index' "
                         "(the default)")


def _neighbours(idx: np.ndarray, mask: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """The distinct particles in the stencils of ``rows``."""
    return np.unique(idx[rows][mask[rows]])


@dataclasses.dataclass(frozen=True)
class _Layout:
    """Host tables of a spatial decomposition (see the module docstring)."""

    rows: np.ndarray        # [D, L] original index of every local row (padding: the shard's first owned)
    n_owned: np.ndarray     # [D]
    n_local: np.ndarray     # [D] owned + halo rows
    owner: np.ndarray       # [N] shard owning each particle
    pos: np.ndarray         # [N] flat local position (k L + row) of each particle's owned row
    shifts: tuple           # device shifts s with a non-empty send list
    send: tuple             # per shift [D, S_s] local rows device k sends to k + s (padded with 0)
    halo_rows: np.ndarray   # [D, H] local rows refreshed by the exchange (padding: the last row)
    halo_src: np.ndarray    # [D, H] their index into the concatenated receive buffers

    @property
    def width(self) -> int:
        return self.rows.shape[1]


def build_layout(x: np.ndarray, idx: np.ndarray, mask: np.ndarray, devices: int,
                 ghost: np.ndarray | None = None, parent: np.ndarray | None = None) -> _Layout:
    """The :class:`_Layout` of ``devices`` shards for the particles ``x`` with the neighbour
    list ``(idx, mask)``; mirror ghosts ``ghost`` are owned by the shard of their ``parent``."""
    n, D = x.shape[0], int(devices)
    order = morton_order(x)
    rank = np.empty(n, np.int64)
    rank[order] = np.arange(n)
    owner = np.empty(n, np.int64)
    placed = order
    if ghost is not None and len(ghost):     # the curve's blocks split the other particles equally
        placed = order[~np.isin(order, ghost)]
    for k, block in enumerate(np.array_split(placed, D)):
        owner[block] = k
    if ghost is not None and len(ghost):
        owner[ghost] = owner[parent]
    by_rank = lambda a: a[np.argsort(rank[a], kind="stable")]  # noqa: E731
    owned, local = [], []
    for k in range(D):
        mine = by_rank(np.flatnonzero(owner == k))
        if mine.size == 0:
            raise InputError(f"invalid run.devices={D}: shard {k} would own no particle ({n} particles); allowed: "
                             f"at most {n} devices")
        h1 = np.setdiff1d(_neighbours(idx, mask, mine), mine)
        h2 = np.setdiff1d(_neighbours(idx, mask, h1), np.concatenate([mine, h1]))
        owned.append(mine)
        local.append(np.concatenate([mine, by_rank(h1), by_rank(h2)]))
    width = max(a.size for a in local) + 1                  # >= 1 padding row per shard
    rows = np.stack([np.concatenate([a, np.full(width - a.size, a[0])]) for a in local])
    pos = np.empty(n, np.int64)
    for k, mine in enumerate(owned):
        pos[mine] = k * width + np.arange(mine.size)
    # send lists: what shard m needs from shard k (its halo rows owned by k), per shift (m - k) mod D
    need = {}
    halo_rows, halo_src = [], []
    for m in range(D):
        halo = local[m][owned[m].size:]
        halo_rows.append(np.arange(owned[m].size, local[m].size))
        for k in range(D):
            sel = owner[halo] == k
            if sel.any():
                need[(k, m)] = halo[sel]
    shifts = tuple(sorted({(m - k) % D for k, m in need})) or (1,)
    send, offset = [], {}
    base = 0
    for s in shifts:
        lists = [need.get((k, (k + s) % D), np.zeros(0, np.int64)) for k in range(D)]
        size = max(1, max(a.size for a in lists))
        table = np.zeros((D, size), np.int64)
        for k, a in enumerate(lists):
            table[k, :a.size] = pos[a] - k * width           # owned rows of k (its first rows)
        send.append(table)
        offset[s] = base
        base += size
    for m in range(D):
        src = np.zeros(halo_rows[m].size, np.int64)
        halo = local[m][owned[m].size:]
        for k in range(D):
            if (k, m) in need:
                s = (m - k) % D
                where = {g: j for j, g in enumerate(need[(k, m)])}
                sel = np.flatnonzero(owner[halo] == k)
                src[sel] = offset[s] + np.array([where[g] for g in halo[sel]], np.int64)
        halo_src.append(src)
    h = max(1, max(a.size for a in halo_rows))
    pad = lambda a, v: np.concatenate([a, np.full(h - a.size, v, np.int64)])  # noqa: E731
    return _Layout(rows=rows, n_owned=np.array([a.size for a in owned]), n_local=np.array([a.size for a in local]),
                   owner=owner, pos=pos, shifts=shifts, send=tuple(send),
                   halo_rows=np.stack([pad(a, width) for a in halo_rows]),   # padding: out of range (dropped)
                   halo_src=np.stack([pad(a, a[0] if a.size else 0) for a in halo_src]))


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SpatialGeometry:
    """The per-shard geometry and exchange tables passed to the spatial chunk.  Every array but
    ``geom.overflow`` is sharded over its leading axis (``D L`` rows, or ``D`` tables)."""

    geom: object            # rhs.Geometry with local rows and indices
    owned: jax.Array        # [D L] bool
    gid: jax.Array          # [D L] original index of each row
    send: tuple             # per shift [D, S_s]
    halo_rows: jax.Array    # [D, H]
    halo_src: jax.Array     # [D, H]
    walls: object | None    # (ghost [D, G], parent [D, G], walls [D, G, nw], has_ghost [D L, nw]) or None

    @property
    def degree(self):
        return self.geom.degree


@dataclasses.dataclass(frozen=True)
class SpatialSharding:
    """A spatial decomposition over a 1-D mesh (module docstring).  Arrays whose leading
    dimension is the particle count ``n`` are placed in the local layout (``D L`` rows, sharded);
    :meth:`gather` returns them in the original particle order."""

    mesh: Mesh
    n: int
    layout: _Layout
    idx_key: bytes          # digest of the neighbour list the layout was built for

    @property
    def devices(self) -> int:
        return self.layout.rows.shape[0]

    @property
    def rows(self) -> int:
        return self.devices * self.layout.width

    @functools.cached_property
    def _base(self) -> ParticleSharding:
        return ParticleSharding(self.mesh, self.rows)

    def info(self) -> dict:
        """Layout statistics for ``summary.json``: owned and halo rows per shard."""
        lay = self.layout
        return {"kind": "spatial", "owned": lay.n_owned.tolist(), "halo": (lay.n_local - lay.n_owned).tolist(),
                "rows_per_shard": int(lay.width), "exchange_shifts": list(lay.shifts),
                "send_rows": [int(t.shape[1]) for t in lay.send]}

    def place(self, tree):
        """Per-particle arrays (original order, leading dimension ``n``) to the sharded local
        layout; everything else replicated."""
        rows = self.layout.rows.reshape(-1)

        def local(a):
            if a is None or np.ndim(a) == 0 or np.shape(a)[0] != self.n:
                return a
            return np.asarray(a)[rows]

        return self._base.place(jax.tree_util.tree_map(local, tree))

    def replicate(self, tree):
        """``tree`` replicated on every device (the parameters, which the shard_map takes as
        replicated: :meth:`place` would permute an array of N entries as a per-particle field)."""
        return self._base.replicate(tree)

    def gather(self, tree):
        """Host copy of ``tree`` with the local-layout arrays back in the original particle order."""
        pos = self.layout.pos

        def orig(a):
            if a is None or np.ndim(a) == 0 or np.shape(a)[0] != self.rows:
                return a
            return jnp.asarray(np.asarray(a)[pos])

        return jax.tree_util.tree_map(orig, self._base.gather(tree))

    def _put(self, a):
        h = np.asarray(a)
        return jax.make_array_from_callback(h.shape, NamedSharding(self.mesh, P(AXIS)), lambda i: h[i])

    def place_geometry(self, geom, boundary=None) -> SpatialGeometry:
        """The run's (global, original-order) geometry as a :class:`SpatialGeometry`: rows
        copied to their shards, neighbour indices rewritten to local rows (foreign neighbours
        of the outer halo masked off), the exchange tables and the local mirror-ghost tables."""
        lay, D, L = self.layout, self.devices, self.layout.width
        rows = lay.rows.reshape(-1)
        idx = np.asarray(geom.idx)
        n = self.n
        inv = np.full((D, n + 1), -1, np.int64)             # (+1: the padding index n)
        for k in range(D):
            inv[k, lay.rows[k, :lay.n_local[k]]] = np.arange(lay.n_local[k])
        loc = inv[np.repeat(np.arange(D), L)[:, None], idx[rows]]
        present = np.asarray(geom.mask)[rows] & (loc >= 0)
        g = dataclasses.replace(
            geom, idx=np.where(present, loc, L).astype(idx.dtype), mask=present,
            rev=np.where(present, np.asarray(geom.rev)[rows], 0).astype(np.asarray(geom.rev).dtype),
            pair_mask=np.asarray(geom.pair_mask)[rows] & present,
            **{f: np.asarray(getattr(geom, f))[rows] for f in ("dx", "A", "h", "interp", "degree")
               if getattr(geom, f) is not None},
            coeffs=None if geom.coeffs is None else np.asarray(geom.coeffs)[rows])
        g = self._base.place(dataclasses.replace(g, overflow=np.asarray(geom.overflow)))
        owned = np.arange(L)[None, :] < lay.n_owned[:, None]
        walls = None if boundary is None else tuple(map(self._put, self._walls(boundary, inv)))
        return SpatialGeometry(geom=g, owned=self._put(owned.reshape(-1)), gid=self._put(rows.astype(np.int32)),
                               send=tuple(self._put(t.astype(np.int32)) for t in lay.send),
                               halo_rows=self._put(lay.halo_rows.astype(np.int32)),
                               halo_src=self._put(lay.halo_src.astype(np.int32)), walls=walls)

    def _walls(self, mw, inv):
        """Per-shard mirror-ghost tables: the ghosts a shard owns, their (owned) parents and
        walls as local rows, padded to the same length (padding: the last row, parent row 0,
        no wall); ``has_ghost`` in the local layout."""
        lay, D, L = self.layout, self.devices, self.layout.width
        ghost, parent, walls = np.asarray(mw.ghost), np.asarray(mw.parent), np.asarray(mw.walls)
        mine = [np.flatnonzero(lay.owner[ghost] == k) for k in range(D)]
        size = max(1, max(a.size for a in mine))
        gl = np.full((D, size), L - 1, np.int32)
        pl = np.zeros((D, size), np.int32)
        wl = np.zeros((D, size, walls.shape[1]), bool)
        for k, sel in enumerate(mine):
            gl[k, :sel.size], pl[k, :sel.size], wl[k, :sel.size] = inv[k, ghost[sel]], inv[k, parent[sel]], walls[sel]
        has = np.zeros((D * L, walls.shape[1]), bool) if mw.has_ghost is None else \
            np.asarray(mw.has_ghost)[lay.rows.reshape(-1)]
        return gl, pl, wl, has


def spatial_sharding(devices: int, x: np.ndarray, nl, boundary=None, *, name: str = "run.devices"):
    """The :class:`SpatialSharding` of ``devices`` devices for the particles ``x`` and the
    neighbour list ``nl`` (``boundary``: mirror walls, whose ghosts follow their parents), or
    ``None`` for one device.  ``devices`` is checked as in :func:`mlsph_jax.sharding.particle_sharding`
    (any particle count: the shards are padded, no particle is dropped)."""
    d = check_devices(devices, name=name)
    if d == 1:
        return None
    idx, mask = np.asarray(nl.idx), np.asarray(nl.mask)
    ghost = parent = None
    if boundary is not None:
        ghost, parent = np.asarray(boundary.ghost), np.asarray(boundary.parent)
    layout = build_layout(np.asarray(x), idx, mask, d, ghost, parent)
    return SpatialSharding(Mesh(np.asarray(jax.devices()[:d]), (AXIS,)), int(np.shape(x)[0]), layout,
                           list_key(nl))


def list_key(nl) -> bytes:
    """Identity of a neighbour list (its indices and mask), to tell when a layout is stale."""
    import hashlib

    return hashlib.sha1(np.asarray(nl.idx).tobytes() + np.asarray(nl.mask).tobytes()).digest()


# --------------------------------------------------------------------------------------------
# inside the shard_map: exchange and reductions
# --------------------------------------------------------------------------------------------

class Collectives:
    """What a step needs across shards, traced inside ``shard_map`` on one shard's arrays
    (``tables``: the shard's slice of a :class:`SpatialGeometry`).  The one-device counterpart is
    :class:`mlsph_jax.integrate.LocalOps`."""

    def __init__(self, tables: SpatialGeometry, devices: int, shifts: tuple, boundary=None):
        self.t = tables
        self.devices = devices
        self.shifts = shifts
        self.mirror = None
        if boundary is not None:
            gl, pl, wl, has = tables.walls
            self.mirror = dataclasses.replace(boundary, ghost=gl[0], parent=pl[0], walls=wl[0], has_ghost=has)
        self.boundary = _HaloBoundary(self)

    def exchange(self, p):
        """``p`` with its halo rows refreshed from their owners (one ppermute per shift; only
        ``q`` travels: the rest is fixed in an Eulerian run)."""
        D = self.devices
        recv = [jax.lax.ppermute(p.q[send[0]], AXIS, perm=[(k, (k + s) % D) for k in range(D)])
                for s, send in zip(self.shifts, self.t.send, strict=True)]
        recv = recv[0] if len(recv) == 1 else jnp.concatenate(recv, axis=0)
        return p.replace(q=p.q.at[self.t.halo_rows[0]].set(recv[self.t.halo_src[0]], mode="drop"))

    def min(self, x):
        return jax.lax.pmin(x, AXIS)

    def count(self, mask):
        """Number of owned rows where ``mask`` holds, over every shard."""
        return jax.lax.psum(jnp.sum(mask & self.t.owned), AXIS)

    def status(self, bits, bad):
        """Status bits OR-ed over the shards; ``bad`` is already an original index, the same on
        every shard (:meth:`first`, :meth:`argmin`, the boundary's :meth:`_HaloBoundary.band_status`)."""
        every = jax.lax.all_gather(bits, AXIS)
        bits = functools.reduce(jnp.bitwise_or, [every[k] for k in range(self.devices)])
        return bits, self._smallest(jnp.where(bad >= 0, bad, _BIG))

    def _smallest(self, gid):
        g = jax.lax.pmin(gid, AXIS)
        return jnp.where(g == _BIG, -1, g).astype(jnp.int32)

    def first(self, mask):
        """Smallest original index of an owned row where ``mask`` holds, over every shard, or -1
        (the particle a one-device run's first-index search names)."""
        return self._smallest(jnp.min(jnp.where(mask & self.t.owned, self.t.gid, _BIG)))

    def argmin(self, values):
        """Original index of the smallest of ``values`` over the owned rows of every shard (the
        smallest such index on ties, as ``jnp.argmin`` on one device)."""
        v = jnp.where(self.t.owned, values, jnp.inf)
        m = jax.lax.pmin(jnp.min(v), AXIS)
        return self._smallest(jnp.min(jnp.where(self.t.owned & (v == m), self.t.gid, _BIG)))


#: "No particle" in the index reductions.
_BIG = np.iinfo(np.int32).max


class _HaloBoundary:
    """The boundary the step sees on a shard: regenerate the owned ghosts, then exchange."""

    def __init__(self, ops: Collectives):
        self.ops = ops

    def apply(self, p, params):
        if self.ops.mirror is not None:
            p = self.ops.mirror.apply(p, params)
        return self.ops.exchange(p)

    def band_status(self, p, params=None):
        """The mirror walls' check of this shard, its particle as an original index (the
        smallest over the shards' first offenders in local order; the cause is the same as on
        one device, the particle may be another one within the band)."""
        if self.ops.mirror is None:
            return jnp.zeros((), jnp.int32), jnp.asarray(-1, jnp.int32)
        bits, bad = self.ops.mirror.band_status(p, params)
        t = self.ops.t
        ok = (bad >= 0) & t.owned[jnp.maximum(bad, 0)]
        return bits, self.ops._smallest(jnp.where(ok, t.gid[jnp.maximum(bad, 0)], _BIG))


def shard_chunk(local_chunk, sharding: SpatialSharding):
    """``local_chunk(carry, params, tables, t_stop, step_stop)`` (one shard's arrays) as a
    ``jax.shard_map`` over the mesh: the carry's per-particle arrays and every table sharded,
    everything else replicated."""
    rows = sharding.rows

    def chunk(carry, params, sgeom, t_stop, step_stop):
        spec = lambda a: P(AXIS) if np.ndim(a) and np.shape(a)[0] == rows else P()  # noqa: E731
        cspec = jax.tree_util.tree_map(spec, carry)
        gspec = jax.tree_util.tree_map(lambda a: P(AXIS) if np.ndim(a) else P(), sgeom)
        rep = jax.tree_util.tree_map(lambda a: P(), (params, t_stop, step_stop))
        f = jax.shard_map(local_chunk, mesh=sharding.mesh, in_specs=(cspec, rep[0], gspec, rep[1], rep[2]),
                          out_specs=cspec, check_vma=False)
        return f(carry, params, sgeom, t_stop, step_stop)

    return chunk
