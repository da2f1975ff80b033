"""Cheaper gradients (issue 15 item 4): the per-block rematerialisation of the stencil passes
(:func:`mlsph_jax.approximation.block_remat`) changes what reverse mode stores, and the
scanned-block derivative of the blocked passes (:func:`mlsph_jax.approximation.block_scan`) how
reverse mode transposes them, never a value.  Gradients with each equal the gradients without it
(the previous behaviour) to 1e-10, on row blocks small enough that every pass runs as a loop of
several blocks (the clamped last block included), for the Eulerian frame (geometry fixed) and for
moving particles (lists, MLS solves and area vectors differentiated every stage); they match
central finite differences; and the forward program is the same."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mlsph_jax.approximation as apx
from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.differentiable import make_simulate, with_param
from mlsph_jax.integrate import ssp_rk3_step
from mlsph_jax.run import setup_run

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def small_blocks(monkeypatch):
    """Blocks of ~64 slots, so that N = 64..100 particles give several blocks per pass."""
    monkeypatch.setattr(apx, "BLOCK_SLOTS", 64 * 10)


def _taylor_green(n: int, frame: str, degree: int = 2):
    over = [f"case.n={n}", "time.t_end=0.004", f"scheme.frame={frame}", f"scheme.reconstruction_degree={degree}",
            "case.layout=perturbed"]
    return build_problem(config.load(ROOT / "configs/taylor_green_2d.toml", over))


def _grads(pb, remat: bool, checkpoint: str, n_steps: int):
    sim = make_simulate(pb, n_steps=n_steps, checkpoint=checkpoint, record_every=1, remat_blocks=remat)

    def loss(mu, q, x):
        p = pb.particles.replace(q=q, x=x)
        return sim(with_param(pb.params, "physics.mu", mu), p).series["ke"][-1]

    p = pb.particles
    return jax.jit(jax.grad(loss, argnums=(0, 1, 2)))(pb.params["physics.mu"], p.q, p.x)


def _blocks_per_pass(pb) -> int:
    from mlsph_jax.run import setup_run

    k = setup_run(pb, headroom=1.6).nl.idx.shape[1]
    n = pb.particles.n
    return -(-n // apx.block_rows(n, k))


def _rhs_loss(pb, remat: bool, scan: bool = True):
    """(mu, q, x) -> sum of weighted right-hand-side outputs, geometry (neighbour offsets, MLS
    solves, area vectors, reconstruction fit) rebuilt from x: every blocked pass differentiated."""
    from mlsph_jax.rhs import geometry, rhs
    from mlsph_jax.run import setup_run

    nl = setup_run(pb, headroom=1.6).nl
    p = pb.particles
    w = [jnp.cos(0.37 * jnp.arange(a.size, dtype=float)).reshape(a.shape) for a in (p.x, p.vol, p.q)]

    def loss(mu, q, x):
        with apx.block_remat(remat), apx.block_scan(scan):
            geom = geometry(x, p.vol, nl, pb.scheme, pb.domain)
            out = rhs(p.replace(q=q, x=x), with_param(pb.params, "physics.mu", mu), geom, pb.scheme, pb.boundary)
        return sum(jnp.sum(a * b) for a, b in zip(w, out, strict=True))

    return loss


def _compare(pb, argnums, names, switch="remat"):
    p = pb.particles
    args = (pb.params["physics.mu"], p.q, p.x)
    variants = {"remat": ({"remat": True}, {"remat": False}),
                "scan": ({"remat": True, "scan": True}, {"remat": True, "scan": False}),
                "both": ({"remat": True, "scan": True}, {"remat": False, "scan": False})}[switch]
    on, off = (jax.jit(jax.grad(_rhs_loss(pb, **v), argnums=argnums))(*args) for v in variants)
    for a, b, name in zip(on, off, names, strict=True):
        a, b = np.asarray(a), np.asarray(b)
        scale = np.max(np.abs(b))
        assert scale > 0 and np.all(np.isfinite(a)), name
        assert np.max(np.abs(a - b)) <= 1e-10 * scale, (name, np.max(np.abs(a - b)) / scale)


@pytest.mark.parametrize("frame", ["eulerian",
                                   # CI time (21 s); the slow geometry test below covers ale_shift with x too
                                   pytest.param("ale_shift", marks=pytest.mark.slow)])
def test_block_remat_and_scan_gradient_of_a_right_hand_side_equals_the_plain_gradient(small_blocks, frame):
    """Gradient of a right-hand side w.r.t. viscosity and conserved fields (the reconstruction
    fit and flux passes, in blocks): the default (rematerialised blocks, scanned-block derivative)
    and the plain differentiated loop that stores every block's intermediates agree to 1e-10 of
    the gradient's scale (measured ~1e-16: the same operations, transposed in another order).
    One comparison for both switches (CI time); the slow tests below take each alone."""
    pb = _taylor_green(8, frame)
    assert _blocks_per_pass(pb) >= 3
    _compare(pb, (0, 1), ("mu", "q"), switch="both")


@pytest.mark.slow
def test_block_remat_gradient_of_a_right_hand_side_equals_the_stored_gradient(small_blocks):
    """Block rematerialisation alone (the loop differentiated): on and off agree to 1e-10."""
    pb = _taylor_green(8, "eulerian")
    _compare(pb, (0, 1), ("mu", "q"), switch="remat")


@pytest.mark.slow
def test_block_scan_gradient_through_the_geometry_equals_the_loop_gradient(small_blocks):
    """The scanned-block derivative (default) against differentiating the loop of row blocks
    itself, w.r.t. viscosity, conserved fields and positions of a moving run (the blocked MLS
    solves and area vectors of the geometry, the reconstruction fit, the flux sweep): equal to
    1e-10 of each gradient's scale (~75 s: two compilations of the geometry's gradient)."""
    pb = _taylor_green(8, "ale_shift")
    assert _blocks_per_pass(pb) >= 3
    _compare(pb, (0, 1, 2), ("mu", "q", "x"), switch="scan")


@pytest.mark.slow
def test_block_scan_gradient_matches_finite_differences(small_blocks):
    """Directional derivatives of the scanned-block gradient of a moving run's right-hand side
    (with its geometry) along random directions in mu, q and x match central differences of the
    forward program to 1e-6 (steps measured to sit between truncation and round-off: relative
    agreement 6e-13 (mu), 1e-8 (q), 2e-7 (x); the flux's kinks make larger q steps disagree)."""
    pb = _taylor_green(8, "ale_shift")
    p = pb.particles
    loss = jax.jit(_rhs_loss(pb, True, True))
    args = (jnp.asarray(pb.params["physics.mu"]), p.q, p.x)
    grads = jax.jit(jax.grad(_rhs_loss(pb, True, True), argnums=(0, 1, 2)))(*args)
    rng = np.random.default_rng(3)
    # direction scales and relative steps: mu, q (max |q|), x (particle spacing)
    scales = (float(args[0]), float(jnp.max(jnp.abs(p.q))), float(jnp.min(p.vol)) ** 0.5)
    for which, eps in zip(range(3), (1e-4, 1e-8, 1e-6), strict=True):
        v = rng.standard_normal(np.shape(args[which])) * scales[which]
        ad = float(np.sum(np.asarray(grads[which]) * v))
        plus = [a + eps * v if i == which else a for i, a in enumerate(args)]
        minus = [a - eps * v if i == which else a for i, a in enumerate(args)]
        fd = float(loss(*plus) - loss(*minus)) / (2 * eps)
        assert abs(ad) > 0 and abs(ad - fd) <= 1e-6 * abs(ad), (which, ad, fd)


def _toy_blocks(n: int = 23, k: int = 5, block: int = 7):
    """A blocked pass shaped like the flux sweep: float and integer row arguments, neighbour
    gathers of whole arrays it closes over (among them an integer one), a float and an integer
    output; 4 blocks of 7 rows for 23 rows (the last one clamped)."""
    rng = np.random.default_rng(0)
    idx = jnp.asarray(rng.integers(0, n, (n, k)), jnp.int32)

    def f(x, w, idx):
        shift = jnp.roll(idx, 1, axis=0)              # an integer array the block closes over

        def blk(b, rows):
            xi, jb = rows(x), rows(idx)
            r = jnp.sum(jnp.sin(x[jb] - xi[:, None, :]) * (w[jb] * w[shift[jb[:, 0]]])[..., None], axis=1)
            return r + xi ** 3, jnp.sum(jb, axis=1)

        r, deg = apx.row_blocks(blk, n, block, [((n, 2), x.dtype), ((n,), jnp.int32)], (x, idx))
        return jnp.sum(jnp.cos(r) * jnp.arange(2 * n, dtype=r.dtype).reshape(n, 2)) + jnp.sum(deg), deg

    x = jnp.asarray(rng.standard_normal((n, 2)))
    w = jnp.asarray(rng.uniform(0.5, 1.5, n))
    return f, x, w, idx


def test_block_scan_of_a_toy_pass_equals_the_loop_in_forward_and_reverse_mode():
    """The scanned-block derivative of a blocked pass with closed-over gathers and integer rows
    and outputs: values identical to the loop, reverse mode (grad, also of a jax.checkpoint as in
    the differentiated runs, whose derivative rules are traced after the forward trace has ended)
    equal to the differentiated loop to 1e-12, forward mode (jacfwd) equal to reverse mode, and
    both equal to central differences."""
    f, x, w, idx = _toy_blocks()
    loss = lambda x, w, idx: f(x, w, idx)[0]  # noqa: E731
    res = {}
    for scan in (True, False):
        with apx.block_scan(scan):
            val, deg = jax.jit(f)(x, w, idx)
            g = jax.jit(jax.grad(loss, argnums=(0, 1)))(x, w, idx)
            gc = jax.jit(jax.grad(jax.checkpoint(loss), argnums=(0, 1)))(x, w, idx)
            jf = jax.jit(jax.jacfwd(loss, argnums=(0, 1)))(x, w, idx)
        res[scan] = (val, g + gc, jf)
        np.testing.assert_array_equal(deg, np.sum(np.asarray(idx), axis=1))
    assert res[True][0] == res[False][0]
    for a, b in zip(res[True][1] + res[True][2], res[False][1] + res[False][1][:2], strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * float(np.max(np.abs(b))))
    rng = np.random.default_rng(1)
    vx, vw = rng.standard_normal(x.shape), rng.standard_normal(w.shape)
    eps = 1e-6
    fd = (loss(x + eps * vx, w + eps * vw, idx) - loss(x - eps * vx, w - eps * vw, idx)) / (2 * eps)
    ad = np.sum(res[True][1][0] * vx) + np.sum(res[True][1][1] * vw)
    assert abs(ad - fd) <= 1e-8 * abs(ad), (ad, fd)


@pytest.mark.slow
def test_block_remat_gradient_through_the_geometry_equals_the_stored_gradient(small_blocks):
    """The same w.r.t. positions too, i.e. through the blocked MLS solves and area vectors of the
    geometry a moving run rebuilds every stage (slow: ~20 s of compilation per variant)."""
    pb = _taylor_green(8, "ale_shift")
    _compare(pb, (0, 1, 2), ("mu", "q", "x"))


@pytest.mark.slow
@pytest.mark.parametrize("frame,checkpoint", [("eulerian", "nested"), ("ale_shift", "step")])
def test_block_remat_run_gradient_equals_the_stored_gradient(small_blocks, frame, checkpoint):
    """Whole differentiated runs: d ke(t_end) / d(mu, initial q, initial x) with and without block
    rematerialisation agree to 1e-10 relative to each gradient's scale (~4 min on a loaded
    2-core machine: four compilations of a gradient of a run)."""
    pb = _taylor_green(8, frame)
    assert _blocks_per_pass(pb) >= 3
    on = _grads(pb, True, checkpoint, 4)
    off = _grads(pb, False, checkpoint, 4)
    for a, b, name in zip(on, off, ("mu", "q", "x"), strict=True):
        a, b = np.asarray(a), np.asarray(b)
        scale = np.max(np.abs(b))
        assert scale > 0 and np.all(np.isfinite(a)), name
        assert np.max(np.abs(a - b)) <= 1e-10 * scale, (name, np.max(np.abs(a - b)) / scale)


def test_block_switches_keep_the_forward_program(small_blocks):
    """The rematerialisation and the scanned blocks only exist under differentiation: the compiled
    right-hand side (with its geometry) is instruction for instruction the same with both on and
    both off, so forward runs and their fingerprints cannot move."""
    import re

    pb = _taylor_green(8, "ale_shift")
    p = pb.particles
    texts = []
    for on in (True, False):
        hlo = jax.jit(_rhs_loss(pb, on, on)).lower(pb.params["physics.mu"], p.q, p.x).compile().as_text()
        texts.append([re.sub(r"metadata=\{[^}]*\}", "", line) for line in hlo.splitlines()
                      if re.match(r"\s+(ROOT )?%", line)])
    assert len(texts[0]) > 100 and texts[0] == texts[1]


@pytest.mark.parametrize("switch,flag", [("block_remat", "_REMAT_BLOCKS"), ("block_scan", "_SCAN_BLOCKS")])
def test_block_switches_are_trace_time_switches(switch, flag):
    """block_remat / block_scan restore the previous setting, also on error; the default is on."""
    assert getattr(apx, flag) is True
    with pytest.raises(RuntimeError), getattr(apx, switch)(False):
        assert getattr(apx, flag) is False
        raise RuntimeError
    assert getattr(apx, flag) is True
    f = apx._remat_block(lambda b: (jnp.arange(3, dtype=float) * (1.0 + b),))
    np.testing.assert_array_equal(f(0.0)[0], [0.0, 1.0, 2.0])


def test_row_blocks_reads_rows_only_of_its_row_args():
    """rows() of an array that is not one of row_args is an error, not a silent whole read."""
    a, b = jnp.arange(10.0), jnp.arange(10.0)
    with pytest.raises(ValueError, match="row_args"):
        apx.row_blocks(lambda size, rows: (rows(b),), 10, 4, [((10,), a.dtype)], (a,))




@pytest.mark.parametrize("config_name,over", [
    ("taylor_green_2d", ["case.n=8"]),
    ("taylor_green_2d", ["case.n=8", "scheme.limiter=mood"]),
    ("lid_driven_cavity", ["case.n=8"]),
    pytest.param("taylor_green_2d", ["case.n=8", "scheme.frame=ale_shift"], marks=pytest.mark.slow)])  # ~2 min
def test_reverse_mode_stores_one_state_per_step_and_nothing_for_fixed_positions(config_name, over):
    """What a checkpointed differentiated run (``checkpoint="step"``) keeps per step: the state it
    carries, nothing else.  XLA's planned memory of the gradient grows with the step count by
    exactly the state a step reads per particle: q (nv * 8 bytes) for a frame that does not move
    its particles, x, vol and q for a moving one (the kind is constant).  The per-particle degrees
    are not stored: without MOOD they stay the initial ones (not carried), and MOOD resets them to
    the scheme's degree at every step's start, so the recomputed step does not read the carried
    ones (measured: 24.06 bytes with MOOD for q's 24).  Before, the
    diagnostics recorded after each step stored their inputs and intermediates (97 bytes per
    particle and step for the Tait Taylor-Green vortex in either frame), and fixed
    particles carried their positions and volumes.  Those stay the set-up values bit for bit
    through SSP-RK3 steps, mirror ghosts' included (the Shu-Osher combination a x + b x moved them
    by round-off)."""
    pb = build_problem(config.load(ROOT / f"configs/{config_name}.toml", over))
    p0, params, scheme = pb.particles, pb.params, pb.scheme
    n, nv = p0.q.shape

    geom_fn = setup_run(pb).geometry_fn(p0)
    step = jax.jit(lambda p: ssp_rk3_step(p, params, 1e-4, scheme, geom_fn, pb.boundary)[0])
    p = p0
    for _ in range(4):
        p = step(p)
    assert not np.array_equal(np.asarray(p.q), np.asarray(p0.q))
    assert np.array_equal(np.asarray(p.x), np.asarray(p0.x)) != scheme.moving
    if not scheme.moving:
        assert np.array_equal(np.asarray(p.vol), np.asarray(p0.vol))

    def simulate(steps):
        return make_simulate(pb, n_steps=steps, t_end=steps * 1e-4, checkpoint="step")

    out = jax.jit(simulate(4))(params, p0)
    assert int(out.status) == 0
    np.testing.assert_allclose(np.asarray(out.particles.q), np.asarray(p.q), rtol=0, atol=1e-14)

    def planned(steps):
        sim = simulate(steps)
        grad = jax.jit(jax.grad(lambda mu: sim(with_param(params, "physics.mu", mu), p0).series["ke"][-1]))
        ma = grad.lower(params["physics.mu"]).compile().memory_analysis()
        return ma.temp_size_in_bytes + ma.argument_size_in_bytes + ma.output_size_in_bytes

    assert scheme.component("limiter").needs_high_order == ("scheme.limiter=mood" in over)
    fields = ((p0.x, p0.vol) if scheme.moving else ()) + (p0.q,)
    state = sum(a.dtype.itemsize * a.size for a in fields) / n
    per_step = (planned(48) - planned(16)) / 32 / n
    assert state <= per_step <= state + 32 / n, (per_step, state)   # + the step counter and status words
