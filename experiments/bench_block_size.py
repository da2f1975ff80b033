"""Block size of the blocked stencil passes (``mlsph_jax.approximation.BLOCK_SLOTS``, rows x K per
block) chosen by measurement: the bare MLSPH-ALE degree-2 right-hand side of
``bench_rhs.py`` (jittered periodic lattice, ideal gas, Eulerian), compiled once per block size
and timed interleaved in one process (A B C D A B C D ..., best of ``--repeat``), so that
contention on a shared machine hits every variant alike.

    python experiments/bench_block_size.py --n 40000 --slots 10240 20480 40960 81920

Prints particle evaluations per second and compile time per block size; writes
experiments/output/bench_block_size.json.  Not a test.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_rhs  # noqa: E402

from mlsph_jax import approximation as apx  # noqa: E402
from mlsph_jax import neighbors  # noqa: E402
from mlsph_jax.rhs import geometry, rhs  # noqa: E402
from mlsph_jax.scheme import Scheme  # noqa: E402
from mlsph_jax.state import Domain, Params, make_particles  # noqa: E402

OUT = Path(__file__).resolve().parent / "output" / "bench_block_size.json"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=40_000)
    ap.add_argument("--slots", type=int, nargs="+", default=[10_240, 20_480, 40_960, 81_920])
    ap.add_argument("--repeat", type=int, default=7)
    a = ap.parse_args(argv)
    scheme = Scheme(**bench_rhs.SCHEMES["mlsph_ale-2"], frame="eulerian")
    x, dx = bench_rhs.layout(a.n, np.random.default_rng(0))
    n = len(x)
    params = Params({"eos.gamma": 1.4})
    vol = np.full(n, dx * dx)
    p = make_particles(x, vol, bench_rhs.smooth_state(x, params))
    dom = Domain((0.0, 0.0), (1.0, 1.0), (True, True))
    _, nl = neighbors.allocate(x, scheme.beta * vol**0.5, dom, support=scheme.support)
    g = jax.jit(lambda p, nl: geometry(p.x, p.vol, nl, scheme, dom))(p, nl)
    default, calls, compile_s = apx.BLOCK_SLOTS, {}, {}
    try:
        for s in a.slots:
            apx.BLOCK_SLOTS = s          # read when the passes are traced
            t0 = time.perf_counter()
            calls[s] = jax.jit(lambda p, prm, g: rhs(p, prm, g, scheme)).lower(p, params, g).compile()
            compile_s[s] = time.perf_counter() - t0
    finally:
        apx.BLOCK_SLOTS = default
    best = dict.fromkeys(calls, float("inf"))
    for _ in range(a.repeat):
        for s, f in calls.items():
            t0 = time.perf_counter()
            jax.block_until_ready(f(p, params, g))
            best[s] = min(best[s], time.perf_counter() - t0)
    load = os.getloadavg()
    for s in a.slots:
        rows = apx.balanced_rows(n, max(1, min(n, s // nl.idx.shape[1])))
        print(f"BLOCK_SLOTS={s:>7d} ({rows} rows): {1e3 * best[s]:.1f} ms, "
              f"{n / best[s]:.3e} particle evaluations/s, compile {compile_s[s]:.1f} s")
    print(f"N={n}, K={nl.idx.shape[1]}, load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps({"n": n, "capacity": int(nl.idx.shape[1]), "load_average": load,
                               "rows": [{"block_slots": s, "rhs_s": best[s], "compile_s": compile_s[s]}
                                        for s in a.slots]}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
