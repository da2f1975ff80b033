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
        [--max-gb 16] [--plan-only] [--reverse-alone] [--out FILE]

``--plan-only`` compiles both programs and reports XLA's memory plan without executing them (the
issue's 10,000-step question: ``--sizes 100 --steps 10000 --checkpoints nested --plan-only``).

``--reverse-alone``: after each configuration's child, a second fresh process compiles and runs
only the gradient, once: its peak resident memory is the gradient's own (the first child's holds
the forward program and its run as well), and its time a second reverse-mode timing.

``--remat-blocks on|off|ab``: with (default) or without the per-block rematerialisation of the
stencil passes (:func:`mlsph_jax.approximation.block_remat`); ``ab`` compiles both in the same
child and times them interleaved (A, B, A, B, ..., best of ``--repeat``), so that the load of a
shared machine falls on both alike; the row then holds both timings and the CPU time of each (a
second measure that contention distorts less), the peak RSS is that of the pair.  ``--dt``: the
fixed step (``t_end = dt * steps``) for runs shorter than the default 1000 steps over t = 0.2.
Every row records the load average (``os.getloadavg``) at its end.

``--block-scan on|off|ab``: with (default) or without the scanned-block derivative of the stencil
passes (:func:`mlsph_jax.approximation.block_scan`); ``ab`` as for ``--remat-blocks`` (not both
``ab`` at once).

``--tangents K [K ...]``: also time forward mode, ``mlsph_jax.sensitivity.value_and_grad(...,
"forward")`` (what ``mlsph sensitivity --mode forward`` runs), with K tangent components (the run
differentiated with respect to v in R^K through mu (1 + sum(v)), so every tangent is carried
through the whole run, as K parameters would be), interleaved with the forward and reverse runs;
the row then holds its time, its ratio to the forward run and the relative difference of its
derivative from reverse mode's.  ``--tangent-blocks loop`` (default: the shipped path, the blocked
stencil passes' own loop JVP) or ``scan`` (their scanned-block derivative, for comparison).
"""

from __future__ import annotations

import argparse
import json
import os
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


def _timed(fn, arg) -> tuple[float, float, object]:
    """(wall seconds, CPU seconds of this process, value) of one blocking call."""
    import jax

    c0, t0 = time.process_time(), time.perf_counter()
    val = jax.block_until_ready(fn(arg))
    return time.perf_counter() - t0, time.process_time() - c0, val


def _problem(n: int, steps: int, dt: float | None):
    """The benchmarked Taylor-Green problem (n x n) and its end time (0.2, or dt * steps)."""
    from mlsph_jax import config
    from mlsph_jax.cases import build_problem

    t_end = 0.2 if dt is None else dt * steps
    cfg = config.load(ROOT / "configs/taylor_green_2d.toml", [f"case.n={n}", f"time.t_end={t_end!r}"])
    return build_problem(cfg), t_end


def alone(n: int, steps: int, checkpoint: str, dt: float | None = None) -> dict:
    """Only the gradient, compiled and run once in this process: its peak resident memory (compile
    included) without the forward program beside it (``--reverse-alone``)."""
    import jax

    from mlsph_jax.differentiable import make_simulate, with_param

    pb, _ = _problem(n, steps, dt)
    sim = make_simulate(pb, n_steps=steps, checkpoint=checkpoint, record_every=1)
    mu = float(pb.params["physics.mu"])
    cg = jax.jit(jax.grad(lambda mu: sim(with_param(pb.params, "physics.mu", mu), pb.particles).series["ke"][-1]))
    cg = cg.lower(mu).compile()
    wall, cpu, val = _timed(cg, mu)
    return {"reverse_alone_s": wall, "reverse_alone_cpu_s": cpu, "reverse_alone_gradient": float(val),
            "peak_rss_reverse_alone_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "planned_reverse_alone_mb": _planned_mb(cg)}


def child(n: int, steps: int, checkpoint: str, max_gb: float, plan_only: bool = False, remat: str = "on",
          dt: float | None = None, repeat: int = 1, scan: str = "on", tangents=(),
          tangent_blocks: str = "loop") -> dict:
    import jax
    import jax.numpy as jnp

    from mlsph_jax.approximation import block_scan
    from mlsph_jax.differentiable import make_simulate, with_param
    from mlsph_jax.sensitivity import value_and_grad

    pb, t_end = _problem(n, steps, dt)
    if remat == "ab" and scan == "ab":
        raise SystemExit("--remat-blocks ab and --block-scan ab: compare one switch at a time")
    opts = {"on": [True], "off": [False], "ab": [False, True]}
    # variants (old first): (block remat, block scan)
    variants = [(rb, sc) for rb in opts[remat] for sc in opts[scan]]
    mu = float(pb.params["physics.mu"])
    out = {"n_particles": n * n, "steps": steps, "checkpoint": checkpoint, "t_end": t_end, "remat_blocks": remat,
           "block_scan": scan}
    progs = {}
    for rb, sc in variants:
        # record_every=1 (one scalar per step): nested checkpointing groups steps into segments that are
        # multiples of record_every, so recording only at the end would leave a single segment
        sim = make_simulate(pb, n_steps=steps, checkpoint=checkpoint, record_every=1, remat_blocks=rb)

        def f(mu, sim=sim):
            return sim(with_param(pb.params, "physics.mu", mu), pb.particles).series["ke"][-1]

        with block_scan(sc):   # a trace-time setting
            t0 = time.perf_counter()
            c = jax.jit(f).lower(mu).compile()
            out["forward_compile_s"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            cg = jax.jit(jax.grad(f)).lower(mu).compile()
            out["reverse_compile_s"] = time.perf_counter() - t0
        out["planned_forward_mb"] = _planned_mb(c)
        out["planned_reverse_mb"] = _planned_mb(cg)
        progs[rb, sc] = (c, cg)
    tangent_progs = {}
    if tangents:
        out["tangent_blocks"] = tangent_blocks
    for k in tangents:   # forward mode with k tangents, on the last variant's run
        def h(v, f=f):
            return f(mu * (1.0 + jnp.sum(v))), 0.0

        t0 = time.perf_counter()
        vg = value_and_grad(h, "forward", scan_blocks=tangent_blocks == "scan")
        tangent_progs[k] = jax.jit(vg).lower(jnp.zeros(k)).compile()
        out[f"forward_mode_{k}_compile_s"] = time.perf_counter() - t0
    if plan_only:  # XLA's memory plan of both programs, nothing executed (e.g. 10,000 steps)
        out["skipped"] = "--plan-only: compiled, not executed"
        return out
    if out["planned_reverse_mb"] is not None and out["planned_reverse_mb"] > 1024 * max_gb:
        # executing would exhaust the machine; report XLA's plan instead of a measurement
        out["skipped"] = f"planned reverse-mode buffers {out['planned_reverse_mb'] / 1024:.1f} GB > --max-gb {max_gb}"
        return out
    best = {v: {} for v in variants}
    for _ in range(repeat):
        for rb in variants:   # interleaved: A, B, A, B, ...
            c, cg = progs[rb]
            for key, fn in (("forward", c), ("reverse", cg)):
                wall, cpu, val = _timed(fn, mu)
                b = best[rb]
                b[f"{key}_s"] = min(b.get(f"{key}_s", wall), wall)
                b[f"{key}_cpu_s"] = min(b.get(f"{key}_cpu_s", cpu), cpu)
                b["gradient" if key == "reverse" else "ke"] = float(val)
                if rb == variants[0] and key == "forward":
                    out["peak_rss_forward_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        for k, cf in tangent_progs.items():
            wall, cpu, ((_, _), jac) = _timed(cf, jnp.zeros(k))
            out[f"forward_mode_{k}_s"] = min(out.get(f"forward_mode_{k}_s", wall), wall)
            out[f"forward_mode_{k}_cpu_s"] = min(out.get(f"forward_mode_{k}_cpu_s", cpu), cpu)
            out[f"forward_mode_{k}_derivative"] = float(jac[0]) / mu   # d ke / d mu
    out.update(best[variants[-1]])
    for k in tangent_progs:
        d = out[f"forward_mode_{k}_derivative"]
        out[f"forward_mode_{k}_rel_diff"] = abs(d - out["gradient"]) / abs(out["gradient"])
    if len(variants) == 2:
        old, new = best[variants[0]], best[variants[1]]
        out["old"] = old
        out["gradient_rel_diff"] = abs(new["gradient"] - old["gradient"]) / abs(old["gradient"])
    out["forward_p_upd_per_s"] = n * n * steps / out["forward_s"]
    out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    out["load_average"] = os.getloadavg()
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
    ap.add_argument("--remat-blocks", choices=("on", "off", "ab"), default="on",
                    help="per-block rematerialisation of the stencil passes; ab: both, timed interleaved")
    ap.add_argument("--block-scan", choices=("on", "off", "ab"), default="on",
                    help="scanned-block derivative of the stencil passes; ab: both, timed interleaved")
    ap.add_argument("--dt", type=float, default=None, help="fixed step (t_end = dt * steps); default t_end = 0.2")
    ap.add_argument("--repeat", type=int, default=1,
                    help="timed repetitions (best of; interleaved with --remat-blocks ab)")
    ap.add_argument("--tangents", type=int, nargs="+", default=[],
                    help="also time forward mode with these numbers (>= 1) of tangent components")
    ap.add_argument("--tangent-blocks", choices=("loop", "scan"), default="loop",
                    help="forward mode through the blocked passes' loop JVP (shipped) or scanned blocks")
    ap.add_argument("--reverse-alone", action="store_true",
                    help="also run the gradient alone in a fresh process: its peak memory without the forward program")
    ap.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    ap.add_argument("--alone-child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if any(k < 1 for k in args.tangents):
        ap.error(f"invalid --tangents {args.tangents}; allowed: integers >= 1")
    if args.reverse_alone and (args.remat_blocks != "on" or args.block_scan != "on"):
        ap.error("invalid --reverse-alone with --remat-blocks/--block-scan other than on: the gradient alone is "
                 "the shipped program; allowed: --reverse-alone with both on (the default)")
    if args.child and args.alone_child:
        print(json.dumps(alone(int(args.child[0]), int(args.child[1]), args.child[2], args.dt)))
        return
    if args.child:
        print(json.dumps(child(int(args.child[0]), int(args.child[1]), args.child[2], args.max_gb, args.plan_only,
                               args.remat_blocks, args.dt, args.repeat, args.block_scan, args.tangents,
                               args.tangent_blocks)))
        return
    rows = []
    print(f"{'N':>7} {'steps':>6} {'checkpoint':<10} {'fwd s':>8} {'fwd p-upd/s':>11} {'rev s':>8} {'rev/fwd':>7} "
          f"{'peak MB':>9} {'plan MB':>9} {'compile s':>9}")
    for n in args.sizes:
        for ck in args.checkpoints:
            cmd = [sys.executable, __file__, "--max-gb", str(args.max_gb), "--remat-blocks", args.remat_blocks,
                   "--block-scan", args.block_scan, "--repeat", str(args.repeat),
                   *(["--tangents", *map(str, args.tangents)] if args.tangents else []),
                   "--tangent-blocks", args.tangent_blocks,
                   "--child", str(n), str(args.steps), ck]
            if args.dt is not None:
                cmd[2:2] = ["--dt", repr(args.dt)]
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
            if args.reverse_alone and "skipped" not in row:
                cmd_alone = [sys.executable, __file__, "--alone-child", "--child", str(n), str(args.steps), ck]
                if args.dt is not None:
                    cmd_alone[2:2] = ["--dt", repr(args.dt)]
                try:
                    ra = subprocess.run(cmd_alone, capture_output=True, text=True, timeout=args.timeout)
                except subprocess.TimeoutExpired:
                    row["reverse_alone_error"] = f"timeout after {args.timeout:.0f} s"
                else:
                    if ra.returncode == 0:
                        row.update(json.loads(ra.stdout.strip().splitlines()[-1]))
                    else:
                        row["reverse_alone_error"] = (ra.stderr.strip().splitlines() or ["?"])[-1][:160]
            plan = row["planned_reverse_mb"]
            plan_s = f"{plan:>9.0f}" if plan is not None else f"{'?':>9}"
            comp = row["forward_compile_s"] + row["reverse_compile_s"]
            if "skipped" in row:
                fwd = (f"{row['forward_s']:>8.1f} {row['forward_p_upd_per_s']:>11.3g}" if "forward_s" in row
                       else f"{'-':>8} {'-':>11}")
                print(f"{row['n_particles']:>7} {row['steps']:>6} {ck:<10} {fwd} {'-':>8} {'-':>7} {'-':>9} "
                      f"{plan_s} {comp:>9.1f}  not executed: {row['skipped']}", flush=True)
                continue
            cpu = f"cpu ratio {row['reverse_cpu_s'] / row['forward_cpu_s']:.2f}"
            if "old" in row:
                o = row["old"]
                which = "block remat" if args.remat_blocks == "ab" else "block scan"
                cpu += (f"; without {which}: fwd {o['forward_s']:.1f} s rev {o['reverse_s']:.1f} s ratio "
                        f"{o['reverse_s'] / o['forward_s']:.2f} cpu ratio "
                        f"{o['reverse_cpu_s'] / o['forward_cpu_s']:.2f}; "
                        f"gradients differ by {row['gradient_rel_diff']:.1e}")
            for k in args.tangents:
                cpu += (f"; forward mode, {k} tangent(s): {row[f'forward_mode_{k}_s']:.1f} s, "
                        f"{row[f'forward_mode_{k}_s'] / row['forward_s']:.2f}x the forward run "
                        f"(cpu {row[f'forward_mode_{k}_cpu_s'] / row['forward_cpu_s']:.2f}x), "
                        f"derivative differs from reverse mode's by {row[f'forward_mode_{k}_rel_diff']:.1e}")
            if "peak_rss_reverse_alone_mb" in row:
                cpu += (f"; the gradient alone in its own process: peak {row['peak_rss_reverse_alone_mb']:.0f} MB, "
                        f"plan {row['planned_reverse_alone_mb'] or 0:.0f} MB, {row['reverse_alone_s']:.1f} s")
            elif "reverse_alone_error" in row:
                cpu += f"; the gradient alone failed: {row['reverse_alone_error']}"
            print(f"{row['n_particles']:>7} {row['steps']:>6} {ck:<10} {row['forward_s']:>8.1f} "
                  f"{row['forward_p_upd_per_s']:>11.3g} {row['reverse_s']:>8.1f} "
                  f"{row['reverse_s'] / row['forward_s']:>7.2f} {row['peak_rss_mb']:>9.0f} {plan_s} "
                  f"{comp:>9.1f}  {cpu}; load {row['load_average'][0]:.1f}", flush=True)
    dest = args.out
    dest.parent.mkdir(parents=True, exist_ok=True)
    import jax

    dest.write_text(json.dumps({"benchmark": "gradients", "jax": jax.__version__, "machine": platform.platform(),
                                "results": rows}, indent=2))
    print(f"wrote {dest}")


if __name__ == "__main__":
    main()
