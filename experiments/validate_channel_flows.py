"""Validation of the Couette and Poiseuille start-up flows (thesis §3.7.4, Figs. 3.16-3.19).

1. The built-in configs (thesis resolution: 40 particles across the gap, 20 along; Re = 10,
   t = 10 s, or ``--t-end``): velocity profiles at output times against the exact series
   solutions (thesis Figs. 3.17 left / 3.18 top right) -> docs/figures/channel_couette_profiles.png,
   channel_poiseuille_profiles.png.  ``--lagrangian`` adds the Lagrangian Poiseuille run of
   Fig. 3.17 (right).
2. Thesis Fig. 3.19: early-time Couette profiles at Re = 100 (t = 0.2 s) and Re = 1000 (t = 2 s)
   for several resolutions -> channel_couette_resolution_re100_re1000.png.
3. Convergence analysis at Re = 10: normalised L-infinity and L2 errors of u against the exact
   solution at t = 1 s (transient; Couette and Poiseuille) and of the Poiseuille flow at t = 10 s
   (steady) vs dx, with observed orders -> channel_convergence.png.

The flow is one-dimensional, so the sweeps use 8 particles along the plates (the smallest
period the mlsph_ale stencil allows; the solution does not depend on it) and CFL 0.6 (the
metrics agree with CFL 0.3 to 4 digits: tests/test_channel_flows.py).  JSON with every number
(metrics, time series, wall times, orders) goes to experiments/output/channel_validation.json.

    python experiments/validate_channel_flows.py [--sizes 10 20 40 80] [--steady-sizes 10 20 40]
        [--fig319-sizes 20 40 80 160] [--skip-builtin] [--lagrangian] [--t-end 10]
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
from mlsph_jax.cases.channel_flows import drives, exact
from mlsph_jax.reference.viscous import channel_u_max
from mlsph_jax.simulation import run_problem
from mlsph_jax.state import Kind

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = {"couette": "configs/couette.toml", "poiseuille": "configs/poiseuille.toml"}
SWEEP = ["case.nx=8", "time.cfl=0.6", "output.progress=false", "output.plots=false"]


def run(path: str, overrides, out_dir=None):
    cfg = config.load(ROOT / path, list(overrides))
    t0 = time.perf_counter()
    r = run_problem(build_problem(cfg), cfg, out_dir=out_dir, quiet=True)
    s = r.summary
    row = {"overrides": list(overrides), **s["metrics"], "n_steps": s["n_steps"], "t_final": s["t_final"],
           "wall_time_s": s["wall_time_s"], "compile_time_s": s["compile_time_s"],
           "total_time_s": time.perf_counter() - t0, "n_particles": s["n_particles"]}
    return cfg, r, row


def orders(h, e):
    h, e = np.asarray(h, float), np.asarray(e, float)
    return [float(o) for o in np.log(e[:-1] / e[1:]) / np.log(h[:-1] / h[1:])]


def builtin(figs: Path, t_end: float | None, lagrangian: bool) -> dict:
    out = {}
    jobs = [(name, path, []) for name, path in CONFIGS.items()]
    if lagrangian:
        jobs.append(("poiseuille_lagrangian", CONFIGS["poiseuille"], ["scheme.frame=lagrangian"]))
    for name, path, extra in jobs:
        ov = ["output.progress=false", "output.snapshots=40", *extra]
        if t_end is not None:
            ov.append(f"time.t_end={t_end}")
        tmp = Path(tempfile.mkdtemp(prefix=f"channel_{name}_"))
        _, r, row = run(path, ov, out_dir=tmp)
        row["timeseries"] = r.summary["timeseries"]
        shutil.copy(tmp / "profiles.png", figs / f"channel_{name}_profiles.png")
        shutil.rmtree(tmp)
        out[name] = row
        print(f"{name:<22} ny=40 t={row['t_final']:.4g}: linf_u_error {row['linf_u_error']:.3e}, l2 "
              f"{row['l2_u_error']:.3e}, max|v| {row['max_abs_v']:.1e}; {row['n_steps']} steps, "
              f"{row['wall_time_s']:.0f} s wall ({row['compile_time_s']:.0f} s compiling)", flush=True)
    return out


def fig319(figs: Path, sizes) -> dict:
    """Couette, Re = 100 at t = 0.2 and Re = 1000 at t = 2, several resolutions (thesis Fig. 3.19)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = {}
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2))
    for ax, (re, t) in zip(axes, ((100, 0.2), (1000, 2.0)), strict=True):
        rows = []
        for ny in sizes:
            cfg, r, row = run(CONFIGS["couette"], [*SWEEP, f"case.ny={ny}", f"physics.mu={1.0 / re}",
                                                   f"time.t_end={t}", "output.snapshots=1"])
            rows.append({"ny": ny, **row})
            p = r.particles
            fl = np.asarray(p.kind) == int(Kind.FLUID)
            y = np.asarray(p.x)[fl, 1]
            u = np.asarray(p.q[:, 1] / p.q[:, 0])[fl]
            o = np.argsort(y)
            ax.plot(u[o], y[o], ".-", ms=3, lw=0.8, label=f"{ny} particles across")
            print(f"couette Re={re:<5} t={t:<4} ny={ny:<4} linf_u_error {row['linf_u_error']:.3e} "
                  f"l2 {row['l2_u_error']:.3e} ({row['n_steps']} steps, {row['wall_time_s']:.0f} s)", flush=True)
        yf = np.linspace(0.0, 1.0, 801)
        ax.plot(exact(cfg, yf, t), yf, "k-", lw=1.2, label="exact (eq. 3.20)")
        ax.set_ylim(0.6 if re == 100 else 0.85, 1.0)
        ax.set_xlabel("u / u_p")
        ax.set_ylabel("y / L")
        ax.set_title(f"Couette Re = {re}, t = {t} s", fontsize=9)
        ax.legend(fontsize=7)
        ax.grid(True, alpha=0.3)
        dx = [1.0 / r_["ny"] for r_ in rows]
        out[f"re{re}_t{t}"] = {"runs": rows, "orders_linf": orders(dx, [r_["linf_u_error"] for r_ in rows]),
                               "orders_l2": orders(dx, [r_["l2_u_error"] for r_ in rows])}
        print(f"  observed orders linf {np.round(out[f're{re}_t{t}']['orders_linf'], 2).tolist()}, "
              f"l2 {np.round(out[f're{re}_t{t}']['orders_l2'], 2).tolist()}", flush=True)
    fig.suptitle("Couette start-up near the moving plate, refinement (cf. thesis Fig. 3.19); "
                 "MLSPH-ALE, Eulerian", fontsize=9)
    fig.tight_layout()
    fig.savefig(figs / "channel_couette_resolution_re100_re1000.png", dpi=120)
    plt.close(fig)
    return out


def convergence(figs: Path, sizes, steady_sizes) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    studies = [("couette", 1.0, sizes), ("poiseuille", 1.0, sizes), ("poiseuille", 10.0, steady_sizes)]
    out = {}
    fig, ax = plt.subplots(figsize=(6.4, 4.6))
    for (name, t, ns), mk in zip(studies, ("o", "s", "^"), strict=True):
        rows = []
        for ny in ns:
            cfg, r, row = run(CONFIGS[name], [*SWEEP, f"case.ny={ny}", f"time.t_end={t}", "output.snapshots=1"])
            rows.append({"ny": ny, "dx": 1.0 / ny, **row})
            print(f"{name:<11} t={t:<5} ny={ny:<4} linf_u_error {row['linf_u_error']:.3e} "
                  f"l2_u_error {row['l2_u_error']:.3e} ({row['n_steps']} steps, {row['wall_time_s']:.0f} s)",
                  flush=True)
        dx = [r_["dx"] for r_ in rows]
        linf = [r_["linf_u_error"] for r_ in rows]
        l2 = [r_["l2_u_error"] for r_ in rows]
        key = f"{name}_t{t:g}"
        out[key] = {"runs": rows, "orders_linf": orders(dx, linf), "orders_l2": orders(dx, l2),
                    "u_max": channel_u_max(**drives(cfg))}
        print(f"  observed orders linf {np.round(out[key]['orders_linf'], 2).tolist()}, "
              f"l2 {np.round(out[key]['orders_l2'], 2).tolist()}", flush=True)
        ax.loglog(dx, linf, mk + "-", label=f"{name}, t = {t:g} s, L-inf")
        ax.loglog(dx, l2, mk + "--", mfc="none", label=f"{name}, t = {t:g} s, L2")
    d = np.array([1 / 10, 1 / 80])
    for k, ls in ((2, ":"), (3, "-.")):
        ax.loglog(d, 0.02 * (d / d[0]) ** k, "k" + ls, lw=0.8, label=f"order {k}")
    ax.set_xlabel("dx / L")
    ax.set_ylabel("error / u_max")
    degree = config.load(ROOT / "configs/couette.toml", [])["scheme"]["reconstruction_degree"]
    ax.set_title("Channel flows, Re = 10: error vs particle spacing\n(MLSPH-ALE, reconstruction degree "
                 f"{degree} (the configs'), Eulerian, mirror-ghost walls)", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(figs / "channel_convergence.png", dpi=120)
    plt.close(fig)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="+", default=[10, 20, 40, 80],
                    help="particles across the gap for the t = 1 convergence study")
    ap.add_argument("--steady-sizes", type=int, nargs="+", default=[10, 20, 40],
                    help="particles across the gap for the steady Poiseuille study (t = 10)")
    ap.add_argument("--fig319-sizes", type=int, nargs="+", default=[20, 40, 80, 160])
    ap.add_argument("--t-end", type=float, default=None, help="end time of the built-in runs (default: config)")
    ap.add_argument("--skip-builtin", action="store_true")
    ap.add_argument("--lagrangian", action="store_true", help="also run the Lagrangian Poiseuille flow")
    ap.add_argument("--figures", default=str(ROOT / "docs" / "figures"))
    args = ap.parse_args()
    figs = Path(args.figures)
    figs.mkdir(parents=True, exist_ok=True)
    res = {"args": vars(args)}
    if not args.skip_builtin:
        res["builtin"] = builtin(figs, args.t_end, args.lagrangian)
    res["fig_3_19"] = fig319(figs, args.fig319_sizes)
    res["convergence"] = convergence(figs, args.sizes, args.steady_sizes)
    dest = ROOT / "experiments" / "output"
    dest.mkdir(parents=True, exist_ok=True)
    (dest / "channel_validation.json").write_text(json.dumps(res, indent=2))
    print(f"wrote {dest / 'channel_validation.json'} and figures channel_*.png in {figs}")


if __name__ == "__main__":
    main()
