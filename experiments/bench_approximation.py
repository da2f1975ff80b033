"""Benchmark of the neighbour build and of the MLS shape-function operator build.

Layout: jittered Cartesian lattice (jitter +-0.25 dx) in the periodic unit box, volumes dx^d,
h = beta dx, cubic-spline weight (support 2h).  For each dimension and size it measures

* ``neighbors``: ``jax.jit(neighbors.update, static_argnames="spec")``;
* ``mls q<k> full``: :func:`mlsph_jax.approximation.build` with ``ApproxSpec("mls", k,
  derivative="full", with_coeffs=True)`` (values, full gradients by forward-mode autodiff of
  M^-1(x) and W(x), per-particle coefficients);
* ``mls q<k> fixed_centre``: the same with the cheaper fixed-centre ("diffuse") gradients.

Compile time (``lower(...).compile()``) is reported separately from the steady-state time
(median of ``--repeat`` calls with ``block_until_ready``); throughput = N / steady-state time.
beta = 1.5 everywhere (thesis ch. 4/6; SPEC §3.2).  Degree 3 needs m = 10 (2D) / 20 (3D)
well-spread neighbours: on this quasi-uniform layout beta = 1.5 gives ~25-35 (2D) and ~100-150
(3D) neighbours, so the full degree stays active (the "full deg" column shows the fraction of
particles at the requested degree); uniformly random clouds need beta ~ 2.0 (2D) / 1.8 (3D).

Every (dimension, size) runs in its own worker process that streams one JSON line per case, so
that a case that exhausts memory or time does not lose the others; cases whose estimated
working set exceeds ``--max-gb`` are skipped and reported as such, as are cases beyond the
wall-clock ``--budget``.

Usage::

    python experiments/bench_approximation.py                      # 2D+3D, N = 1e4, 1e5
    python experiments/bench_approximation.py --sizes 10000 --dims 2 --degrees 1 2 --repeat 5
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import subprocess
import sys
import time

OUT = pathlib.Path(__file__).resolve().parent / "output" / "bench_approximation.json"
BETA = 1.5
JITTER = 0.25


# ----------------------------------------------------------------------------------------------
# worker: runs inside a child process
# ----------------------------------------------------------------------------------------------


def _peak_rss_gb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # kB -> GB (Linux)


def _layout(n_target: int, dim: int, seed: int = 0):
    import numpy as np

    m = max(2, round(n_target ** (1.0 / dim)))
    dx = 1.0 / m
    axes = [(np.arange(m) + 0.5) * dx] * dim
    x = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, dim)
    x = x + np.random.default_rng(seed).uniform(-JITTER, JITTER, x.shape) * dx
    return np.mod(x, 1.0), dx


def _time(fn, args, repeat: int):
    import jax
    import numpy as np

    out = jax.block_until_ready(fn(*args))  # warm-up (first call after compile)
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
    return out, float(np.median(times)), float(np.min(times))


def _estimate_gb(n: int, k: int, m: int, d: int, derivative: str) -> float:
    """Working set of the build, which runs over row blocks: the assembled [N, K] values,
    [N, K, d] gradients and [N, m, K] coefficients (twice: result and input of the update) plus
    one block's temporaries (at most 2048 rows of [K, m] planes with d tangents for the full
    derivative, x 4 for the solves)."""
    factor = (d + 1) if derivative == "full" else 1
    outputs = 2 * 8.0 * n * k * (1 + d + m)
    block = 4 * 8.0 * min(n, 2048) * k * m * (2 * factor + 2)
    return (outputs + block) / 2**30


def worker(cfg: dict) -> None:
    import jax
    import jax.numpy as jnp
    import numpy as np

    import mlsph_jax  # noqa: F401  (float64)
    from mlsph_jax import neighbors
    from mlsph_jax.approximation import ApproxSpec, basis, build
    from mlsph_jax.state import Domain

    dim, n_target, repeat = cfg["dim"], cfg["n"], cfg["repeat"]
    deadline = cfg["deadline"]

    def emit(rec):
        rec.update(dim=dim, peak_rss_gb=round(_peak_rss_gb(), 3))
        print(json.dumps(rec), flush=True)

    x, dx = _layout(n_target, dim)
    n = x.shape[0]
    h = np.full(n, BETA * dx)
    vol = np.full(n, dx**dim)
    domain = Domain((0.0,) * dim, (1.0,) * dim, (True,) * dim)
    t0 = time.perf_counter()
    spec, _ = neighbors.allocate(x, h, domain, support=2.0)
    t_alloc = time.perf_counter() - t0
    xj, hj, vj = jnp.asarray(x), jnp.asarray(h), jnp.asarray(vol)

    fn = jax.jit(neighbors.update, static_argnames="spec")
    t0 = time.perf_counter()
    compiled = fn.lower(xj, hj, spec=spec).compile()
    t_compile = time.perf_counter() - t0
    nl, t, tmin = _time(compiled, (xj, hj), repeat)
    assert not bool(nl.overflow)
    count = np.asarray(nl.count)
    emit(
        dict(
            case="neighbors",
            n=n,
            K=spec.capacity,
            mean_nbrs=float(count.mean()),
            allocate_s=t_alloc,
            compile_s=t_compile,
            run_s=t,
            run_min_s=tmin,
            particles_per_s=n / t,
            status="ok",
        )
    )

    L = jnp.ones(dim)
    per = jnp.ones(dim, bool)
    for q in cfg["degrees"]:
        for derivative in ("fixed_centre", "full"):
            case = f"mls q{q} {derivative}"
            m = basis.basis_size(q, dim)
            est = _estimate_gb(n, spec.capacity, m, dim, derivative)
            base = dict(case=case, n=n, K=spec.capacity, m=m, est_gb=round(est, 2))
            if est > cfg["max_gb"]:
                emit(
                    dict(base, status=f"skipped: estimated {est:.1f} GB > --max-gb {cfg['max_gb']}")
                )
                continue
            if time.time() > deadline:
                emit(dict(base, status="skipped: wall-clock budget exhausted"))
                continue
            aspec = ApproxSpec("mls", q, "cubic_spline", derivative, with_coeffs=True)
            t0 = time.perf_counter()
            comp = build.lower(xj, hj, vj, nl.idx, nl.mask, aspec, L, per).compile()
            t_compile = time.perf_counter() - t0
            ops, t, tmin = _time(comp, (xj, hj, vj, nl.idx, nl.mask, L, per), repeat)
            deg = np.asarray(ops.degree)
            finite = bool(np.isfinite(np.asarray(ops.gradients)).all())
            emit(
                dict(
                    base,
                    compile_s=t_compile,
                    run_s=t,
                    run_min_s=tmin,
                    particles_per_s=n / t,
                    full_degree_fraction=float(np.mean(deg == q)),
                    finite=finite,
                    status="ok",
                )
            )
            del ops, comp


# ----------------------------------------------------------------------------------------------
# driver
# ----------------------------------------------------------------------------------------------


def run_group(dim: int, n: int, args, deadline: float) -> list[dict]:
    cfg = dict(
        dim=dim,
        n=n,
        repeat=args.repeat,
        degrees=args.degrees,
        max_gb=args.max_gb,
        deadline=deadline,
    )
    cmd = [sys.executable, os.path.abspath(__file__), "--worker", json.dumps(cfg)]
    timeout = max(30.0, deadline - time.time() + 60.0)
    recs: list[dict] = []
    t0 = time.time()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        out, rc, err = proc.stdout, proc.returncode, proc.stderr
    except subprocess.TimeoutExpired as exc:
        out = exc.stdout.decode() if isinstance(exc.stdout, bytes) else (exc.stdout or "")
        rc, err = "timeout", f"worker exceeded {timeout:.0f} s"
    for line in out.splitlines():
        if line.startswith("{"):
            recs.append(json.loads(line))
    expected = ["neighbors"] + [
        f"mls q{q} {d}" for q in args.degrees for d in ("fixed_centre", "full")
    ]
    done = {r["case"] for r in recs}
    if rc != 0:
        why = "out of memory / killed (rc=-9)" if rc == -9 else f"worker failed (rc={rc})"
        tail = err.strip().splitlines()[-1] if isinstance(err, str) and err.strip() else ""
        for case in expected:
            if case not in done:
                recs.append(dict(case=case, dim=dim, n=None, status=f"{why} {tail}".strip()))
                break  # the first missing case is the one that failed; the rest never ran
        for case in expected:
            if case not in {r["case"] for r in recs}:
                recs.append(dict(case=case, dim=dim, n=None, status="not run (worker died)"))
    for r in recs:
        r.setdefault("n_target", n)
    print(f"  [{dim}D N~{n}: {time.time() - t0:.0f} s]", file=sys.stderr, flush=True)
    return recs


def fmt_table(recs: list[dict]) -> str:
    head = (
        f"{'dim':>3} {'N':>7} {'case':<22} {'K':>4} {'compile s':>9} {'run s':>8} "
        f"{'particles/s':>12} {'full deg':>8} {'RSS GB':>6}  status"
    )
    lines = [head, "-" * len(head)]
    for r in recs:
        n = r.get("n") or r.get("n_target")
        ok = r.get("status") == "ok"
        comp = f"{r['compile_s']:9.2f}" if ok else " " * 9
        run = f"{r['run_s']:8.3f}" if ok else " " * 8
        pps = f"{r['particles_per_s']:12.3g}" if ok else " " * 12
        fd = f"{r['full_degree_fraction']:8.3f}" if ok and "full_degree_fraction" in r else " " * 8
        rss = f"{r['peak_rss_gb']:6.2f}" if "peak_rss_gb" in r else " " * 6
        lines.append(
            f"{r['dim']:>3} {n:>7} {r['case']:<22} {r.get('K', ''):>4} {comp} {run} {pps} "
            f"{fd} {rss}  {r.get('status', '')}"
        )
    return "\n".join(lines)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument(
        "--sizes",
        type=int,
        nargs="+",
        default=[10_000, 100_000],
        help="target particle counts (default: 10000 100000)",
    )
    p.add_argument("--dims", type=int, nargs="+", default=[2, 3], choices=[1, 2, 3])
    p.add_argument("--degrees", type=int, nargs="+", default=[1, 2, 3], choices=[0, 1, 2, 3])
    p.add_argument("--repeat", type=int, default=3, help="timed calls per case (median)")
    p.add_argument(
        "--max-gb",
        type=float,
        default=12.0,
        help="skip cases whose estimated working set exceeds this (default 12)",
    )
    p.add_argument(
        "--budget",
        type=float,
        default=600.0,
        help="wall-clock budget in s; later cases are skipped (default 600)",
    )
    p.add_argument("--out", type=pathlib.Path, default=OUT)
    p.add_argument("--worker", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.worker:
        worker(json.loads(args.worker))
        return

    t_start = time.time()
    deadline = t_start + args.budget
    recs: list[dict] = []
    for n in sorted(args.sizes):
        for dim in args.dims:
            recs.extend(run_group(dim, n, args, deadline))
    table = fmt_table(recs)
    print(table)
    print(
        "\nfull deg = fraction of particles whose active MLS degree equals the requested one "
        "(beta = 1.5;\ncubic in 3D needs m = 20 independent neighbours: fine on this lattice, "
        "random clouds need beta ~ 1.8).\nRSS GB = peak resident memory of the worker process "
        "so far (the build runs over row blocks of particles)."
    )
    import jax

    meta = dict(
        platform=platform.platform(),
        python=platform.python_version(),
        jax=jax.__version__,
        devices=[str(dv) for dv in jax.devices()],
        cpu_count=os.cpu_count(),
        load_average=os.getloadavg(),
        beta=BETA,
        jitter=JITTER,
        repeat=args.repeat,
        wall_s=time.time() - t_start,
        layout="jittered Cartesian, periodic unit box",
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(dict(meta=meta, results=recs), indent=2))
    print(f"\nwrote {args.out} ({meta['wall_s']:.0f} s; load average {meta['load_average']})")


if __name__ == "__main__":
    main()
