"""Validation of the weakly compressible Taylor-Green vortex (thesis §3.7.3, Figs. 3.10-3.13; §4.5.1, Fig. 4.6).

1. Decay runs (thesis Figs. 3.10-3.12): the built-in config configs/taylor_green_2d.toml
   (L = 1, Eulerian MLSPH-ALE, quadratic reconstruction) at ``--n`` particles per side to
   ``--t-end`` for each Reynolds number in ``--re`` (default 10, 100, 1000): kinetic-energy
   factor E_k/E_k0 against exp(-16 pi^2 t / Re) and max |u| / U0 against exp(-8 pi^2 t / Re)
   (Fig. 3.11), pressure at the particle nearest the centre against the exact
   rho0 U0^2/2 exp(-16 pi^2 t / Re) (Fig. 3.12), and the u, v, p fields at t_end for Re = 100
   (Fig. 3.10).
2. Convergence study: relative L2 velocity error (and the pressure and energy errors) at
   ``--conv-t`` for Re = 100 and n in ``--conv-sizes`` on the Cartesian and the perturbed
   (+-0.15 dx, seed 1) layouts, with the observed orders log2(e(n) / e(2n)) / log2(2n / n).
3. ``--fig313``: the pressure along y = L/2 at t* = 6 for Re = 1000 against the exact
   solution, at each n of ``--fig313-sizes`` (thesis Fig. 3.13; particles within dx/2 of the
   line, gauge pressure minus its mean; writes docs/figures/taylor_green_fig313_pressure_line.png).
4. ``--fig46``: the §4.5.1 run, configs/taylor_green_2d_mlsph.toml ([0, 2 pi]^2, 50 x 50,
   Re = 100 on L / 2 pi), in the particle-shifting ALE frame and Eulerian: max |u| and E_k
   against exp(-2 nu t) and exp(-4 nu t), nu = 0.01 (thesis eq. 4.41, Fig. 4.6; writes
   docs/figures/taylor_green_fig46_decay.png).

Writes experiments/output/taylor_green_validation.json and docs/figures/taylor_green_decay.png,
taylor_green_fields_re100.png, taylor_green_convergence.png.  The defaults (n = 50 to t = 1;
convergence 16, 32, 64 to t = 0.2) take about 6 minutes on 2 cores; the thesis resolution is
``--n 100`` (about 10 minutes per Reynolds number).

    python experiments/validate_taylor_green.py [--n 50] [--t-end 1.0] [--re 10 100 1000]
        [--conv-sizes 16 32 64] [--conv-t 0.2] [--layouts cartesian perturbed]
        [--method mlsph_ale] [--skip-decay] [--skip-convergence]
        [--fig313 [--fig313-sizes 50]] [--fig46]
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.cases.taylor_green_2d import TaylorGreen, plot_fields
from mlsph_jax.simulation import run_problem

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "taylor_green_2d.toml"
#: The thesis' setting (Mach 0.1, no low-Mach option), which the built-in config left in issue 14
#: (c0 = 20 and Thornber's correction there): the figures here reproduce the thesis'.
THESIS = ("eos.c0=10", "scheme.low_mach_reconstruction=none")
OUT = ROOT / "experiments" / "output" / "taylor_green_validation.json"


def run(overrides):
    cfg = config.load(CONFIG, [*THESIS, *overrides, "output.plots=false", "output.progress=false"])
    pb = build_problem(cfg)
    t0 = time.perf_counter()
    res = run_problem(pb, cfg, out_dir=None, quiet=True)
    return cfg, pb, res, time.perf_counter() - t0


def decay_study(args, figs: Path) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = {}
    print(f"decay runs: n = {args.n}, t_end = {args.t_end}, method {args.method}")
    print(f"{'Re':>7} {'ke_rel':>9} {'umax_rel':>9} {'l2_u':>9} {'l2_p':>9} {'steps':>6} {'wall s':>7}")
    for re in args.re:
        cfg, pb, res, wall = run([f"case.n={args.n}", f"case.re={re!r}", f"time.t_end={args.t_end!r}",
                                  f"scheme.method={args.method}", f"output.snapshots={args.samples}"])
        s = res.summary
        m = s["metrics"]
        out[str(re)] = {"metrics": m, "timeseries": s["timeseries"], "n_steps": s["n_steps"], "wall_s": wall,
                        "compile_s": s["compile_time_s"]}
        print(f"{re:>7g} {m['ke_rel_error']:>9.4f} {m['umax_rel_error']:>9.4f} {m['l2_velocity_error']:>9.4f} "
              f"{m['l2_pressure_error']:>9.4f} {s['n_steps']:>6} {wall:>7.1f}", flush=True)
        if re == 100:
            plot_fields(figs / "taylor_green_fields_re100.png", res.particles, s["t_final"], pb.params,
                        TaylorGreen.from_config(cfg), "tait", title=pb.description)

    fig, axes = plt.subplots(1, 3, figsize=(14.0, 4.0))
    tf = np.linspace(0.0, args.t_end, 400)
    for k, (re, r) in enumerate(out.items()):
        col = f"C{k}"
        ts = {key: np.asarray(v) for key, v in r["timeseries"].items()}
        ex = np.exp(-16 * math.pi**2 * tf / float(re))
        axes[0].plot(tf, ex, "-", color=col, lw=1.0)
        axes[0].plot(ts["t"], ts["ke"] / ts["ke"][0], "o", ms=3.5, mfc="none", color=col, label=f"Re = {float(re):g}")
        axes[1].plot(tf, np.sqrt(ex), "-", color=col, lw=1.0)
        axes[1].plot(ts["t"], ts["umax"], "o", ms=3.5, mfc="none", color=col, label=f"Re = {float(re):g}")
        if float(re) >= 100:
            axes[2].plot(tf, 0.5 * ex, "-", color=col, lw=1.0)
            axes[2].plot(ts["t"], ts["p_centre"], "o", ms=3.5, mfc="none", color=col, label=f"Re = {float(re):g}")
    axes[0].set_ylabel("$E_k / E_{k0}$ (lines: exp(-16 pi^2 t / Re))")
    axes[1].set_ylabel("max |u| / U0 (lines: exp(-8 pi^2 t / Re))")
    axes[2].set_ylabel("p - p0 at the centre (lines: exact)")
    for ax in axes:
        ax.set_xlabel("t U0 / L")
        ax.legend(fontsize=8)
    fig.suptitle(f"Taylor-Green vortex, {args.n}x{args.n} Cartesian, {args.method} quadratic reconstruction, "
                 "Eulerian (thesis Figs. 3.11, 3.12)", fontsize=9)
    fig.tight_layout()
    fig.savefig(figs / "taylor_green_decay.png", dpi=120)
    plt.close(fig)
    return out


def convergence_study(args, figs: Path) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = {}
    print(f"convergence: Re = 100, t = {args.conv_t}, method {args.method}")
    print(f"{'layout':>10} {'n':>4} {'l2_u':>10} {'order':>6} {'l2_p':>10} {'order':>6} {'ke_rel':>10} "
          f"{'steps':>6} {'wall s':>7}")
    for layout in args.layouts:
        rows = []
        for n in args.conv_sizes:
            _, _, res, wall = run([f"case.n={n}", "case.re=100.0", f"case.layout={layout}", "case.perturbation=0.15",
                                   "case.seed=1", f"time.t_end={args.conv_t!r}", f"scheme.method={args.method}",
                                   "output.snapshots=1"])
            m = res.summary["metrics"]
            row = {"n": n, "dx": 1.0 / n, **{k: m[k] for k in ("l2_velocity_error", "l2_pressure_error",
                                                                 "ke_rel_error", "umax_rel_error")},
                   "n_steps": res.summary["n_steps"], "wall_s": wall}
            if rows:
                f = math.log(n / rows[-1]["n"])
                row["order_velocity"] = math.log(rows[-1]["l2_velocity_error"] / row["l2_velocity_error"]) / f
                row["order_pressure"] = math.log(rows[-1]["l2_pressure_error"] / row["l2_pressure_error"]) / f
            rows.append(row)
            ou = f"{row['order_velocity']:6.2f}" if "order_velocity" in row else "     -"
            op = f"{row['order_pressure']:6.2f}" if "order_pressure" in row else "     -"
            print(f"{layout:>10} {n:>4} {row['l2_velocity_error']:>10.4g} {ou} {row['l2_pressure_error']:>10.4g} {op} "
                  f"{row['ke_rel_error']:>10.4g} {row['n_steps']:>6} {wall:>7.1f}", flush=True)
        out[layout] = rows

    fig, ax = plt.subplots(figsize=(5.8, 4.4))
    for k, (layout, rows) in enumerate(out.items()):
        dx = np.array([r["dx"] for r in rows])
        ax.loglog(dx, [r["l2_velocity_error"] for r in rows], "o-", color=f"C{k}", label=f"velocity, {layout}")
        ax.loglog(dx, [r["l2_pressure_error"] for r in rows], "s--", color=f"C{k}", mfc="none",
                  label=f"pressure, {layout}")
    dx = np.array([1.0 / n for n in args.conv_sizes])
    e0 = out[args.layouts[0]][-1]["l2_velocity_error"]
    for p, st in ((2, ":"), (3, "-.")):
        ax.loglog(dx, e0 * (dx / dx[-1]) ** p, "k" + st, lw=0.8, label=f"order {p}")
    ax.set_xlabel("dx / L")
    ax.set_ylabel("relative L2 error")
    ax.set_title(f"Taylor-Green, Re = 100, t = {args.conv_t}, {args.method} degree 2, Eulerian", fontsize=8)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(figs / "taylor_green_convergence.png", dpi=120)
    plt.close(fig)
    return out


def fig313_study(args, figs: Path) -> dict:
    """Thesis Fig. 3.13: p along y = L/2 at t* = 6, Re = 1000."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mlsph_jax.cases.taylor_green_2d import fields

    out = {}
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    xs = np.linspace(0.0, 1.0, 400)
    for k, n in enumerate(args.fig313_sizes):
        cfg, pb, res, wall = run([f"case.n={n}", "case.re=1000.0", "time.t_end=6.0", f"scheme.method={args.method}",
                                  "output.snapshots=2"])
        t = res.summary["t_final"]
        exact = TaylorGreen.from_config(cfg)
        f = fields(res.particles, pb.params, "tait")
        y = f["x"][:, 1]
        yc = y[np.argmin(np.abs(y - 0.5 * exact.length))]           # the particle row nearest y = L/2
        line = np.isclose(y, yc, rtol=0.0, atol=1e-9 * exact.length)
        order = np.argsort(f["x"][line, 0])
        xy, p = f["x"][line][order], f["p"][line][order]
        x = xy[:, 0]
        p = p - np.sum(f["vol"] * f["p"]) / np.sum(f["vol"])              # gauge: the mean is free (WC)
        pe_all = np.asarray(exact.pressure(f["x"], t))
        pe = np.asarray(exact.pressure(xy, t)) - np.sum(f["vol"] * pe_all) / np.sum(f["vol"])
        amp = float(exact.pressure_amplitude(t))
        err = float(np.sqrt(np.mean((p - pe) ** 2)) / amp)
        out[str(n)] = {"t": t, "line_rms_error_rel": err, "wall_s": wall, "n_steps": res.summary["n_steps"],
                       "metrics": res.summary["metrics"]}
        print(f"Fig. 3.13: n = {n}, t = {t:.3f}, row y = {yc:.4f}: RMS error of p relative to the exact amplitude "
              f"{err:.4f}, {res.summary['n_steps']} steps, {wall:.0f} s", flush=True)
        ax.plot(x, p, "o", ms=3.5, mfc="none", color=f"C{k}", label=f"{n} x {n}")
    ax.plot(xs, np.asarray(exact.pressure(np.stack([xs, np.full_like(xs, yc)], 1), t)), "k-", lw=1.0,
            label=f"exact at y = {yc:.4f}")
    ax.set_xlabel("x / L")
    ax.set_ylabel("p - <p> on the particle row nearest y = L/2")
    ax.set_title(f"Taylor-Green, Re = 1000, t* = 6 (thesis Fig. 3.13), {args.method}, Eulerian", fontsize=8)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(figs / "taylor_green_fig313_pressure_line.png", dpi=120)
    plt.close(fig)
    return out


def fig46_study(args, figs: Path) -> dict:
    """Thesis Fig. 4.6: the §4.5.1 run (2 pi box, Re = 100 on L / 2 pi), ALE-shift and Eulerian."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cfg_path = ROOT / "configs" / "taylor_green_2d_mlsph.toml"
    out = {}
    fig, axes = plt.subplots(1, 2, figsize=(10.0, 4.0))
    for k, frame in enumerate(("ale_shift", "eulerian")):
        cfg = config.load(cfg_path, [f"scheme.frame={frame}", "output.plots=false", "output.progress=false",
                                     "output.snapshots=40"])
        pb = build_problem(cfg)
        t0 = time.perf_counter()
        res = run_problem(pb, cfg, out_dir=None, quiet=True)
        wall = time.perf_counter() - t0
        s = res.summary
        ts = {key: np.asarray(v) for key, v in s["timeseries"].items()}
        out[frame] = {"metrics": s["metrics"], "conservation": s["conservation"], "wall_s": wall,
                      "n_steps": s["n_steps"], "status": s["status"]}
        m = s["metrics"]
        print(f"Fig. 4.6: {frame}: ke_rel_error {m['ke_rel_error']:.4f}, umax_rel_error {m['umax_rel_error']:.4f}, "
              f"l2_velocity_error {m['l2_velocity_error']:.4f}, status {s['status']}, {s['n_steps']} steps, "
              f"{wall:.0f} s", flush=True)
        axes[0].plot(ts["t"], ts["umax"], "o", ms=3.5, mfc="none", color=f"C{k}", label=frame)
        axes[1].plot(ts["t"], ts["ke"] / ts["ke"][0], "o", ms=3.5, mfc="none", color=f"C{k}", label=frame)
    tf = np.linspace(0.0, float(cfg["time"]["t_end"]), 200)
    decay = np.asarray(TaylorGreen.from_config(cfg).decay(tf))        # exp(-2 nu t), eq. 4.41
    axes[0].plot(tf, decay, "k-", lw=1.0, label="exact exp(-2 nu t)")
    axes[1].plot(tf, decay ** 2, "k-", lw=1.0, label="exact exp(-4 nu t)")
    axes[0].set_ylabel("max |u| / U0")
    axes[1].set_ylabel("$E_k / E_{k0}$")
    for ax in axes:
        ax.set_xlabel("t")
        ax.legend(fontsize=8)
    fig.suptitle("Taylor-Green on [0, 2 pi]^2, Re = 100, 50 x 50, MLSPH-ALE (thesis §4.5.1, Fig. 4.6)", fontsize=9)
    fig.tight_layout()
    fig.savefig(figs / "taylor_green_fig46_decay.png", dpi=120)
    plt.close(fig)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=50, help="particles per side of the decay runs")
    ap.add_argument("--t-end", type=float, default=1.0, help="end time of the decay runs (thesis: t* = 1)")
    ap.add_argument("--re", type=float, nargs="+", default=[10.0, 100.0, 1000.0])
    ap.add_argument("--samples", type=int, default=20, help="output times of the decay runs")
    ap.add_argument("--conv-sizes", type=int, nargs="+", default=[16, 32, 64])
    ap.add_argument("--conv-t", type=float, default=0.2)
    ap.add_argument("--layouts", nargs="+", default=["cartesian", "perturbed"])
    ap.add_argument("--method", default="mlsph_ale")
    ap.add_argument("--figures", default=str(ROOT / "docs" / "figures"))
    ap.add_argument("--skip-decay", action="store_true")
    ap.add_argument("--skip-convergence", action="store_true")
    ap.add_argument("--fig313", action="store_true", help="also the Re = 1000, t* = 6 pressure line (Fig. 3.13)")
    ap.add_argument("--fig313-sizes", type=int, nargs="+", default=[50])
    ap.add_argument("--fig46", action="store_true", help="also the §4.5.1 run in both frames (Fig. 4.6)")
    args = ap.parse_args(argv)
    figs = Path(args.figures)
    figs.mkdir(parents=True, exist_ok=True)
    result = {"config": str(CONFIG.relative_to(ROOT)), "method": args.method}
    if not args.skip_decay:
        result["decay"] = {"n": args.n, "t_end": args.t_end, "runs": decay_study(args, figs)}
    if not args.skip_convergence:
        result["convergence"] = {"t": args.conv_t, "re": 100.0, "perturbation": 0.15, "seed": 1,
                                 "layouts": convergence_study(args, figs)}
    if args.fig313:
        result["fig313"] = fig313_study(args, figs)
    if args.fig46:
        result["fig46"] = fig46_study(args, figs)
    OUT.parent.mkdir(parents=True, exist_ok=True)
    if OUT.exists():  # keep the studies this invocation skipped
        result = {**json.loads(OUT.read_text()), **result}
    OUT.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {OUT.relative_to(ROOT)} and figures in {figs}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
