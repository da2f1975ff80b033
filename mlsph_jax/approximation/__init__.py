"""Approximation library: shape-function values and gradients on the (N, K) neighbour stencil.

For every particle i and slot k with j = idx[i, k] this builds

    values[i, k]    = N_j(x_i)            (shape function of j evaluated at particle i)
    gradients[i, k] = grad N_j(x_i)       (= "grad N_ji" of the thesis, SPEC §4.3)

for the approximations of SPEC §4 and §11 (the thesis' Table 5.1 and the settings of §10.5):

* ``kernel``    — plain SPH, N_j(x) = W(x - x_j, h_ij) V_j with the pair-mean smoothing length
  h_ij = (h_i + h_j)/2 (thesis eq. 3.5); so V_i grad N_ji - V_j grad N_ij = 2 V_i V_j grad_i W_ij
  (thesis eq. 5.84-5.85).
* ``shepard``   — MLS with the constant basis, N_j = w_j / sum_k w_k (B98 eq. 38, FVPM particle
  functions, thesis eq. 5.46).  Identical to ``mls`` with degree 0.
* ``corrected`` — Shepard-normalised kernel values with the Randles–Libersky / Bonet–Lok
  renormalised gradient grad N_j(x_i) = B_i grad W_ij V_j, B_i = (sum_j V_j grad W_ij (x_j -
  x_i)^T)^{-1}, and grad N_i(x_i) = -sum_{j != i} grad N_j(x_i) (B98 eq. 67-70, thesis eq. 5.108);
  exact for linear fields; falls back to the plain kernel gradient where B_i is singular
  (``degree`` 0 there, 1 elsewhere).
* ``mls``       — moving least squares of degree 0..3 (see :mod:`.mls`), full or fixed-centre
  derivative, per-particle fallback to lower degrees, and the per-particle polynomial
  coefficients for evaluating fitted fields anywhere near the particle (:func:`fit`,
  :func:`evaluate_fit`).

Smoothing length: h_i = beta * V_i^(1/d) (thesis eq. 4.34).  MLS uses the gather convention
(weights W(x_k - x_i, h_i), SPEC §13.1 item 2); kernel approximations the pair mean h_ij.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools

import jax
import jax.extend.core as jex
import jax.numpy as jnp

from ..errors import InputError
from ..kernels import get_kernel
from ..registry import Registry
from ..state import minimum_image, tiny
from . import basis, mls

APPROXIMATIONS: Registry = Registry("scheme.approximation", protocol=("build", "basis_degree", "has_coeffs"),
                                    doc="shape functions on the stencil")

DERIVATIVES = ("full", "fixed_centre")


@dataclasses.dataclass(frozen=True)
class ApproxSpec:
    """Static, hashable choice of approximation (a jit static argument).

    ``rcond`` is the pivot-ratio threshold of the MLS degree fallback (see :mod:`.mls`);
    ``wall_rcond`` (None: not used) the threshold of the particles whose stencil a boundary
    truncates (:func:`pivot_thresholds`, docs/architecture.md decision 77).
    """

    approximation: str = "mls"
    degree: int = 2
    kernel: str = "cubic_spline"
    derivative: str = "full"
    rcond: float = 1e-6
    with_coeffs: bool = False
    wall_rcond: float | None = None

    def __post_init__(self):
        APPROXIMATIONS.get(self.approximation, "approximation")
        get_kernel(self.kernel)
        if not isinstance(self.degree, int) or isinstance(self.degree, bool) or not 0 <= self.degree <= 3:
            raise InputError(f"invalid degree={self.degree!r}; allowed: an integer in 0..3")
        if self.derivative not in DERIVATIVES:
            raise InputError(f"invalid derivative={self.derivative!r}; allowed: {', '.join(DERIVATIVES)}")
        if not (0.0 <= self.rcond < 1.0):
            raise InputError(f"invalid rcond={self.rcond!r}; allowed: 0 <= rcond < 1")
        if self.wall_rcond is not None and not (0.0 <= self.wall_rcond < 1.0):
            raise InputError(f"invalid wall_rcond={self.wall_rcond!r}; allowed: 0 <= wall_rcond < 1, or None")

    @property
    def truncated_rcond(self) -> float | None:
        """The threshold of truncated stencils when it differs from ``rcond`` (else None):
        ``max(rcond, wall_rcond)``, so it never lowers the threshold below ``rcond``."""
        if self.wall_rcond is None or self.wall_rcond <= self.rcond:
            return None
        return float(self.wall_rcond)

    @property
    def mls_degree(self) -> int | None:
        """Polynomial basis degree of the approximation (``shepard``: 0; kernel methods: None)."""
        return APPROXIMATIONS.get(self.approximation).basis_degree(self.degree)

    @property
    def is_mls(self) -> bool:
        """Whether the shape functions come from an MLS fit (and can provide fit coefficients)."""
        return APPROXIMATIONS.get(self.approximation).has_coeffs


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ShapeOperators:
    """Shape-function data on the stencil (a pytree).

    values[N, K], gradients[N, K, d]: N_j(x_i) and grad N_j(x_i) for j = idx[i, k] (zero on
    padding); coeffs[N, m, K] (MLS only, else None): fixed-centre coefficients C_i so that the
    fitted polynomial of stencil data u is p((y - x_i)/h_i)^T C_i u_S; h[N]: smoothing length of
    each particle (gather); degree[N]: the degree the gradients reproduce at each particle after
    fallback: MLS the active degree (:mod:`.mls`), ``corrected`` 1 (renormalised gradient) or 0
    (kernel-gradient fallback), ``kernel`` -1 (none; :mod:`mlsph_jax.fallback`).
    """

    values: jax.Array
    gradients: jax.Array
    coeffs: jax.Array | None
    h: jax.Array
    degree: jax.Array


def smoothing_length(vol, beta: float, dim: int):
    """h_i = beta * V_i^(1/d)  (thesis eq. 4.34, T:L1185)."""
    return beta * vol ** (1.0 / dim)


def pair_offsets(x, idx, mask, box_length=None, periodic=None):
    """dx[i, k] = x_j - x_i (minimum image), zero on padding slots.

    Component by component (:func:`minimum_image` on one axis at a time, bitwise the same): the
    whole-vector form made XLA:CPU materialise the broadcast ``x[:, None, :]`` as an [N, K, d]
    array, a pass over the stencil of its own in every moving stage (docs/performance.md)."""
    n, d = x.shape
    j = jnp.where(mask, idx, jnp.arange(n)[:, None])
    wrap = box_length is not None and periodic is not None
    cols = []
    for a in range(d):
        xa = x[:, a]
        da = (xa[j] - xa[:, None])[..., None]
        if wrap:
            da = minimum_image(da, jnp.asarray(box_length)[a:a + 1], jnp.asarray(periodic)[a:a + 1])
        cols.append(jnp.where(mask, da[..., 0], 0.0))
    return jnp.stack(cols, axis=-1)


#: Target number of stencil slots (rows x K) per block of the batched passes: the per-block
#: temporaries (a few dozen [rows, K] planes) then stay in the CPU caches.
BLOCK_SLOTS = 40960


#: Rows per block of the vmapped per-particle path (bases above ``mls.UNROLL_MAX``).
VMAP_BLOCK_ROWS = 2048


def block_rows(n: int, k: int) -> int:
    """Rows per block for arrays of ``n`` rows and ``k`` slots: the fewest blocks of at most
    :data:`BLOCK_SLOTS` slots, their rows balanced (ceil(n / blocks)).  The last block of
    :func:`row_blocks` is clamped to end at row ``n`` and recomputes the rows it shares with its
    predecessor: with unbalanced blocks (``BLOCK_SLOTS // k`` rows each) that was up to a whole
    block, e.g. 2 x 1,517 rows for 2,500 particles at K = 27 (21 % of the pair sweep and the fit
    pass done twice); balanced, fewer rows than there are blocks (docs/performance.md,
    "Per-step overhead at 2,500 particles")."""
    return balanced_rows(n, BLOCK_SLOTS // max(k, 1))


def balanced_rows(n: int, cap: int) -> int:
    """Rows per block for ``n`` rows in the fewest blocks of at most ``cap`` rows (at least one
    row per block), balanced: ceil(n / blocks) (:func:`block_rows`; at least 1, also for
    ``n = 0`` or ``cap = 0``)."""
    blocks = max(1, -(-n // max(cap, 1)))
    return max(1, -(-n // blocks))


#: Whether :func:`row_blocks` rematerialises each block in reverse mode (see there); switched
#: by :func:`block_remat` at trace time.
_REMAT_BLOCKS = True


@contextlib.contextmanager
def block_remat(enabled: bool):
    """Trace-time switch of the per-block rematerialisation of :func:`row_blocks` (default on).

    It only changes how reverse mode stores a block's intermediates, never a value: the forward
    program is the same and gradients agree to round-off (tests/test_gradient_cost.py).  Functions
    traced (``jit``, ``grad``) inside the ``with`` use the setting; ``jax.jit`` caches earlier traces."""
    global _REMAT_BLOCKS
    old, _REMAT_BLOCKS = _REMAT_BLOCKS, bool(enabled)
    try:
        yield
    finally:
        _REMAT_BLOCKS = old


def _remat_block(fn):
    """``fn(*args)`` under ``jax.checkpoint``: reverse mode keeps only the block's inputs (its rows
    of arrays that exist anyway, or the start row) and recomputes its fused forward, in cache, just
    before its transpose, instead of writing every [rows, K] temporary of every block to memory and
    reading it back.  ``prevent_cse=False``: the block runs inside a loop (or once), where JAX's
    CSE concern does not arise, and the forward program stays the plain one."""
    return jax.checkpoint(fn, prevent_cse=False)


#: Whether :func:`row_blocks` differentiates through scanned blocks (see there); switched by
#: :func:`block_scan` at trace time.
_SCAN_BLOCKS = True


@contextlib.contextmanager
def block_scan(enabled: bool):
    """Trace-time switch of how :func:`row_blocks` is differentiated (default on).

    On: the forward program is the loop over ``dynamic_slice`` row blocks, derivatives (forward
    and reverse mode) are those of the same blocks run as the steps of a ``lax.scan`` over stacked
    rows.  Off: the loop itself is differentiated, whose pullback costs blocks x N (see
    :func:`row_blocks`).  It never changes a value: the blocks are the same operations and the
    gradients agree to round-off (tests/test_gradient_cost.py)."""
    global _SCAN_BLOCKS
    old, _SCAN_BLOCKS = _SCAN_BLOCKS, bool(enabled)
    try:
        yield
    finally:
        _SCAN_BLOCKS = old


def _row_lookup(row_args, blocks):
    """``rows(a)``: the block's rows of ``a``, which must be one of ``row_args`` (the same object)."""
    lookup = {id(a): blk for a, blk in zip(row_args, blocks, strict=True)}

    def rows(a):
        try:
            return lookup[id(a)]
        except KeyError:
            raise ValueError("row_blocks: rows() of an array not passed in row_args") from None

    return rows


def _slices(arrays, start, size):
    return tuple(jax.lax.dynamic_slice_in_dim(a, start, size, 0) for a in arrays)


def _loop_blocks(fn, n, block, outputs):
    """The blocks as a ``fori_loop``, ``fn(start)`` reading its rows by ``dynamic_slice``, the
    results written by ``dynamic_update_slice`` (the forward program)."""
    nb = -(-n // block)

    def body(b, outs):
        start = jnp.minimum(b * block, n - block)
        return tuple(jax.lax.dynamic_update_slice_in_dim(o, r.astype(o.dtype), start, 0)
                     for o, r in zip(outs, fn(start), strict=True))

    init = tuple(jnp.zeros(shape, dtype) for shape, dtype in outputs)
    return jax.lax.fori_loop(0, nb, body, init)


def _scan_blocks(fn, n, block, outputs, row_args):
    """The blocks as the steps of a ``lax.scan`` over the stacked rows ``[blocks, size, ...]``,
    ``fn(rows)``; the results assembled from the stacked outputs.  Stacking is one concatenate
    of the leading full blocks and the clamped last block, then a reshape (no gather: its index
    array would be constant-folded at compile time, slowly), and the assembly the reverse."""
    nb = -(-n // block)
    head = (nb - 1) * block

    def stack(a):
        return jnp.concatenate([a[:head], a[n - block:]]).reshape((nb, block) + a.shape[1:])

    def body(carry, blocks):
        return carry, tuple(r.astype(dtype) for r, (_, dtype) in zip(fn(blocks), outputs, strict=True))

    _, ys = jax.lax.scan(body, None, tuple(stack(a) for a in row_args))
    return tuple(jnp.concatenate([y[:-1].reshape((head,) + y.shape[2:]), y[-1][head - (n - block):]])
                 for y in ys)


def _closure_convert(fn, example):
    """``(conv, consts)``: ``conv(blocks, *consts) == fn(blocks)`` with every tracer ``fn`` closes
    over (of any dtype) as an explicit argument in ``consts``.

    Unlike ``jax.closure_convert``, which keeps closed-over values that cannot carry a tangent
    (integer and boolean arrays) inside the traced jaxpr, this hoists every tracer: a
    ``custom_jvp`` rule can be traced after the trace that made them has ended (under
    ``jax.checkpoint``), and a tracer left inside would then leak."""
    cj = jax.make_jaxpr(fn)(example)
    hoist = [isinstance(c, jax.core.Tracer) for c in cj.consts]
    fixed = [c for c, h in zip(cj.consts, hoist, strict=True) if not h]

    def conv(blocks, *cs):
        it_fixed, it_cs = iter(fixed), iter(cs)
        consts = [next(it_cs) if h else next(it_fixed) for h in hoist]
        return tuple(jex.jaxpr_as_fun(jex.ClosedJaxpr(cj.jaxpr, consts))(*jax.tree.leaves(blocks)))

    return conv, [c for c, h in zip(cj.consts, hoist, strict=True) if h]


def row_blocks(fn, n: int, block: int, outputs, row_args=()):
    """Run ``fn(size, rows) -> tuple of [size, ...] arrays`` over row blocks of ``n`` rows.

    ``outputs`` lists the ``(shape, dtype)`` of the assembled ``[n, ...]`` results.
    ``row_args`` are the ``[n, ...]`` arrays ``fn`` reads row-wise: inside ``fn``, ``rows(a)`` is
    the block's rows of ``a`` (``a`` must be one of ``row_args``, the same object); anything else
    ``fn`` reads whole (e.g. to gather neighbours) it closes over.  The last block is clamped to
    end at row ``n`` and so recomputes, identically, a few rows of its predecessor.  With
    ``block >= n`` this is a single call.

    The forward program visits the blocks with a ``fori_loop`` that reads rows by
    ``dynamic_slice``.  Differentiated as such, the cotangent of a sliced loop-invariant array is
    a zero array of the whole shape plus an add per block, so a pullback costs blocks x N per
    array (quadratic in N).  So (:func:`block_scan`, default on) the loop is a ``jax.custom_jvp``
    whose derivative is that of the same blocks run as the steps of a ``lax.scan`` over stacked
    rows (one concatenate and reshape per array, :func:`_scan_blocks`; scanned rows transpose to
    stacked cotangents): the forward keeps the loop, which the stacking and the assembly of the
    outputs would slow, and reverse mode gets the scan (docs/performance.md,
    "Gradients").  The block function is closure-converted (:func:`_closure_convert`) so that the
    whole arrays it closes over are explicit arguments.

    In reverse mode each block is rematerialised (:func:`block_remat`, default on): the
    gradient of a right-hand side then costs about half of what storing the per-block
    intermediates costs (docs/performance.md, "Gradients").
    """
    row_args = tuple(row_args)

    def call(blocks, size=block):
        return tuple(fn(size, _row_lookup(row_args, blocks)))

    remat = _remat_block if _REMAT_BLOCKS else (lambda f: f)
    if block >= n:
        return tuple(r.astype(dtype) for r, (_, dtype) in
                     zip(remat(functools.partial(call, size=n))(row_args), outputs, strict=True))
    if not _SCAN_BLOCKS:
        return _loop_blocks(remat(lambda s: call(_slices(row_args, s, block))), n, block, outputs)
    conv, consts = _closure_convert(call, tuple(a[:block] for a in row_args))

    def loop(args, cs):
        return _loop_blocks(lambda s: conv(_slices(args, s, block), *cs), n, block, outputs)

    blocked = jax.custom_jvp(loop)

    @blocked.defjvp
    def _(primals, tangents):
        def scanned(args, cs):
            return _scan_blocks(remat(lambda b: conv(b, *cs)), n, block, outputs, args)

        return jax.jvp(scanned, primals, tangents)

    return blocked(row_args, tuple(consts))


@functools.partial(jax.jit, static_argnames=("spec",))
def build(x, h, vol, idx, mask, spec: ApproxSpec, box_length=None, periodic=None) -> ShapeOperators:
    """Shape-function operators for all particles (jit-able; ``spec`` is static).

    Arguments: positions x[N, d], smoothing lengths h[N], volumes vol[N], neighbour indices
    idx[N, K] (padding value N) and mask[N, K] from :mod:`mlsph_jax.neighbors`, optional periodic
    box lengths and periodic flags (arrays of length d).
    """
    dx = pair_offsets(x, idx, mask, box_length, periodic)
    return build_from_offsets(dx, h, vol, idx, mask, spec)


def build_from_offsets(dx, h, vol, idx, mask, spec: ApproxSpec, *,
                       coeffs_only: bool = False) -> ShapeOperators:
    """:func:`build` with the offsets ``dx = pair_offsets(...)`` already computed (not jitted).

    ``coeffs_only`` (MLS with coefficients): skip assembling values and gradients (returned as
    ``None``) when only the fit coefficients are needed.
    """
    return APPROXIMATIONS.get(spec.approximation, "approximation").build(dx, h, vol, idx, mask, spec,
                                                                         coeffs_only=coeffs_only)


#: A stencil whose kernel sum sum_j V_j W(x_j - x_i, h_i) is below this is *truncated* (a support
#: cut by a boundary-integral wall or a free boundary; decision 77): its MLS fit uses
#: ``ApproxSpec.truncated_rcond``.  Complete supports are within a few per cent of 1 (lattices
#: 1.003, the graded polar rings 0.998-1.003; mirror ghosts and frozen far-field particles complete
#: the wall and outer rows; the shipped moving runs >= 0.983); a row half a spacing from a straight
#: or curved wall 0.53-0.76 (experiments/one_sided_fits.py).  Strongly disordered complete
#: stencils can fall below the cut (a lattice jittered by 0.3 dx: down to 0.84-0.85 in a few per
#: cent of the rows) and then take ``truncated_rcond`` too; so does a Lagrangian 1D end particle
#: that leaves the frozen ends behind (riemann_r2_tammann: 0.66).
TRUNCATED_FILL = 0.9


def fill_thresholds(fill, spec: ApproxSpec):
    """Per-particle pivot-ratio thresholds of the MLS degree fallback from the kernel sums
    ``fill`` (decision 77): ``spec.truncated_rcond`` where the stencil is truncated (``fill`` <
    :data:`TRUNCATED_FILL`), ``spec.rcond`` elsewhere.  Carries no gradient (it picks a degree, as
    the pivot test does)."""
    fill = jax.lax.stop_gradient(fill)
    return jnp.where(fill < TRUNCATED_FILL, spec.truncated_rcond, spec.rcond).astype(fill.dtype)


def pivot_thresholds(dx, vol_j, mask, h, kernel, spec: ApproxSpec):
    """:func:`fill_thresholds` ``[B]`` of stencils ``dx[B, K, d]`` with neighbour volumes
    ``vol_j[B, K]``, ``mask[B, K]``, ``h[B]`` (kernel sum sum_k V_k W(|dx_k|, h))."""
    fill = jnp.sum(jnp.where(mask, vol_j * kernel.w_vec(dx, h[:, None]), 0.0), axis=1)
    return fill_thresholds(fill, spec)


def _mls_operators(dx, h, vol, idx, mask, spec: ApproxSpec, coeffs_only: bool) -> ShapeOperators:
    """MLS shape functions of degree ``spec.mls_degree`` (:mod:`.mls`), blocked over rows; the
    per-particle pivot thresholds of :func:`fill_thresholds` when ``spec.truncated_rcond`` is set."""
    kern = get_kernel(spec.kernel)
    n, k, d = dx.shape
    q = spec.mls_degree
    m = basis.basis_size(q, d)
    vol_j = None if spec.truncated_rcond is None else jnp.where(mask, vol[jnp.where(mask, idx, 0)], 0.0)
    small = m <= mls.UNROLL_MAX

    row_args = (dx, mask, h) + (() if vol_j is None else (vol_j,))

    def rc(rows):
        if vol_j is None:
            return {}
        if small:   # the block's own kernel weights give the sums (no second kernel pass)
            return {"vol_j": rows(vol_j), "thresholds": functools.partial(fill_thresholds, spec=spec)}
        return {"rcond": pivot_thresholds(rows(dx), rows(vol_j), rows(mask), rows(h), kern, spec)}
    if small:
        # unrolled small bases, whole row blocks at once
        f = functools.partial(mls.operators_block, kernel=kern, degree=q, rcond=spec.rcond,
                              derivative=spec.derivative, with_coeffs=spec.with_coeffs)
        block = block_rows(n, k)
        if coeffs_only and spec.with_coeffs:
            f = functools.partial(f, derivative="fixed_centre")

            def cblk(b, rows):
                _, _, coeffs, deg = f(rows(dx), rows(mask), rows(h), **rc(rows))
                return deg, coeffs

            deg, coeffs = row_blocks(cblk, n, block, [((n,), jnp.int32), ((n, m, k), dx.dtype)], row_args)
            return ShapeOperators(None, None, coeffs, h, deg)
    else:
        # large bases (3D cubic, m = 20): per-particle solves, vmapped over row blocks so the
        # working set (a few [rows, K, m] planes with d tangents) stays bounded for any N
        f = jax.vmap(functools.partial(mls.particle_operators, kernel=kern, degree=q,
                                       rcond=spec.rcond, derivative=spec.derivative,
                                       with_coeffs=spec.with_coeffs))
        block = max(block_rows(n, k), balanced_rows(n, VMAP_BLOCK_ROWS))
    outputs = [((n, k), dx.dtype), ((n, k, d), dx.dtype), ((n,), jnp.int32)]
    if spec.with_coeffs:
        outputs.append(((n, m, k), dx.dtype))

    def blk(b, rows):
        values, grads, coeffs, deg = f(rows(dx), rows(mask), rows(h), **rc(rows))
        return (values, grads, deg) + ((coeffs,) if spec.with_coeffs else ())

    out = row_blocks(blk, n, block, outputs, row_args)
    return ShapeOperators(out[0], out[1], out[3] if spec.with_coeffs else None, h, out[2])


def _kernel_operators(dx, h, vol, idx, mask, spec: ApproxSpec, corrected: bool) -> ShapeOperators:
    """Kernel shape functions W(x_i - x_j, h_ij) V_j, or (``corrected``) Shepard values with the
    renormalised gradient (module docstring)."""
    kern = get_kernel(spec.kernel)
    n = dx.shape[0]
    jsafe = jnp.where(mask, idx, jnp.arange(n)[:, None])
    hij = 0.5 * (h[:, None] + h[jsafe])
    vj = jnp.where(mask, vol[jsafe], 0.0)
    w = kern.w_vec(dx, hij) * vj
    kgrad = kern.grad(-dx, hij) * vj[..., None]  # grad_x W(x - x_j) at x = x_i
    none_deg = jnp.full((n,), -1, jnp.int32)
    if not corrected:
        return ShapeOperators(w, kgrad, None, h, none_deg)

    # corrected: Shepard values, renormalised gradients with the partition of nullity
    values = w / jnp.sum(w, axis=1, keepdims=True)
    E = jnp.einsum("nka,nkb->nab", kgrad, dx)  # sum_j V_j dW_ij/dx^a (x_j - x_i)^b
    d = dx.shape[2]
    det = jnp.linalg.det(E)
    scale = jnp.prod(jnp.abs(jnp.diagonal(E, axis1=1, axis2=2)), axis=1)
    good = jax.lax.stop_gradient(jnp.abs(det) > 1e-8 * jnp.maximum(scale, tiny(scale.dtype)))
    Esafe = jnp.where(good[:, None, None], E, jnp.eye(d))
    B = jnp.linalg.inv(Esafe)
    g = jnp.einsum("nab,nkb->nka", B, kgrad)
    is_self = idx == jnp.arange(n)[:, None]
    g = jnp.where(is_self[..., None], 0.0, g)
    g = g - is_self[..., None] * jnp.sum(g, axis=1, keepdims=True)
    g = jnp.where(good[:, None, None], g, kgrad - is_self[..., None] * jnp.sum(kgrad, axis=1, keepdims=True))
    return ShapeOperators(values, g, None, h, good.astype(jnp.int32))   # 1 renormalised, 0 kernel fallback


@dataclasses.dataclass(frozen=True)
class MLSApproximation:
    """Moving least squares of degree ``scheme.degree`` (or a fixed degree: ``shepard`` is MLS with
    the constant basis), full or fixed-centre derivative, per-particle degree fallback (:mod:`.mls`)."""

    fixed_degree: int | None = None
    has_coeffs: bool = True

    def basis_degree(self, degree: int) -> int:
        return self.fixed_degree if self.fixed_degree is not None else degree

    def nominal_degree(self, degree: int) -> int:
        """Degree of the shape functions without fallback (:mod:`mlsph_jax.fallback`)."""
        return self.basis_degree(degree)

    def build(self, dx, h, vol, idx, mask, spec: ApproxSpec, coeffs_only: bool = False) -> ShapeOperators:
        return _mls_operators(dx, h, vol, idx, mask, spec, coeffs_only)


@dataclasses.dataclass(frozen=True)
class KernelApproximation:
    """Plain SPH kernel shape functions N_j = W(x - x_j, h_ij) V_j, or (``corrected``) the
    Randles-Libersky renormalised gradient with Shepard values."""

    corrected: bool = False
    has_coeffs: bool = False

    def basis_degree(self, degree: int) -> None:
        return None

    def nominal_degree(self, degree: int) -> int | None:
        """Degree the gradient reproduces without fallback: 1 (``corrected``), none (``kernel``)."""
        return 1 if self.corrected else None

    def build(self, dx, h, vol, idx, mask, spec: ApproxSpec, coeffs_only: bool = False) -> ShapeOperators:
        return _kernel_operators(dx, h, vol, idx, mask, spec, self.corrected)


APPROXIMATIONS.register("mls", MLSApproximation())
APPROXIMATIONS.register("shepard", MLSApproximation(fixed_degree=0))
APPROXIMATIONS.register("kernel", KernelApproximation())
APPROXIMATIONS.register("corrected", KernelApproximation(corrected=True))


def fit(ops: ShapeOperators, idx, mask, field):
    """Per-particle polynomial coefficients a_i = C_i u_S of ``field[N, ...]`` -> ``[N, m, ...]``."""
    if ops.coeffs is None:
        raise InputError("fit() needs coefficients; build with ApproxSpec(approximation='mls', "
                         "with_coeffs=True)")
    n = field.shape[0]
    j = jnp.where(mask, idx, jnp.arange(n)[:, None])
    u = field[j]  # [N, K, ...]
    return jnp.einsum("nmk,nk...->nm...", ops.coeffs, u)


def evaluate_fit(a, h, offset, degree: int):
    """Value and gradient of the fitted polynomials at ``x_i + offset``.

    a[N, m, ...] from :func:`fit` (or any leading batch shape matching ``offset[..., d]``),
    h[...] the owner's smoothing length.  Returns ``(value[..., ...], gradient[..., d, ...])``.
    """
    xi = offset / h[..., None]
    P = basis.evaluate(xi, degree)  # [..., m]
    G = basis.gradient(xi, degree) / h[..., None, None]  # [..., m, d]
    value = jnp.einsum("...m,...m->...", P, a) if a.ndim == P.ndim else jnp.einsum("...m,...mv->...v", P, a)
    if a.ndim == P.ndim:
        grad = jnp.einsum("...md,...m->...d", G, a)
    else:
        grad = jnp.einsum("...md,...mv->...dv", G, a)
    return value, grad


def interpolate(ops: ShapeOperators, idx, mask, field):
    """sum_k N_j(x_i) field_j — the approximation of ``field[N, ...]`` at the particles."""
    n = field.shape[0]
    j = jnp.where(mask, idx, jnp.arange(n)[:, None])
    return jnp.einsum("nk,nk...->n...", ops.values, field[j])


def gradient(ops: ShapeOperators, idx, mask, field):
    """sum_k grad N_j(x_i) (field_j - field_i) -> ``[N, d, ...]`` (thesis eq. 5.105-5.107)."""
    n = field.shape[0]
    j = jnp.where(mask, idx, jnp.arange(n)[:, None])
    diff = field[j] - field[:, None]
    return jnp.einsum("nkd,nk...->nd...", ops.gradients, diff)
