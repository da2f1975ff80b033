"""Validation of the lid-driven cavity against Ghia et al. (1982) (thesis §3.7.5, Figs. 3.22-3.23).

Runs the built-in config (Re = 100, 40 x 40 particles, to a steady state) with the runs given
as ``RE:N[:T_END]`` (Reynolds number, particles per side, end time; default: the config's
t_end), e.g. ``--runs 100:40 100:50 400:32:40 1000:32:40`` (coarse Re = 400 / 1000) or
``--runs 100:100`` (thesis resolution).  Outputs are written every second (the steady-state
test compares consecutive outputs).  For every run: centre-line profiles u(x = L/2, y) and
v(x, y = L/2) against Ghia (cf. Fig. 3.22) and speed contours with streamlines (cf. Fig. 3.23)
-> docs/figures/cavity_re{Re}_n{n}_centerlines.png / _field.png, plus one figure with every
run's centre lines (cavity_centerlines_all.png); metrics, steady-state stop, time series and
wall times -> experiments/output/cavity_validation.json.  Printed per run: where along the centre
lines the largest u and v deviations sit (signed, > 0 = above Ghia) and the time series of both
deviations, u_min and the steady-state residual at every output (is the steady stop early?);
``--keep DIR`` keeps each run's output folder (a snapshot per second in fields.h5).

    python experiments/validate_cavity.py [--runs 100:40 ...] [--set KEY=VALUE ...] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.cases.lid_driven_cavity import (
    centerlines,
    finish_centerline_figure,
    ghia_deviations,
    worst_points,
)
from mlsph_jax.reference import ghia
from mlsph_jax.simulation import run_problem

ROOT = Path(__file__).resolve().parents[1]
CFG = "configs/lid_driven_cavity.toml"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", nargs="+", default=["100:40"], help="RE:N[:T_END] per run")
    ap.add_argument("--set", nargs="*", default=[], help="further config overrides")
    ap.add_argument("--figures", default=str(ROOT / "docs" / "figures"))
    ap.add_argument("--keep", default=None, metavar="DIR",
                    help="keep every run's output folder (fields.h5 with a snapshot per second, summary.json, "
                         "timeseries.csv) as DIR/cavity_re{Re}_n{n} instead of deleting it")
    args = ap.parse_args()
    figs = Path(args.figures)
    figs.mkdir(parents=True, exist_ok=True)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = []
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10.5, 4.6))
    line = np.linspace(0.0, 1.0, 201)
    colors = iter(plt.cm.tab10.colors)
    print(f"{'Re':>6} {'n':>4} {'t_final':>8} {'steady':>7} {'u_dev':>8} {'v_dev':>8} {'u_rms':>8} {'v_rms':>8} "
          f"{'u_min':>8} {'steps':>6} {'wall s':>7}")
    for spec in args.runs:
        parts = spec.split(":")
        re, n = float(parts[0]), int(parts[1])
        ov = [f"case.re={re:g}", f"case.n={n}", "output.progress=false", *args.set]
        if len(parts) > 2:
            t_end = float(parts[2])
            ov += [f"time.t_end={t_end:g}", f"output.snapshots={max(1, round(t_end))}"]
        cfg = config.load(ROOT / CFG, ov)
        pb = build_problem(cfg)
        stem = f"cavity_re{re:g}_n{n}"
        tmp = Path(args.keep) / stem if args.keep else Path(tempfile.mkdtemp(prefix="cavity_"))
        t0 = time.perf_counter()
        r = run_problem(pb, cfg, out_dir=tmp, quiet=True)
        total = time.perf_counter() - t0
        s = r.summary
        shutil.copy(tmp / "centerlines.png", figs / f"{stem}_centerlines.png")
        shutil.copy(tmp / "velocity_field.png", figs / f"{stem}_field.png")
        if not args.keep:
            shutil.rmtree(tmp)
        m = s["metrics"]
        row = {"re": re, "n": n, "overrides": ov, "metrics": m, "steady_state": s.get("steady_state"),
               "t_final": s["t_final"], "n_steps": s["n_steps"], "n_particles": s["n_particles"],
               "wall_time_s": s["wall_time_s"], "compile_time_s": s["compile_time_s"], "total_time_s": total,
               "conservation": s["conservation"], "timeseries": s.get("timeseries")}
        re_table = ghia.table_reynolds(re)
        if re_table is not None:
            dev = ghia_deviations(r.particles, pb.params, pb.config, pb.scheme, re_table)
            row["deviations"] = {k: [list(map(float, a)) for a in ab] for k, ab in zip("uv", dev, strict=True)}
            row["worst"] = worst_points(dev)
        runs.append(row)
        st = s.get("steady_state") or {}
        g = {k: m.get(k, float("nan")) for k in ("ghia_u_max_abs_dev", "ghia_v_max_abs_dev", "ghia_u_rms_dev",
                                                  "ghia_v_rms_dev")}
        print(f"{re:>6g} {n:>4} {s['t_final']:>8.3g} {str(st.get('converged', '-')):>7} "
              f"{g['ghia_u_max_abs_dev']:>8.4f} {g['ghia_v_max_abs_dev']:>8.4f} "
              f"{g['ghia_u_rms_dev']:>8.4f} {g['ghia_v_rms_dev']:>8.4f} "
              f"{m['u_min_centerline']:>8.4f} {s['n_steps']:>6} {s['wall_time_s']:>7.0f}", flush=True)
        if "worst" in row:
            (yu, du), (xv, dv) = row["worst"]["u"], row["worst"]["v"]
            print(f"       largest deviations: u {du:+.4f} at y = {yu:.4f} L, v {dv:+.4f} at x = {xv:.4f} L")
        ts = s.get("timeseries") or {}
        if "ghia_u_max_abs_dev" in ts:
            print("       t: u_dev v_dev u_min residual | " + "; ".join(
                f"{t:g}: {a:.4f} {b:.4f} {c:.4f} {d:.2g}" for t, a, b, c, d in zip(
                    ts["t"], ts["ghia_u_max_abs_dev"], ts["ghia_v_max_abs_dev"], ts["u_min_centerline"],
                    ts.get("velocity_change_rate", [float("nan")] * len(ts["t"])), strict=True)), flush=True)
        col = next(colors)
        u_line, v_line = centerlines(r.particles, pb.params, pb.config, pb.scheme, line, line)
        a1.plot(u_line, line, "-", color=col, lw=1.1, label=f"Re={re:g}, {n}x{n}")
        a2.plot(line, v_line, "-", color=col, lw=1.1, label=f"Re={re:g}, {n}x{n}")
    for k, re in enumerate(sorted({ghia.table_reynolds(r_["re"]) for r_ in runs} - {None})):
        mk = "osd"[k % 3]
        yg, ug = ghia.centerline("u", re)
        xg, vg = ghia.centerline("v", re)
        a1.plot(ug, yg, "k" + mk, ms=4, mfc="none", label=f"Ghia et al. 1982, Re={re}")
        a2.plot(xg, vg, "k" + mk, ms=4, mfc="none", label=f"Ghia et al. 1982, Re={re}")
    finish_centerline_figure(fig, a1, a2, "Lid-driven cavity: centre lines vs Ghia et al. (1982) (cf. thesis "
                             "Fig. 3.22); MLSPH-ALE, Eulerian, mirror ghosts", figs / "cavity_centerlines_all.png")
    plt.close(fig)
    dest = ROOT / "experiments" / "output"
    dest.mkdir(parents=True, exist_ok=True)
    (dest / "cavity_validation.json").write_text(json.dumps({"args": vars(args), "runs": runs}, indent=2))
    print(f"wrote {dest / 'cavity_validation.json'} and figures cavity_*.png in {figs}")


if __name__ == "__main__":
    main()
