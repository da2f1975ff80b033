"""First order vs MOOD on the 1D Riemann problems (thesis Fig. 3.3 and 3.4; Sod).

For each built-in config (MOOD on, as shipped) and each particle count, runs the config and its
first-order version (``scheme.reconstruction_degree=0 scheme.limiter=none``), prints L1 errors,
overshoots and MOOD statistics, draws the two solutions side by side against the exact one
(docs/figures/<config>_first_vs_mood.png, at the config's own resolution) and writes
experiments/output/mood_validation.json (numbers quoted in docs/validation.md).

``--blast`` adds the 2D underwater blast (configs/blast_2d.toml, its default Delaunay layout or
``--blast-layout``) at first order and with MOOD: radial metrics and density against radius side
by side (docs/figures/blast_2d_first_vs_mood.png).

    python experiments/validate_mood.py [--sizes 100 200 400] [--blast [--blast-layout rings]]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from mlsph_jax import config  # noqa: E402
from mlsph_jax.cases import build_problem  # noqa: E402
from mlsph_jax.cases.riemann_1d import exact_solution, profile_fields  # noqa: E402
from mlsph_jax.simulation import run_problem  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = {"R1 (Tait)": "configs/riemann_r1_tait.toml", "R2 (stiffened gas)": "configs/riemann_r2_tammann.toml",
           "Sod (ideal gas)": "configs/sod_ideal_gas.toml"}
FIRST = ["scheme.reconstruction_degree=0", "scheme.limiter=none"]


def run(path: str, over: list[str]):
    cfg = config.load(ROOT / path, ["output.progress=false", *over])
    pb = build_problem(cfg)
    return cfg, pb, run_problem(pb, cfg, quiet=True)


def figure(dest: Path, title: str, cfg, pb, results):
    exact = exact_solution(cfg)
    t = cfg["time"]["t_end"]
    names = ["rho", "u", "p"]
    fig, axes = plt.subplots(2, 3, figsize=(12.5, 6.2), sharex=True)
    for row, (label, res) in enumerate(results.items()):
        x, _, f = profile_fields(res.particles, pb.params, cfg["eos"]["kind"])
        xf = np.linspace(x.min(), x.max(), 2000)
        ex = exact(xf, t)
        ppd = np.asarray(res.particles.ppd)[np.asarray(res.particles.kind) == 0]
        for ax, k in zip(axes[row], names, strict=True):
            ax.plot(xf, ex[k], "k-", lw=1.1, label="exact")
            ax.plot(x, f[k], "o", ms=3, mfc="none", color="tab:blue", label=label)
            if label.startswith("MOOD"):
                dem = ppd == 0
                ax.plot(x[dem], f[k][dem], "x", ms=4, color="tab:red", label="demoted (last step)")
            ax.set_title(f"{label}: {k}", fontsize=9)
        axes[row][0].legend(fontsize=7)
    for ax in axes[1]:
        ax.set_xlabel("x")
    fig.suptitle(f"{title}, n={cfg['case']['n']}, t={t:g}", fontsize=10)
    fig.tight_layout()
    fig.savefig(dest, dpi=110)
    plt.close(fig)


def blast(figs: Path, layout: str | None) -> dict:
    """First order vs MOOD on the 2D blast: radial metrics and a side-by-side density scatter."""
    from mlsph_jax.cases.blast_2d import radial_fields as blast_fields
    from mlsph_jax.cases.blast_2d import reference

    over = [f"case.layout={layout}"] if layout else []
    fig, axes = plt.subplots(1, 2, figsize=(12.0, 4.2), sharey=True)
    out = {}
    for ax, (label, extra) in zip(axes, (("first order", FIRST), ("MOOD", [])), strict=True):
        cfg, pb, res = run("configs/blast_2d.toml", [*over, *extra])
        s = res.summary
        m, mood = s["metrics"], s.get("mood", {})
        out[label] = {"metrics": m, "mood": mood, "n_steps": s["n_steps"], "wall_time_s": s["wall_time_s"]}
        print(f"blast_2d ({cfg['case']['layout']}) {label:<12} l1_rho_radial {m['l1_rho_radial']:.4f} "
              f"radial_spread {m['radial_spread']:.4f} (linear {m['radial_spread_linear']:.4f}) "
              f"rho_max {m['rho_max']:.1f} (reference shock {m['rho_ref_shock']:.1f}) "
              f"demoted {mood.get('flagged_fraction_mean', 0):.3f} "
              f"RHS/stage {mood.get('rhs_evaluations_per_stage', 1):.2f} "
              f"steps {s['n_steps']} wall {s['wall_time_s']:.0f} s", flush=True)
        ref = reference(cfg, s["t_final"])
        r, _, rho, _ = blast_fields(res.particles, pb.params, cfg["eos"]["kind"])
        ax.plot(r, rho, ".", ms=1.5, alpha=0.6, color="tab:blue", label=f"particles ({r.size})")
        ax.plot(ref.r, ref.rho, "k-", lw=1.1, label="radial reference")
        ax.set_title(f"{label} ({s['scheme']['method']}): l1 {m['l1_rho_radial']:.4f}, "
                     f"spread {m['radial_spread']:.4f}", fontsize=9)
        ax.set_xlabel("r [m]")
        ax.set_xlim(0.0, float(ref.r[-1]))
        ax.legend(fontsize=8, markerscale=4)
    axes[0].set_ylabel("density [kg/m^3]")
    fig.suptitle(f"2D underwater blast ({cfg['case']['layout']}), t = {cfg['time']['t_end']:g} s: first order vs "
                 "MOOD (thesis §3.7.2)", fontsize=10)
    fig.tight_layout()
    fig.savefig(figs / "blast_2d_first_vs_mood.png", dpi=110)
    plt.close(fig)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="*", default=[], help="extra particle counts (refinement)")
    ap.add_argument("--figures", default=str(ROOT / "docs" / "figures"))
    ap.add_argument("--blast", action="store_true", help="also the 2D blast, first order vs MOOD")
    ap.add_argument("--blast-layout", default=None, help="layout of the blast run (default: the config's)")
    ap.add_argument("--skip-riemann", action="store_true", help="only the blast (with --blast)")
    args = ap.parse_args()
    figs = Path(args.figures)
    figs.mkdir(parents=True, exist_ok=True)
    out = {}
    print(f"{'case':<20} {'n':>5} {'scheme':<12} {'l1_rho':>8} {'l1_u':>8} {'l1_p':>8} {'overshoot':>9} "
          f"{'demoted':>8} {'RHS/stage':>9} {'steps':>6} {'wall s':>7}")
    for name, path in ({} if args.skip_riemann else CONFIGS).items():
        n0 = config.load(ROOT / path)["case"]["n"]
        rows = []
        for n in [n0, *[s for s in args.sizes if s != n0]]:
            results = {}
            for label, over in (("first order", FIRST), ("MOOD", [])):
                cfg, pb, res = run(path, [f"case.n={n}", *over])
                s = res.summary
                m, mood = s["metrics"], s.get("mood", {})
                rows.append({"n": n, "scheme": label, **m, "mood": mood, "n_steps": s["n_steps"],
                             "wall_time_s": s["wall_time_s"], "compile_time_s": s["compile_time_s"],
                             "method": s["scheme"]["method"]})
                print(f"{name:<20} {n:>5} {label:<12} {m['l1_rho']:>8.4f} {m['l1_u']:>8.4f} {m['l1_p']:>8.4f} "
                      f"{m['overshoot']:>9.4f} {mood.get('flagged_fraction_mean', 0):>8.3f} "
                      f"{mood.get('rhs_evaluations_per_stage', 1):>9.2f} {s['n_steps']:>6} {s['wall_time_s']:>7.1f}")
                results[f"{label} ({s['scheme']['method']})"] = res
            if n == n0:
                figure(figs / f"{Path(path).stem}_first_vs_mood.png", name, cfg, pb, results)
        out[name] = {"config": path, "runs": rows}
    if args.blast:
        out["blast_2d"] = blast(figs, args.blast_layout)
    dest = ROOT / "experiments" / "output"
    dest.mkdir(parents=True, exist_ok=True)
    if (dest / "mood_validation.json").exists():  # keep the cases this invocation skipped
        out = {**json.loads((dest / "mood_validation.json").read_text()), **out}
    (dest / "mood_validation.json").write_text(json.dumps(out, indent=2))
    print(f"wrote {dest / 'mood_validation.json'} and figures in {figs}")


if __name__ == "__main__":
    main()
