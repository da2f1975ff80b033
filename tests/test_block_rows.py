"""Row blocks of the blocked stencil passes are balanced (decision 93, docs/performance.md,
"Per-step overhead at 2,500 particles"): the clamped last block of ``row_blocks`` recomputes fewer
rows than there are blocks, never most of a block."""

import pytest

from mlsph_jax import approximation as apx


@pytest.mark.parametrize("n, k", [(2500, 27), (10_000, 27), (40_000, 31), (100, 27), (1517, 27), (1518, 27)])
def test_blocks_are_balanced(n, k):
    rows = apx.block_rows(n, k)
    cap = max(1, apx.BLOCK_SLOTS // k)
    blocks = -(-n // rows)
    assert rows <= min(n, cap)                     # each block within the slot budget
    assert blocks == -(-n // min(n, cap))          # as few blocks as the budget allows
    assert blocks * rows - n < blocks              # rows computed twice: fewer than the blocks
