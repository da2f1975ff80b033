"""Benchmark of the O(N) neighbour-list build (:mod:`mlsph_jax.neighbors`).

Jittered Cartesian layouts in 2D and 3D (spacing dx, jitter 0.1 dx, non-periodic unit box),
h = beta * dx with beta = 1.5 and kernel support 2.  Reports the compile time of
``jax.jit(update, static_argnames="spec")`` and the steady-state build time (median of
repeats; wall clock and process CPU time, the latter being robust on a shared machine) as
particles per second; writes ``experiments/output/bench_neighbors.json``.

Usage::

    python experiments/bench_neighbors.py --sizes 10000 100000 --dims 2 3
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import time

import jax
import numpy as np

import mlsph_jax
from mlsph_jax import neighbors
from mlsph_jax.state import Domain


def layout(n_target: int, dim: int, rng: np.random.Generator, jitter: float = 0.1):
    """Jittered Cartesian lattice with about ``n_target`` particles in the unit box."""
    m = max(2, round(n_target ** (1.0 / dim)))
    dx = 1.0 / m
    axes = [(np.arange(m) + 0.5) * dx] * dim
    x = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, dim)
    x = x + rng.uniform(-jitter, jitter, x.shape) * dx
    return x, dx


def run(n_target: int, dim: int, beta: float, support: float, repeats: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    x, dx = layout(n_target, dim, rng)
    n = x.shape[0]
    h = np.full(n, beta * dx)
    domain = Domain((0.0,) * dim, (1.0,) * dim, (False,) * dim)
    t0 = time.perf_counter()
    spec, _ = neighbors.allocate(x, h, domain, support=support)
    t_alloc = time.perf_counter() - t0

    xj, hj = jax.device_put(x), jax.device_put(h)
    fn = jax.jit(neighbors.update, static_argnames="spec")
    t0 = time.perf_counter()
    compiled = fn.lower(xj, hj, spec=spec).compile()
    t_compile = time.perf_counter() - t0
    nl = jax.block_until_ready(compiled(xj, hj))
    if bool(nl.overflow):
        raise RuntimeError(f"unexpected overflow for N={n}, d={dim}")
    times, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        jax.block_until_ready(compiled(xj, hj))
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    t = float(np.median(times))
    count = np.asarray(nl.count)
    return dict(dim=dim, n=n, beta=beta, support=support, capacity=spec.capacity,
                cell_capacity=spec.cell_capacity, batch_size=spec.batch_size,
                n_cells=list(spec.n_cells), mean_count=float(count.mean()),
                max_count=int(count.max()), allocate_s=t_alloc, compile_s=t_compile,
                build_s=t, build_min_s=float(np.min(times)), build_cpu_s=float(np.median(cpu)),
                particles_per_s=n / t, load_avg=list(os.getloadavg()))


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000],
                   help="target particle counts (default: 10000 100000)")
    p.add_argument("--dims", type=int, nargs="+", default=[2, 3], choices=[1, 2, 3])
    p.add_argument("--beta", type=float, default=1.5)
    p.add_argument("--support", type=float, default=2.0)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=pathlib.Path,
                   default=pathlib.Path(__file__).parent / "output" / "bench_neighbors.json")
    args = p.parse_args(argv)

    rows = []
    hdr = (f"{'d':>2} {'N':>8} {'K':>4} {'C':>4} {'batch':>6} {'mean nb':>8} "
           f"{'alloc s':>8} {'compile s':>9} {'build s':>8} {'cpu s':>7} {'particles/s':>12}")
    print(hdr)
    print("-" * len(hdr))
    for dim in args.dims:
        for n in args.sizes:
            r = run(n, dim, args.beta, args.support, args.repeats, args.seed)
            rows.append(r)
            print(f"{r['dim']:>2} {r['n']:>8} {r['capacity']:>4} {r['cell_capacity']:>4} "
                  f"{str(r['batch_size']):>6} {r['mean_count']:>8.1f} {r['allocate_s']:>8.2f} "
                  f"{r['compile_s']:>9.2f} {r['build_s']:>8.3f} {r['build_cpu_s']:>7.3f} "
                  f"{r['particles_per_s']:>12.3e}",
                  flush=True)
    meta = dict(jax=jax.__version__, mlsph_jax=mlsph_jax.__version__,
                backend=jax.default_backend(), devices=[str(d) for d in jax.devices()],
                platform=platform.platform(), processor=platform.processor())
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(dict(meta=meta, results=rows), indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
