"""Cost of sampling the time series between outputs (``output.series_interval``, issue 17) on the
Re = 100 shedding config (``configs/cylinder_re100.toml``, reduced by ``--set``).

Three ways of running the same physical time with one driver (one compilation, the chunk reused):

* ``outputs``: ``--snapshots * m`` outputs, the series at each (the former way to sample C_L finely:
  every sample writes the fields and a checkpoint);
* ``series``: ``--snapshots`` outputs and the series every ``t_end / (snapshots m)``
  (``output.series_interval``): the same step targets, so the same steps and series bit for bit
  (checked here too), without the snapshots;
* ``outputs_only``: ``--snapshots`` outputs and the series at them only (no finer sampling: fewer
  step targets, so a slightly different trajectory and step count).

Each is run ``--repeat`` times interleaved (A, B, C, A, B, C, ...; best of n) into a fresh folder.
``series`` against ``outputs_only`` is the cost of the samples (a chunk ending at each sample
time, one host synchronisation, the step clipped to the sample time, the case's diagnostics
evaluated on the host); ``outputs`` against ``series`` what writing the fields at each sample cost.
Prints particle-steps/s, the compile time, wall times, fields.h5 sizes, the cost of one call of
the case's diagnostics and the load average ("contended" above 2.5), and writes
``experiments/output/bench_series.json``.  Not a test.

Usage::

    python experiments/bench_series.py --set case.n_theta=32 case.r_far=4.0 time.t_end=5 --snapshots 1 --m 20
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import shutil
import sys
import tempfile
import time

from mlsph_jax import config as config_mod
from mlsph_jax.cases import build_problem
from mlsph_jax.simulation import make_simulation
from mlsph_jax.testing import CONFIG_DIR


def best_of(fn, repeat: int) -> float:
    """Best wall time of ``repeat`` calls of ``fn`` (after one warm-up call)."""
    fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--set", nargs="*", default=["case.n_theta=32", "case.r_far=4.0", "time.t_end=5"],
                    help="overrides of configs/cylinder_re100.toml")
    ap.add_argument("--snapshots", type=int, default=1, help="outputs of the series and outputs_only runs")
    ap.add_argument("--m", type=int, default=20, help="samples per output interval")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    cfg = config_mod.load(CONFIG_DIR / "cylinder_re100.toml",
                          [*args.set, f"output.snapshots={args.snapshots}", "output.series_interval=0",
                           "output.plots=false", "output.progress=false", "output.degree_fallback_warn=1"])
    pb = build_problem(cfg)
    sim = make_simulation(pb, cfg)
    interval = pb.t_end / (args.snapshots * args.m)
    kinds = {"outputs": {"snapshots": args.snapshots * args.m},
             "series": {"snapshots": args.snapshots, "series_interval": interval},
             "outputs_only": {"snapshots": args.snapshots}}
    tmp = pathlib.Path(tempfile.mkdtemp(prefix="bench_series_"))
    best, last, loads, compile_s = {k: float("inf") for k in kinds}, {}, {k: [] for k in kinds}, 0.0
    try:
        for r in range(args.repeat):
            for k, kw in kinds.items():
                out = tmp / f"{k}{r}"
                t0 = time.perf_counter()
                res = sim.run(out, progress=False, plots=False, degree_fallback_warn=1.0, **kw)
                wall = time.perf_counter() - t0 - res.summary["compile_time_s"]
                compile_s += res.summary["compile_time_s"]    # (the first run compiles, the others reuse it)
                best[k] = min(best[k], wall)
                loads[k].append(os.getloadavg()[0])
                last[k] = {"summary": res.summary, "fields_bytes": (out / "fields.h5").stat().st_size,
                           "samples": len(res.summary["timeseries"]["t"])}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    same = last["series"]["summary"]["timeseries"] == last["outputs"]["summary"]["timeseries"]
    rows = {}
    n = pb.particles.n
    tag = lambda v: f"load {v:.1f}" + (" (contended)" if v > 2.5 else "")  # noqa: E731
    for k in kinds:
        s = last[k]["summary"]
        rows[k] = {**kinds[k], "best_wall_s": best[k], "n_steps": int(s["n_steps"]),
                   "samples": last[k]["samples"], "fields_bytes": last[k]["fields_bytes"],
                   "particle_steps_per_s": n * int(s["n_steps"]) / best[k], "load_average": loads[k]}
        print(f"{k:13s} {rows[k]['snapshots']:4d} outputs {rows[k]['samples']:4d} samples {rows[k]['n_steps']:6d} "
              f"steps  best {best[k]:7.2f} s  {rows[k]['particle_steps_per_s']:.3g} particle-steps/s  fields.h5 "
              f"{rows[k]['fields_bytes'] / 1e6:7.2f} MB  {tag(max(loads[k]))}", flush=True)
    extra = rows["series"]["samples"] - rows["outputs_only"]["samples"]
    per_sample = (best["series"] - best["outputs_only"]) / max(extra, 1)
    print(f"compile {compile_s:.1f} s (once); series == outputs (bit for bit): {same}; sampling cost "
          f"{per_sample * 1e3:.1f} ms per extra sample ({(best['series'] / best['outputs_only'] - 1) * 100:+.1f} % "
          f"wall), fields at every sample {(best['outputs'] / best['series'] - 1) * 100:+.1f} % wall", flush=True)
    diag = best_of(lambda: pb.diagnostics(pb.particles, 0.0, pb.params), args.repeat)
    print(f"one call of the case's diagnostics (host, eager jnp): {diag * 1e3:.1f} ms (best of {args.repeat}); "
          f"{tag(os.getloadavg()[0])}", flush=True)
    out_dir = pathlib.Path(__file__).parent / "output"
    out_dir.mkdir(exist_ok=True)
    (out_dir / "bench_series.json").write_text(json.dumps(
        {"argv": sys.argv[1:], "n_particles": n, "rows": rows, "same_series": same, "compile_s": compile_s,
         "seconds_per_extra_sample": per_sample, "diagnostics_call_s": diag}, indent=1))
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
