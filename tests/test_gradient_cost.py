"""Cheaper gradients (issue 15 item 4): the per-block rematerialisation of the stencil passes
(:func:`mlsph_jax.approximation.block_remat`) changes what reverse mode stores, never a value.
Gradients with it equal the stored-intermediates gradients (the previous behaviour) to 1e-10, on
row blocks small enough that every pass runs as a loop of several blocks (the clamped last block
included), for the Eulerian frame (geometry fixed) and for moving particles (lists, MLS solves and
area vectors differentiated every stage); and the forward program is the same."""

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


def _rhs_loss(pb, remat: bool):
    """(mu, q, x) -> sum of weighted right-hand-side outputs, geometry (neighbour offsets, MLS
    solves, area vectors, reconstruction fit) rebuilt from x: every blocked pass differentiated."""
    from mlsph_jax.rhs import geometry, rhs
    from mlsph_jax.run import setup_run

    nl = setup_run(pb, headroom=1.6).nl
    p = pb.particles
    w = [jnp.cos(0.37 * jnp.arange(a.size, dtype=float)).reshape(a.shape) for a in (p.x, p.vol, p.q)]

    def loss(mu, q, x):
        with apx.block_remat(remat):
            geom = geometry(x, p.vol, nl, pb.scheme, pb.domain)
            out = rhs(p.replace(q=q, x=x), with_param(pb.params, "physics.mu", mu), geom, pb.scheme, pb.boundary)
        return sum(jnp.sum(a * b) for a, b in zip(w, out, strict=True))

    return loss


def _compare(pb, argnums, names):
    p = pb.particles
    args = (pb.params["physics.mu"], p.q, p.x)
    on, off = (jax.jit(jax.grad(_rhs_loss(pb, r), argnums=argnums))(*args) for r in (True, False))
    for a, b, name in zip(on, off, names, strict=True):
        a, b = np.asarray(a), np.asarray(b)
        scale = np.max(np.abs(b))
        assert scale > 0 and np.all(np.isfinite(a)), name
        assert np.max(np.abs(a - b)) <= 1e-10 * scale, (name, np.max(np.abs(a - b)) / scale)


@pytest.mark.parametrize("frame", ["eulerian",
                                   # CI time (21 s); the slow geometry test below covers ale_shift with x too
                                   pytest.param("ale_shift", marks=pytest.mark.slow)])
def test_block_remat_gradient_of_a_right_hand_side_equals_the_stored_gradient(small_blocks, frame):
    """Gradient of a right-hand side w.r.t. viscosity and conserved fields (the reconstruction
    fit and flux passes, in blocks): block rematerialisation on and off agree to 1e-10 of the
    gradient's scale (measured ~1e-16: the same operations, transposed in another order)."""
    pb = _taylor_green(8, frame)
    assert _blocks_per_pass(pb) >= 3
    _compare(pb, (0, 1), ("mu", "q"))


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


def test_block_remat_keeps_the_forward_program(small_blocks):
    """The rematerialisation only exists under differentiation: the compiled right-hand side
    (with its geometry) is instruction for instruction the same with it on and off, so forward
    runs and their fingerprints cannot move."""
    import re

    pb = _taylor_green(8, "ale_shift")
    p = pb.particles
    texts = []
    for remat in (True, False):
        hlo = jax.jit(_rhs_loss(pb, remat)).lower(pb.params["physics.mu"], p.q, p.x).compile().as_text()
        texts.append([re.sub(r"metadata=\{[^}]*\}", "", line) for line in hlo.splitlines()
                      if re.match(r"\s+(ROOT )?%", line)])
    assert len(texts[0]) > 100 and texts[0] == texts[1]


def test_block_remat_is_a_trace_time_switch():
    """block_remat restores the previous setting, also on error, and the default is on."""
    assert apx._REMAT_BLOCKS is True
    with pytest.raises(RuntimeError), apx.block_remat(False):
        assert apx._REMAT_BLOCKS is False
        raise RuntimeError
    assert apx._REMAT_BLOCKS is True
    f = apx._remat_block(lambda s, b: (jnp.arange(b, dtype=float) * (1.0 + s),))
    np.testing.assert_array_equal(f(0, 3)[0], [0.0, 1.0, 2.0])
