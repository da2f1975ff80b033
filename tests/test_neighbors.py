"""Tests of the O(N) fixed-capacity neighbour lists (mlsph_jax.neighbors).

Every list is compared exactly with the O(N^2) brute force.  Compilation dominates the run
time, so most comparisons share one kernel shape per (d, periodic?) — N = 40 particles with
``capacity = cell_capacity = N`` — which the kernel cache reuses across specs.
"""

from __future__ import annotations

import dataclasses
import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import mlsph_jax  # noqa: F401  (enables float64)
from mlsph_jax import neighbors as nb
from mlsph_jax.errors import InputError, NeighborOverflowError
from mlsph_jax.state import Domain

N = 40  # shared particle count of the brute-force comparisons (one compiled kernel per key)


# ------------------------------------------------------------------------------------------
# helpers
# ------------------------------------------------------------------------------------------

def check_list(x, h, domain, nl, support=2.0):
    """Exact brute-force match, row layout, counts, symmetry and reverse slots."""
    x = np.asarray(x)
    n = x.shape[0]
    bf = nb.brute_force(x, h, domain, support)
    idx, mask = np.asarray(nl.idx), np.asarray(nl.mask)
    rev, count = np.asarray(nl.rev), np.asarray(nl.count)
    K = idx.shape[1]
    assert idx.dtype == np.int32 and rev.dtype == np.int32 and count.dtype == np.int32
    assert idx.shape == mask.shape == rev.shape == (n, K) and count.shape == (n,)
    assert not bool(nl.overflow)
    assert np.array_equal(mask, idx < n)
    for i in range(n):
        assert np.array_equal(idx[i, mask[i]], bf[i]), f"row {i}: {idx[i, mask[i]]} != {bf[i]}"
        assert i in bf[i]  # self included
    lengths = np.array([len(r) for r in bf])
    assert np.array_equal(count, lengths)
    # valid entries first, ascending, padding = N
    assert np.array_equal(mask, np.arange(K)[None, :] < lengths[:, None])
    assert np.all(idx[~mask] == n)
    assert np.all(np.diff(idx, axis=1) >= 0)
    # symmetry: j in row i <=> i in row j
    ii, kk = np.nonzero(mask)
    jj = idx[ii, kk]
    pairs = set(zip(ii.tolist(), jj.tolist(), strict=True))
    assert all((j, i) in pairs for i, j in pairs)
    # reverse slots
    assert np.array_equal(idx[jj, rev[ii, kk]], ii)
    assert np.all(rev[~mask] == 0)


def fixed_spec(x, h, domain, support=2.0, **kw):
    """Spec with capacity = cell_capacity = N (never overflows; shared compiled kernel)."""
    spec = nb.plan(x, h, domain, support=support, **kw)
    n = len(x)
    return dataclasses.replace(spec, capacity=n, cell_capacity=n, batch_size=None)


def cloud(rng, domain, n, h0, spread=2.0, special=True):
    """Random cloud with variable h in ``domain``; optionally with particles on box faces and
    corners (exactly on periodic boundaries), duplicates, and some outside the bounds."""
    lo, L = np.array(domain.lower), np.array(domain.length)
    d = domain.dim
    x = lo + rng.uniform(0, 1, (n, d)) * L
    if special:
        x[0] = lo                       # lower corner
        x[1] = lo + L                   # upper corner (== lower corner on periodic axes)
        x[2] = lo + L * (1 - 1e-13)     # just inside the upper corner
        x[3] = x[4]                     # duplicate position
        x[5, 0] = lo[0] + L[0]          # exactly on the upper face of axis 0
        x[6, -1] = lo[-1]               # exactly on the lower face of the last axis
        x[7] = lo - 0.1 * L             # outside the bounds (clamped / wrapped)
        x[8] = lo + 1.05 * L
    h = h0 * rng.uniform(1.0 / spread, 1.0, n)
    return x, h


# ------------------------------------------------------------------------------------------
# exact agreement with brute force
# ------------------------------------------------------------------------------------------

CONFIGS = [
    ((False,),), ((True,),),
    *[(p,) for p in itertools.product((False, True), repeat=2)],
    ((False, False, False),), ((True, False, True),), ((True, True, True),),
]


@pytest.mark.parametrize("periodic", [c[0] for c in CONFIGS], ids=str)
def test_matches_brute_force(periodic):
    d = len(periodic)
    rng = np.random.default_rng(11 + d + 7 * sum(periodic))
    lower = (-1.0, 0.5, 2.0)[:d]
    length = (2.0, 1.5, 1.6)[:d]
    domain = Domain(lower, tuple(a + b for a, b in zip(lower, length, strict=True)), periodic)
    h0 = (0.12, 0.2, 0.25)[d - 1]         # support * max h <= min(L) / 3
    x, h = cloud(rng, domain, N, h0)
    spec = fixed_spec(x, h, domain)
    assert all(n >= 3 for n in spec.n_cells)
    nl = nb.update(x, h, spec)
    check_list(x, h, domain, nl)
    assert np.asarray(nl.count).max() > 1   # non-trivial neighbourhoods


def test_update_is_jittable_with_static_spec():
    rng = np.random.default_rng(3)
    domain = Domain((0.0, 0.0), (2.0, 1.5), (True, False))
    x, h = cloud(rng, domain, N, 0.2)
    spec = fixed_spec(x, h, domain)
    a = nb.update(x, h, spec)
    b = nb.update_jit(x, h, spec=spec)
    c = jax.jit(nb.update, static_argnames="spec")(x, h, spec=spec)
    for f in ("idx", "mask", "rev", "count", "overflow"):
        assert np.array_equal(np.asarray(getattr(a, f)), np.asarray(getattr(b, f)))
        assert np.array_equal(np.asarray(getattr(a, f)), np.asarray(getattr(c, f)))
    # a pytree: passes through jit
    out = jax.jit(lambda nl: nl.idx.sum())(a)
    assert int(out) == int(np.asarray(a.idx).sum())


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(d=st.integers(1, 3), data=st.data(), seed=st.integers(0, 2**32 - 1),
       hscale=st.sampled_from([0.35, 0.7, 1.0]), spread=st.sampled_from([1.0, 1.5, 4.0]),
       snap=st.booleans())
def test_property_matches_brute_force(d, data, seed, hscale, spread, snap):
    periodic = tuple(data.draw(st.lists(st.booleans(), min_size=d, max_size=d)))
    rng = np.random.default_rng(seed)
    lower = (-1.0, 0.5, 2.0)[:d]
    length = (2.0, 1.5, 1.6)[:d]
    domain = Domain(lower, tuple(a + b for a, b in zip(lower, length, strict=True)), periodic)
    h0 = hscale * (0.12, 0.2, 0.25)[d - 1]
    x, h = cloud(rng, domain, N, h0, spread=spread, special=data.draw(st.booleans()))
    if snap:  # dyadic lattice positions and h: exact ties at the cut-off, boundary hits
        x = np.round(x * 16) / 16
        h = np.round(h * 64) / 64
        h = np.clip(h, 1 / 64, np.floor(min(length) / 6.0 * 64 - 1) / 64)  # >= 3 cells/axis
    spec = fixed_spec(x, h, domain)
    nl = nb.update(x, h, spec)
    check_list(x, h, domain, nl)


@pytest.mark.parametrize("periodic,length,cut", [
    ((True, True), (1.0, 1.5), 0.7),            # n_cells = (1, 2)
    ((True, False, True), (1.25, 1.0, 1.0), 0.6),  # n_cells = (2, 2, 1)
], ids=["2d", "3d"])
def test_periodic_axes_with_fewer_than_three_cells(periodic, length, cut):
    d = len(periodic)
    rng = np.random.default_rng(5)
    domain = Domain((0.0,) * d, length, periodic)
    x, h = cloud(rng, domain, N, cut / 2.0, spread=1.5)
    spec = fixed_spec(x, h, domain)
    assert any(n < 3 for n, p in zip(spec.n_cells, periodic, strict=True) if p)
    nl = nb.update(x, h, spec)
    check_list(x, h, domain, nl)


def test_thin_periodic_tube_allocate_and_batched_path():
    """A 1D tube: 2D channel 1e9 x 1 (1.7e8 x 1 cells), periodic along x, particles on a line
    in clusters (one wrapping around x = 0).  Real sizing by ``allocate`` and the batched
    kernel (several batches + a partial one)."""
    rng = np.random.default_rng(8)
    n, L = 500, 1.0e9
    domain = Domain((0.0, 0.0), (L, 1.0), (True, False))
    starts = np.array([0.0, 2.5e8, 5e8, 7.5e8, L - 120.0])
    x = np.stack([np.repeat(starts, n // 5) + rng.uniform(0, 150.0, n), np.full(n, 0.5)], axis=1)
    x[::7, 1] += rng.uniform(-0.3, 0.3, x[::7].shape[0])
    x[0, 0] = 0.0
    h = rng.uniform(1.0, 3.0, n)
    spec, nl = nb.allocate(x, h, domain)
    assert spec.n_cells[1] == 1 and spec.n_cells[0] == math.floor(L / spec.cell_size) > 1e8
    assert spec.cell_size >= 2.0 * h.max()
    counts = np.array([len(r) for r in nb.brute_force(x, h, domain)])
    assert counts.max() <= spec.capacity <= min(n, math.ceil(counts.max() * 1.3))
    check_list(x, h, domain, nl)
    batched = dataclasses.replace(spec, batch_size=64)   # 7 full batches + a partial one
    check_list(x, h, domain, nb.update(x, h, batched))


# ------------------------------------------------------------------------------------------
# thin domains: no dense grid
# ------------------------------------------------------------------------------------------

def _max_intermediate(jaxpr) -> int:
    """Largest array (elements) produced anywhere in a (closed) jaxpr, sub-jaxprs included."""
    best = 0
    for eqn in jaxpr.eqns:
        for v in eqn.outvars:
            best = max(best, int(np.prod(getattr(v.aval, "shape", ()), dtype=np.int64)))
        for p in eqn.params.values():
            for sub in p if isinstance(p, tuple | list) else (p,):
                inner = sub if hasattr(sub, "eqns") else getattr(sub, "jaxpr", None)
                if inner is not None and hasattr(inner, "eqns"):
                    best = max(best, _max_intermediate(inner))
    return best


def test_sparse_cloud_in_huge_box_no_dense_grid():
    rng = np.random.default_rng(4)
    L = 1.0e7
    domain = Domain((0.0, 0.0, 0.0), (L, L, L), (False, False, True))
    # clumps far apart; two clumps exactly 2**20 cells apart along x collide in the hash
    centres = np.array([[1.0, 1.0, 1.0], [5e6, 3e6, 9e6], [2.0 ** 20 * 1.0 + 1.0, 1.0, 1.0],
                        [9.9e6, 9.9e6, 0.5]])
    x = np.concatenate([c + rng.uniform(-1.0, 1.0, (15, 3)) for c in centres])
    x = np.concatenate([x, rng.uniform(0, L, (20, 3))])         # isolated particles
    x[-1] = (L, L, L)                                           # corner, periodic wrap on z
    x[-2] = (L - 0.2, L - 0.2, 0.3)                             # its neighbour across z
    h = rng.uniform(0.25, 0.5, len(x))
    spec, nl = nb.allocate(x, h, domain, cell_size=1.0)
    dense = np.prod([float(n) for n in spec.n_cells])
    assert dense > 1e20                       # a dense grid would have > 1e12 cells
    assert spec.n_cells[0] > 2 ** 20          # hash folding is active on x
    check_list(x, h, domain, nl)
    # memory: no intermediate scales with the box; all are O(N * K) / O(N * 3^d * C)
    jaxpr = jax.make_jaxpr(lambda a, b: nb.update(a, b, spec))(x, h)
    n, bound = len(x), len(x) * max(spec.capacity, 27 * 32 * 2) * 4
    biggest = _max_intermediate(jaxpr.jaxpr)
    assert biggest <= bound, (biggest, bound)
    small = dataclasses.replace(spec, n_cells=(4, 4, 4), lower=(0.0,) * 3, upper=(4.0,) * 3)
    jaxpr_small = jax.make_jaxpr(lambda a, b: nb.update(a, b, small))(x / L * 4, h)
    assert _max_intermediate(jaxpr_small.jaxpr) == biggest
    assert n == 80


# ------------------------------------------------------------------------------------------
# overflow and regrowth
# ------------------------------------------------------------------------------------------

def test_overflow_flag_and_regrowth():
    rng = np.random.default_rng(21)
    domain = Domain((0.0, 0.0), (2.0, 1.5), (False, True))
    x, h = cloud(rng, domain, N, 0.3)
    bf_max = max(len(r) for r in nb.brute_force(x, h, domain))
    assert bf_max > 3
    # row capacity too small
    small = nb.plan(x, h, domain, capacity=3)
    assert small.capacity == 3 and small.cell_capacity < N
    nl = nb.update(x, h, small)
    assert bool(nl.overflow)
    assert int(np.asarray(nl.count).max()) == bf_max         # true count, exceeds K
    with pytest.raises(NeighborOverflowError, match=r"capacity=3"):
        nb.update_or_grow(x, h, small, max_tries=0)
    # cell capacity too small (K large enough)
    tiny_cells = dataclasses.replace(small, capacity=N, cell_capacity=1)
    assert bool(nb.update(x, h, tiny_cells).overflow)
    # support radius outgrew the cell size (same spec, larger h): flagged, then regrown
    big_h = 1.5 * h
    assert bool(nb.update(x, big_h, small).overflow)
    spec, nl2 = nb.update_or_grow(x, big_h, small)
    assert not bool(nl2.overflow)
    assert spec.cell_size >= 2.0 * big_h.max() and spec.capacity > 3
    check_list(x, big_h, domain, nl2)


def test_grow_never_shrinks():
    rng = np.random.default_rng(2)
    domain = Domain((0.0, 0.0), (2.0, 1.5), (False, False))
    x, h = cloud(rng, domain, N, 0.3)
    big = dataclasses.replace(nb.plan(x, h, domain), capacity=N, cell_capacity=N,
                              cell_size=1.0)
    g = nb.grow(big, x, h)
    assert g.capacity == N and g.cell_capacity == N and g.cell_size == 1.0


# ------------------------------------------------------------------------------------------
# bad input
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("case,match", [
    ("x_nan", r"non-finite x at particle 3"),
    ("x_inf", r"non-finite x at particle 0"),
    ("x_shape", r"invalid x with shape \(10,\)"),
    ("x_dim", r"invalid x with shape \(10, 3\).*dimension 2"),
    ("h_zero", r"invalid h=0\.0 at particle 4"),
    ("h_neg", r"invalid h=-1\.0 at particle 0"),
    ("h_nan", r"invalid h=nan at particle 2"),
    ("h_shape", r"invalid h with shape \(9,\)"),
    ("support", r"invalid support=0"),
    ("headroom", r"invalid headroom=0\.5"),
    ("capacity", r"invalid capacity=0"),
    ("cell_size", r"invalid cell_size=0\.01"),
    ("domain", r"invalid domain="),
])
def test_bad_input_raises_input_error(case, match):
    rng = np.random.default_rng(0)
    domain = Domain((0.0, 0.0), (1.0, 1.0), (False, True))
    x = rng.uniform(0, 1, (10, 2))
    h = np.full(10, 0.05)
    kw = {}
    if case == "x_nan":
        x[3, 1] = np.nan
    elif case == "x_inf":
        x[0, 0] = np.inf
    elif case == "x_shape":
        x = x[:, 0]
    elif case == "x_dim":
        x = rng.uniform(0, 1, (10, 3))
    elif case == "h_zero":
        h[4] = 0.0
    elif case == "h_neg":
        h[0] = -1.0
    elif case == "h_nan":
        h[2] = np.nan
    elif case == "h_shape":
        h = h[:9]
    elif case == "domain":
        domain = ((0.0, 0.0), (1.0, 1.0))
    else:
        kw = {"support": dict(support=0), "headroom": dict(headroom=0.5),
              "capacity": dict(capacity=0), "cell_size": dict(cell_size=0.01)}[case]
    with pytest.raises(InputError, match=match):
        nb.allocate(x, h, domain, **kw)
    if case.startswith(("x_", "h_")):
        spec = nb.NeighborSpec(capacity=4, cell_capacity=4, cell_size=0.1, n_cells=(10, 10),
                               lower=(0.0, 0.0), upper=(1.0, 1.0), periodic=(False, True),
                               support=2.0, batch_size=None)
        with pytest.raises(InputError, match=match):
            nb.update_or_grow(x, h, spec)
        with pytest.raises(InputError, match=match):
            nb.grow(spec, x, h)


def test_brute_force_reference_small_example():
    domain = Domain((0.0,), (1.0,), (True,))
    x = np.array([[0.0], [0.05], [0.95], [0.5]])
    h = np.array([0.03, 0.01, 0.01, 0.2])
    got = nb.brute_force(x, h, domain, support=2.0)
    # |0 - .05| = .05 < 2*.03 ; |0 - .95| wraps to .05 < .06 ; .05-.95 wraps to .1 >= .02
    assert [r.tolist() for r in got] == [[0, 1, 2], [0, 1], [0, 2], [3]]


# -- Verlet-skin candidate lists (mlsph_jax.verlet) ----------------------------------------------

def test_verlet_candidates_restricted_to_the_stencil_are_the_rebuilt_list():
    """Candidates built with a skin at x0, restricted at positions and smoothing lengths that moved
    by less than the skin allows, give exactly the list a fresh build gives there (indices,
    reverse slots, counts, bits); the candidates are only rebuilt once a particle has moved half
    the skin."""
    from mlsph_jax import verlet

    rng = np.random.default_rng(3)
    n1 = 16
    g = (np.stack(np.meshgrid(np.arange(n1), np.arange(n1), indexing="ij"), -1).reshape(-1, 2) + 0.5) / n1
    x0 = np.mod(g + rng.uniform(-0.2, 0.2, g.shape) / n1, 1.0)
    h0 = np.full(len(x0), 1.5 / n1)
    dom = Domain((0.0, 0.0), (1.0, 1.0), (True, True))
    spec, _ = nb.allocate(x0, h0, dom, support=2.0, headroom=1.6, cell_size=2.0 * 1.5 * h0.max())
    cspec = verlet.candidate_spec(spec)
    v = jax.jit(verlet.build, static_argnums=(2, 3))(jnp.asarray(x0), jnp.asarray(h0), spec, cspec)
    skin = float(v.skin)
    assert skin == pytest.approx(verlet.VERLET_SKIN * 2.0 * h0.max())
    assert int(v.cand.count.max()) > int(nb.update(x0, h0, spec).count.max())     # the skin adds candidates
    refresh = jax.jit(verlet.refresh, static_argnums=(3, 4))
    for scale, rebuilt in ((0.2, False), (0.4, False), (1.5, True)):
        # displacements up to scale * skin / 2 in length; smoothing lengths grow a little
        step = rng.normal(size=x0.shape)
        step *= (scale * 0.5 * skin / np.sqrt(2.0)) * (rng.uniform(0.5, 1.0, len(x0)) / np.abs(step).max(1))[:, None]
        x1 = np.mod(x0 + step, 1.0)
        h1 = h0 * (1.0 + (0.02 * skin if not rebuilt else 0.0))
        nl, v1 = refresh(v, jnp.asarray(x1), jnp.asarray(h1), spec, cspec)
        ref = nb.update(x1, h1, spec)
        assert not bool(ref.overflow)
        for f in ("idx", "mask", "rev", "count", "overflow_bits"):
            np.testing.assert_array_equal(np.asarray(getattr(nl, f)), np.asarray(getattr(ref, f)), err_msg=f)
        assert bool(jnp.any(v1.x_ref != v.x_ref)) == rebuilt
        # the stencil changed: the test is not vacuous
        assert not np.array_equal(np.asarray(ref.idx), np.asarray(nb.update(x0, h0, spec).idx))


def test_verlet_restriction_reports_a_row_overflow():
    """A stencil larger than the capacity K sets the row bit of the restricted list (the
    candidate capacity is larger than K, so the candidates alone would not)."""
    from mlsph_jax import verlet

    x = np.random.default_rng(0).uniform(0.0, 1.0, (400, 2))
    h = np.full(400, 0.06)
    dom = Domain((0.0, 0.0), (1.0, 1.0), (True, True))
    spec, _ = nb.allocate(x, h, dom, support=2.0, headroom=1.0, cell_size=0.18)
    small = dataclasses.replace(spec, capacity=spec.capacity - 2)
    cspec = verlet.candidate_spec(small)
    v = jax.jit(verlet.build, static_argnums=(2, 3))(jnp.asarray(x), jnp.asarray(h), small, cspec)
    assert int(v.cand.overflow_bits) == 0
    nl, _ = jax.jit(verlet.refresh, static_argnums=(3, 4))(v, jnp.asarray(x), jnp.asarray(h), small, cspec)
    assert int(nl.overflow_bits) == nb.OVERFLOW_ROW == int(nb.update(x, h, small).overflow_bits)


@pytest.mark.parametrize("width", [1, 5, 75, 128, 129, 200, 435])
def test_verlet_prefix_counts_are_the_row_cumsum(width):
    """The restriction's slot of each kept candidate: the row's running count of kept entries,
    exactly, for one block (width <= 128) and for several blocks with their carried totals."""
    from mlsph_jax import verlet

    keep = np.random.default_rng(width).uniform(size=(37, width)) < 0.6
    got = np.asarray(verlet.prefix_counts(jnp.asarray(keep)))
    assert got.dtype == np.int32
    np.testing.assert_array_equal(got, np.cumsum(keep, axis=1))
