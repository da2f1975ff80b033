"""Vortex shedding behind the cylinder (issue 17 items 5 and 7; docs/validation.md "Vortex
shedding"): the C_L / C_D history of a finished ``mlsph run`` folder, its whole-period statistics
(the case's own :func:`mlsph_jax.cases.cylinder.shedding_statistics`, so the numbers are those a
run with that ``--transient`` writes to summary.json) against thesis Table 4.2, the run's cost
(steps, wall time, particle-updates/s, compile time) and a plot.

Usage::

    nice -n 10 mlsph run cylinder_re100 --out out/cylinder_re100
    python experiments/cylinder_shedding.py out/cylinder_re100 [--transient 75]

Writes ``experiments/output/cylinder_shedding_<folder>.json`` and ``.png``.
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

import numpy as np

from mlsph_jax.cases.cylinder import shedding_statistics
from mlsph_jax.plotting import subplots

#: Thesis Table 4.2 (present method) and the issue-17 targets: Re -> metric -> (value, rel. tol.).
TARGETS = {100: {"cd_mean": (1.35, 0.03), "cl_amplitude": (0.33, 0.10), "st": (0.165, 0.03)},
           185: {"cd_mean": (1.3398, 0.03), "cl_rms": (0.4447, 0.10), "st": (0.1937, 0.03)}}

OUT = Path(__file__).resolve().parent / "output"


def read_series(run: Path) -> dict[str, np.ndarray]:
    with open(run / "timeseries.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    return {k: np.array([float(r[k]) for r in rows]) for k in rows[0]}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path, help="output folder of a finished cylinder run")
    ap.add_argument("--transient", type=float, default=None, help="default: the run's case.transient")
    args = ap.parse_args(argv)
    summary = json.loads((args.run / "summary.json").read_text())
    import tomllib

    cfg = tomllib.loads((args.run / "config.toml").read_text())
    case = cfg["case"]
    transient = case.get("transient", 50.0) if args.transient is None else args.transient
    series = read_series(args.run)
    stats = shedding_statistics(series, transient, D=2.0 * case["radius"])
    re = round(case["re"])
    m = stats.get("metrics", {})
    checks = {k: {"measured": m.get(k), "target": v, "rel_error": None if k not in m else (m[k] - v) / v,
                  "met": k in m and abs(m[k] - v) <= tol * v}
              for k, (v, tol) in TARGETS.get(re, {}).items()}
    result = {"run": str(args.run), "re": case["re"], "mach": case["mach"], "n_theta": case["n_theta"],
              "r_far": case["r_far"], "n_particles": summary["n_particles"], "n_steps": summary["n_steps"],
              "t_final": summary["t_final"], "wall_time_s": summary["wall_time_s"],
              "compile_time_s": summary["compile_time_s"],
              "particle_updates_per_s": summary["particle_updates_per_s"], "statistics": stats, "targets": checks}
    for k in ("n_particles", "n_steps", "t_final", "wall_time_s", "compile_time_s", "particle_updates_per_s"):
        print(f"{k:>24s}: {summary[k]:.6g}")
    print(json.dumps(stats, indent=1))
    for k, c in checks.items():
        print(f"{k:>14s}: measured {c['measured']}, target {c['target']} -> {'met' if c['met'] else 'MISSED'}")
    OUT.mkdir(exist_ok=True)
    stem = f"cylinder_shedding_{args.run.name}"
    (OUT / f"{stem}.json").write_text(json.dumps(result, indent=1))
    fig, (a1, a2) = subplots(2, 1, figsize=(8.0, 5.0), sharex=True)
    t = series["t"]
    late = t > 1.0   # the impulsive start's C_D (~37 at t = 0) would flatten the plot
    a1.plot(t[late], series["cd"][late], lw=0.8)
    a2.plot(t, series["cl"], lw=0.8)
    if "window" in stats:
        for a in (a1, a2):
            a.axvspan(*stats["window"], color="0.9", zorder=0, label="whole periods used")
        a1.axhline(m["cd_mean"], color="k", ls="--", lw=0.6, label=f"mean C_D {m['cd_mean']:.4f}")
        a2.set_title(f"St {m['st']:.4f}, C_L amplitude {m['cl_amplitude']:.4f}, {int(m['n_periods'])} periods",
                     fontsize=8)
    a1.set_ylabel("C_D")
    a2.set_ylabel("C_L")
    a2.set_xlabel("t U_inf / D")
    a1.legend(fontsize=7)
    a1.set_title(f"cylinder Re={case['re']:g}, M={case['mach']:g}, {case['n_theta']} on the body, "
                 f"{summary['n_particles']} particles", fontsize=8)
    fig.tight_layout()
    fig.savefig(OUT / f"{stem}.png", dpi=120)
    print(f"wrote {OUT / stem}.json and .png")
    return result


if __name__ == "__main__":
    main()
