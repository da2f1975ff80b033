"""The MLS operators of one row block (:func:`mlsph_jax.approximation.mls.operators_block`) with
the factor computed once inside a conditional (``mls.per_row_once``, docs/architecture.md
decision 94) against the same code inlined, where XLA's fusion copies the factor into every
consumer over the stencil planes.

Per case (dimension, degree, derivative, block rows B, stencil slots K; random offsets, full
stencils): both variants compiled in one process (compile seconds and the optimised HLO's
instruction count), the outputs compared bit for bit, then timed interleaved (inlined, once,
inlined, once, ... ``--rounds`` times; best and median), so that contention hits both alike.

    python experiments/bench_mls_block.py [--rounds 25] [--out FILE]

Prints one row per case with the load average; writes experiments/output/bench_mls_block.json.
Not a test.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import mlsph_jax  # noqa: F401  (float64)
from mlsph_jax.approximation import mls
from mlsph_jax.kernels import get_kernel

OUT = Path(__file__).resolve().parent / "output" / "bench_mls_block.json"
CASES = [(1, 3, "fixed_centre", 200, 7), (2, 1, "full", 1077, 38), (2, 2, "full", 1077, 38),
         (2, 2, "fixed_centre", 1077, 38), (2, 3, "full", 1077, 38), (2, 3, "fixed_centre", 1077, 38),
         (3, 1, "full", 264, 155), (3, 2, "full", 264, 155)]
_HLO_INSTRUCTION = re.compile(r"^\s*(ROOT\s+)?%?[\w.\-]+ = ", re.M)


def _inline(fn, *operands):
    return fn(*operands)


def bench_case(d, degree, derivative, B, K, rounds):
    rng = np.random.default_rng(0)
    dx = jnp.asarray(rng.uniform(-1.0, 1.0, (B, K, d)) * 0.08)
    mask = jnp.ones((B, K), bool)
    h = jnp.full(B, 0.05)
    real = mls.per_row_once
    variants = {}
    try:
        for name, impl in (("inlined", _inline), ("once", real)):
            mls.per_row_once = impl

            def block(dx, mask, h):
                return mls.operators_block(dx, mask, h, kernel=get_kernel("cubic_spline"), degree=degree,
                                           rcond=1e-6, derivative=derivative, with_coeffs=True)

            t = time.perf_counter()
            c = jax.jit(block).lower(dx, mask, h).compile()
            compile_s = time.perf_counter() - t
            out = jax.block_until_ready(c(dx, mask, h))
            variants[name] = {"fn": c, "compile_s": compile_s, "out": out, "times": [],
                              "hlo": len(_HLO_INSTRUCTION.findall(c.as_text()))}
    finally:
        mls.per_row_once = real
    same = all(bool(jnp.array_equal(a, b)) for a, b in zip(variants["inlined"]["out"], variants["once"]["out"],
                                                                strict=True))
    for _ in range(rounds):
        for v in variants.values():
            t = time.perf_counter()
            jax.block_until_ready(v["fn"](dx, mask, h))
            v["times"].append(time.perf_counter() - t)
    row = {"d": d, "degree": degree, "derivative": derivative, "B": B, "K": K, "bitwise_equal": same,
           "load": os.getloadavg()[0]}
    for name, v in variants.items():
        ts = sorted(v["times"])
        row[name] = {"compile_s": v["compile_s"], "hlo_instructions": v["hlo"], "best_ms": ts[0] * 1e3,
                     "median_ms": ts[len(ts) // 2] * 1e3}
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=25)
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args(argv)
    rows = []
    for case in CASES:
        r = bench_case(*case, rounds=args.rounds)
        a, b = r["inlined"], r["once"]
        print(f"d={r['d']} degree={r['degree']} {r['derivative']:12s} B={r['B']:5d} K={r['K']:3d}: "
              f"compile {a['compile_s']:.2f} -> {b['compile_s']:.2f} s, HLO {a['hlo_instructions']} -> "
              f"{b['hlo_instructions']}, run best {a['best_ms']:.3f} -> {b['best_ms']:.3f} ms "
              f"({r['B'] / a['best_ms'] * 1e3:.3g} -> {r['B'] / b['best_ms'] * 1e3:.3g} particles/s), median "
              f"{a['median_ms']:.3f} -> {b['median_ms']:.3f} ms, bitwise equal {r['bitwise_equal']}, "
              f"load {r['load']:.1f}", flush=True)
        rows.append(r)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(rows, indent=1))
    print(f"wrote {args.out}")
    return 0 if all(r["bitwise_equal"] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
