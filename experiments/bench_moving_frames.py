"""Moving frames against the Eulerian step, this tree against a baseline commit, in one process.

Issue 15: the ALE frames must not cost more than 1.5x the Eulerian step.  For each size n in
``--sizes`` this builds ``taylor_green_2d`` (n x n, Re = 100, MLSPH-ALE degree 2, quadratic
reconstruction; the setting of ``profile_step.py``) in every frame of ``--frames`` and compiles the
driver's jitted chunk (:func:`mlsph_jax.integrate.make_chunk`: ``--chunk-steps`` SSP-RK3 steps at
a fixed dt, per-stage geometry, Verlet-skin lists for moving particles, CFL and status reductions
included) twice: from this tree and from ``--baseline REF`` (a git commit exported by ``git
archive`` into a temporary folder and imported as a second package, ``mlsph_base``).  All chunks
then run interleaved (base A, this A, base B, this B, ..., ``--rounds`` times) and each keeps its
best time, so the ratios are those of one load; the load average is recorded before and after.
Both versions' final states (q, x and V) are compared (max |difference|, should be 0 when the
change keeps the numbers).

    python experiments/bench_moving_frames.py --baseline 0f0c6e6 [--sizes 50 100] [--rounds 5]
    python experiments/bench_moving_frames.py --baseline HEAD --frames eulerian ale_shift \
        --this-set scheme.conservation_projection=true     # an option's cost (decision 112)

Prints per chunk: compile seconds, ms per step (best and median wall time, and best process CPU time),
particle-updates/s (N / step time) and the ratio to
the Eulerian step of the same version; writes experiments/output/bench_moving_frames.json.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "experiments" / "output" / "bench_moving_frames.json"
BASE = '[case]\nname = "taylor_green_2d"\nre = 100.0\n[output]\nplots = false\nprogress = false\n'


def baseline_package(ref: str, folder: str):
    """``git archive`` the package of ``ref`` into ``folder/mlsph_base`` and import it."""
    data = subprocess.run(["git", "-C", str(ROOT), "archive", ref, "mlsph_jax"], check=True,
                          capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", folder], input=data, check=True)
    os.rename(Path(folder) / "mlsph_jax", Path(folder) / "mlsph_base")
    sys.path.insert(0, folder)
    return importlib.import_module("mlsph_base")


def chunk_of(pkg, n: int, frame: str, steps: int, sets=()):
    """``(compiled chunk, args, particles, compile s, capacity)`` of ``pkg`` (a copy of mlsph_jax)."""
    config = importlib.import_module(pkg.__name__ + ".config")
    cases = importlib.import_module(pkg.__name__ + ".cases")
    integ = importlib.import_module(pkg.__name__ + ".integrate")
    run = importlib.import_module(pkg.__name__ + ".run")
    rhs = importlib.import_module(pkg.__name__ + ".rhs")
    cfg = config.loads(BASE, [f"case.n={n}", f"scheme.frame={frame}", "time.t_end=0.01", *sets])
    pb = cases.build_problem(cfg)
    sc, dom, p, prm = pb.scheme, pb.domain, pb.particles, pb.params
    setup = run.setup_run(pb, headroom=cfg["scheme"]["neighbor_headroom"],
                          min_moving_headroom=cfg["scheme"]["moving_neighbor_headroom"] or True)
    dt = 0.3 * (1.0 / n) / 11.0
    g = None if sc.moving else jax.jit(lambda x, v, nl: rhs.geometry(x, v, nl, sc, dom))(p.x, p.vol, setup.nl)
    ch = integ.make_chunk(sc, dom, integ.StepControl(dt_fixed=dt), steps, nspec=setup.nspec if sc.moving else None)
    args = (integ.initial_carry(p), prm, g, jax.numpy.asarray(1e9))
    t0 = time.perf_counter()
    c = ch.lower(*args).compile()
    comp = time.perf_counter() - t0
    r = c(*args)
    assert int(r.status) == 0 and int(r.step) == steps, int(r.status)
    state = np.concatenate([np.asarray(a).ravel() for a in (r.particles.q, r.particles.x, r.particles.vol)])
    return c, args, int(p.n), comp, setup.nspec.capacity, state


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--baseline", default=None, help="git ref of the baseline (omit: this tree alone)")
    ap.add_argument("--sizes", type=int, nargs="+", default=[50, 100])
    ap.add_argument("--frames", nargs="+", default=["eulerian", "ale_shift", "lagrangian"])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--chunk-steps", type=int, default=10)
    ap.add_argument("--set", nargs="*", default=[], dest="sets", help="config overrides KEY=VALUE")
    ap.add_argument("--this-set", nargs="*", default=[], dest="this_sets",
                    help="overrides for this tree only (an option the baseline lacks, e.g. "
                         "scheme.conservation_projection=true against --baseline HEAD)")
    a = ap.parse_args(argv)
    import mlsph_jax
    versions = {"this": mlsph_jax}
    tmp = tempfile.TemporaryDirectory()
    if a.baseline:
        versions = {"base": baseline_package(a.baseline, tmp.name), "this": mlsph_jax}
    load0 = os.getloadavg()
    rows = []
    for n in a.sizes:
        calls = {}
        for frame in a.frames:
            for ver, pkg in versions.items():
                sets = [*a.sets, *(a.this_sets if ver == "this" else [])]
                c, args, npart, comp, cap, q = chunk_of(pkg, n, frame, a.chunk_steps, sets)
                calls[(ver, frame)] = (c, args, npart, comp, cap, q)
                print(f"n={n} {ver:>4s} {frame:>10s}: compiled in {comp:.1f} s (K = {cap})", flush=True)
        best = dict.fromkeys(calls, float("inf"))
        cpu = dict.fromkeys(calls, float("inf"))
        times = {key: [] for key in calls}
        for _ in range(a.rounds):
            for key, (c, args, *_rest) in calls.items():
                t0, c0 = time.perf_counter(), time.process_time()
                jax.block_until_ready(c(*args))
                times[key].append(time.perf_counter() - t0)
                best[key] = min(best[key], times[key][-1])
                cpu[key] = min(cpu[key], time.process_time() - c0)
        for (ver, frame), (_, _, npart, comp, cap, q) in calls.items():
            step = best[(ver, frame)] / a.chunk_steps
            median = statistics.median(times[(ver, frame)]) / a.chunk_steps
            eul = best.get((ver, "eulerian"))
            ratio = None if eul is None else best[(ver, frame)] / eul
            diff = (float(np.max(np.abs(q - calls[("base", frame)][5]))) if "base" in versions else None)
            rows.append({"n": n, "particles": npart, "version": ver, "frame": frame, "capacity": cap,
                         "compile_s": comp, "step_s": step, "median_step_s": median,
                         "cpu_step_s": cpu[(ver, frame)] / a.chunk_steps,
                         "particle_updates_per_s": npart / step,
                         "ratio_to_eulerian": ratio, "max_abs_diff_to_base": diff})
            print(f"n={n} {ver:>4s} {frame:>10s}: {1e3 * step:8.2f} ms/step (median {1e3 * median:.2f}, process CPU "
                  f"{1e3 * cpu[(ver, frame)] / a.chunk_steps:.2f} ms)  {npart / step:.3e} updates/s"
                  + ("" if ratio is None else f"  {ratio:.2f}x Eulerian")
                  + ("" if diff is None else f"  |(q, x, V) - base| {diff:.1e}"), flush=True)
    load1 = os.getloadavg()
    print(f"load average {load0[0]:.2f} -> {load1[0]:.2f}")
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps({"baseline": a.baseline, "rounds": a.rounds, "chunk_steps": a.chunk_steps,
                               "sets": a.sets, "this_sets": a.this_sets,
                               "load_average": [list(load0), list(load1)], "rows": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
