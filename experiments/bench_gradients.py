"""Forward time, reverse-mode time and peak memory of a whole-run gradient (Taylor-Green, Re = 100,
Eulerian MLSPH-ALE degree 2), with and without checkpointing (:mod:`mlsph_jax.differentiable`).
Not a test.

Each configuration (particles per side n, steps, checkpoint = none | step | nested) runs in a fresh
subprocess, which (1) compiles and times the forward run ``simulate`` (ke at the end), (2) compiles
and times ``jax.grad`` of it with respect to physics.mu, and reports its peak resident memory
(``ru_maxrss`` of the child, i.e. the high-water mark of the whole process, compile included) and
XLA's planned buffer sizes (``memory_analysis`` of the compiled gradient).  A gradient whose plan
exceeds ``--max-gb`` is compiled but not executed (its plan is reported instead: reverse mode
without checkpointing stores every stage's residuals).  Prints a table and writes
experiments/output/bench_gradients.json.

    python experiments/bench_gradients.py [--sizes 50 100] [--steps 1000] [--checkpoints none step nested]
        [--max-gb 16] [--plan-only] [--out FILE]

``--plan-only`` compiles both programs and reports XLA's memory plan without executing them (the
issue's 10,000-step question: ``--sizes 100 --steps 10000 --checkpoints nested --plan-only``).
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _planned_mb(compiled) -> float | None:
    """XLA's planned buffer sizes of a compiled function (arguments + outputs + temporaries), MB."""
    try:
        ma = compiled.memory_analysis()
        return (ma.temp_size_in_bytes + ma.argument_size_in_bytes + ma.output_size_in_bytes) / 2**20
    except Exception:  # noqa: BLE001  (not every backend reports it)
        return None


def child(n: int, steps: int, checkpoint: str, max_gb: float, plan_only: bool = False) -> dict:
    import jax

    from mlsph_jax import config
    from mlsph_jax.cases import build_problem
    from mlsph_jax.differentiable import make_simulate, with_param

    cfg = config.load(ROOT / "configs/taylor_green_2d.toml", [f"case.n={n}", "time.t_end=0.2"])
    pb = build_problem(cfg)
    # record_every=1 (one scalar per step): nested checkpointing groups steps into segments that are
    # multiples of record_every, so recording only at the end would leave a single segment
    sim = make_simulate(pb, n_steps=steps, checkpoint=checkpoint, record_every=1)

    def f(mu):
        return sim(with_param(pb.params, "physics.mu", mu), pb.particles).series["ke"][-1]

    mu = float(pb.params["physics.mu"])
    out = {"n_particles": n * n, "steps": steps, "checkpoint": checkpoint}
    fwd = jax.jit(f)
    t0 = time.perf_counter()
    c = fwd.lower(mu).compile()
    out["forward_compile_s"] = time.perf_counter() - t0
    if plan_only:  # XLA's memory plan of both programs, nothing executed (e.g. 10,000 steps)
        t0 = time.perf_counter()
        cg = jax.jit(jax.grad(f)).lower(mu).compile()
        out["reverse_compile_s"] = time.perf_counter() - t0
        out["planned_forward_mb"] = _planned_mb(c)
        out["planned_reverse_mb"] = _planned_mb(cg)
        out["skipped"] = "--plan-only: compiled, not executed"
        return out
    t0 = time.perf_counter()
    jax.block_until_ready(c(mu))
    out["forward_s"] = time.perf_counter() - t0
    rss_fwd = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    g = jax.jit(jax.grad(f))
    t0 = time.perf_counter()
    cg = g.lower(mu).compile()
    out["reverse_compile_s"] = time.perf_counter() - t0
    out["forward_p_upd_per_s"] = n * n * steps / out["forward_s"]
    out["planned_forward_mb"] = _planned_mb(c)
    out["planned_reverse_mb"] = _planned_mb(cg)
    out["peak_rss_forward_mb"] = rss_fwd
    if out["planned_reverse_mb"] is not None and out["planned_reverse_mb"] > 1024 * max_gb:
        # executing would exhaust the machine; report XLA's plan instead of a measurement
        out["skipped"] = f"planned reverse-mode buffers {out['planned_reverse_mb'] / 1024:.1f} GB > --max-gb {max_gb}"
        return out
    t0 = time.perf_counter()
    out["gradient"] = float(jax.block_until_ready(cg(mu)))
    out["reverse_s"] = time.perf_counter() - t0
    out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="+", default=[50, 100], help="particles per side")
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--checkpoints", nargs="+", default=["nested", "step", "none"])
    ap.add_argument("--timeout", type=float, default=3600.0, help="seconds per configuration")
    ap.add_argument("--max-gb", type=float, default=16.0,
                    help="do not execute a gradient whose XLA-planned buffers exceed this (report the plan)")
    ap.add_argument("--out", type=Path, default=ROOT / "experiments" / "output" / "bench_gradients.json")
    ap.add_argument("--plan-only", action="store_true",
                    help="compile forward and reverse programs and report XLA's memory plan without running them")
    ap.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(child(int(args.child[0]), int(args.child[1]), args.child[2], args.max_gb, args.plan_only)))
        return
    rows = []
    print(f"{'N':>7} {'steps':>6} {'checkpoint':<10} {'fwd s':>8} {'fwd p-upd/s':>11} {'rev s':>8} {'rev/fwd':>7} "
          f"{'peak MB':>9} {'plan MB':>9} {'compile s':>9}")
    for n in args.sizes:
        for ck in args.checkpoints:
            cmd = [sys.executable, __file__, "--max-gb", str(args.max_gb), "--child", str(n), str(args.steps), ck]
            if args.plan_only:
                cmd.insert(2, "--plan-only")
            try:
                r = subprocess.run(cmd, capture_output=True, text=True, timeout=args.timeout)
            except subprocess.TimeoutExpired:
                rows.append({"n_particles": n * n, "steps": args.steps, "checkpoint": ck, "error": "timeout"})
                print(f"{n * n:>7} {args.steps:>6} {ck:<10} timeout after {args.timeout:.0f} s")
                continue
            if r.returncode != 0:
                err = (r.stderr.strip().splitlines() or ["?"])[-1][:160]
                rows.append({"n_particles": n * n, "steps": args.steps, "checkpoint": ck, "error": err})
                print(f"{n * n:>7} {args.steps:>6} {ck:<10} failed: {err}")
                continue
            row = json.loads(r.stdout.strip().splitlines()[-1])
            rows.append(row)
            plan = row["planned_reverse_mb"]
            plan_s = f"{plan:>9.0f}" if plan is not None else f"{'?':>9}"
            comp = row["forward_compile_s"] + row["reverse_compile_s"]
            if "skipped" in row:
                fwd = (f"{row['forward_s']:>8.1f} {row['forward_p_upd_per_s']:>11.3g}" if "forward_s" in row
                       else f"{'-':>8} {'-':>11}")
                print(f"{row['n_particles']:>7} {row['steps']:>6} {ck:<10} {fwd} {'-':>8} {'-':>7} {'-':>9} "
                      f"{plan_s} {comp:>9.1f}  not executed: {row['skipped']}", flush=True)
                continue
            print(f"{row['n_particles']:>7} {row['steps']:>6} {ck:<10} {row['forward_s']:>8.1f} "
                  f"{row['forward_p_upd_per_s']:>11.3g} {row['reverse_s']:>8.1f} "
                  f"{row['reverse_s'] / row['forward_s']:>7.2f} {row['peak_rss_mb']:>9.0f} {plan_s} "
                  f"{comp:>9.1f}", flush=True)
    dest = args.out
    dest.parent.mkdir(parents=True, exist_ok=True)
    import jax

    dest.write_text(json.dumps({"benchmark": "gradients", "jax": jax.__version__, "machine": platform.platform(),
                                "results": rows}, indent=2))
    print(f"wrote {dest}")


if __name__ == "__main__":
    main()
