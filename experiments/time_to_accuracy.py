"""Time to accuracy (issue 14 item 4): error against particle count and against wall time for the
reconstruction degree x flux / low-Mach option x frame x layout, on the Taylor-Green vortex
(Re = 100, t = 1, configs/taylor_green_2d.toml) and the lid-driven cavity
(configs/lid_driven_cavity.toml, Re = 100 / 400 / 1000).

Every run is the built-in config with ``--set``-style overrides, run through the same path as
``mlsph run`` (``run_problem``); the error is the case's own metric from summary.json
(Taylor-Green: ``ke_rel_error``; cavity: max of ``ghia_u_max_abs_dev`` and ``ghia_v_max_abs_dev``).
Wall time is the whole run including compilation (what a user waits for); the compile time is
reported beside it.  Prints a markdown table, the wall time of the cheapest run per scheme that
reaches the target error (``--target``, 1 % for Taylor-Green) and writes
experiments/output/time_to_accuracy_<case>.json and, with ``--plot``, docs/figures/time_to_accuracy_<case>.png.

    python experiments/time_to_accuracy.py --case taylor_green [--sizes 16 25 32 50]
        [--schemes NAME ...] [--frames eulerian ale_shift] [--layouts cartesian perturbed] [--plot]
        [--set eos.c0=20 ...] [--tag NAME]
    python experiments/time_to_accuracy.py --case cavity --re 100 --sizes 20 40 [--plot]
    python experiments/time_to_accuracy.py --quick          # 2 sizes, 2 schemes (checks the script)

Runs one at a time (the machine's cores belong to the run).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.errors import SimulationError
from mlsph_jax.simulation import run_problem

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "experiments" / "output"
FIG = ROOT / "docs" / "figures"

#: The scheme variants compared: name -> overrides.
#: Every variant names its flux and low-Mach option, so a change of the config's defaults does not
#: change what a name means.
_PLAIN, _THORNBER = "scheme.low_mach_reconstruction=none", "scheme.low_mach_reconstruction=thornber"
SCHEMES: dict[str, tuple[str, ...]] = {
    "deg2 rusanov": ("scheme.reconstruction_degree=2", "scheme.flux=rusanov", _PLAIN),
    "deg3 rusanov": ("scheme.reconstruction_degree=3", "scheme.flux=rusanov", _PLAIN),
    "deg3 rusanov+thornber": ("scheme.reconstruction_degree=3", "scheme.flux=rusanov", _THORNBER),
    "deg3 hllc_zha": ("scheme.reconstruction_degree=3", "scheme.flux=hllc_zha", _PLAIN),
    "deg2 hllc_zha": ("scheme.reconstruction_degree=2", "scheme.flux=hllc_zha", _PLAIN),
    "deg1 rusanov+thornber": ("scheme.reconstruction_degree=1", "scheme.flux=rusanov", _THORNBER),
}

#: Extra settings of the moving frames (the scheme of configs/taylor_green_2d_mlsph.toml: linear
#: area vectors without the area correction, whose CG solve would run every stage on moving
#: particles, beta 2, C = 1, the conservation projection of decision 112).
_MOVING = ("scheme.degree=1", "scheme.beta=2.0", "scheme.area_correction=none", "scheme.conservation_projection=true")
FRAMES: dict[str, tuple[str, ...]] = {
    "eulerian": ("scheme.frame=eulerian",),
    "lagrangian": ("scheme.frame=lagrangian", *_MOVING),
    "ale_shift": ("scheme.frame=ale_shift", *_MOVING, "scheme.shift_coefficient=1.0"),
}

CASES = {
    "taylor_green": ("taylor_green_2d.toml", "ke_rel_error", 0.01),
    "cavity": ("lid_driven_cavity.toml", "ghia_max_abs_dev", 0.01),
}


def error_of(case: str, metrics: dict) -> float:
    if case == "cavity":
        return max(metrics["ghia_u_max_abs_dev"], metrics["ghia_v_max_abs_dev"])
    return metrics["ke_rel_error"]


def run_one(case: str, n: int, scheme: str, frame: str, layout: str, re: float | None,
            extra: tuple[str, ...] = ()) -> dict:
    cfg_file, _, _ = CASES[case]
    sets = [f"case.n={n}", *SCHEMES[scheme], *FRAMES[frame], "output.plots=false",
            "output.progress=false", "output.snapshots=1", *extra]
    if case == "taylor_green":
        sets.append(f"case.layout={layout}")
    if re is not None:
        sets.append(f"case.re={re!r}")
    row = {"case": case, "n": n, "scheme": scheme, "frame": frame, "layout": layout, "re": re, "overrides": sets}
    t0 = time.perf_counter()
    try:
        cfg = config.load(ROOT / "configs" / cfg_file, sets)
        s = run_problem(build_problem(cfg), cfg, out_dir=None, quiet=True).summary
    except SimulationError as e:
        row.update(status=f"failed: {str(e)[:120]}", wall_s=time.perf_counter() - t0)
        return row
    m = s["metrics"]
    if case == "taylor_green":   # sign: + = more kinetic energy than the exact incompressible flow
        row["ke_signed_error"] = m["ke"] / m["ke_exact"] - 1.0
    row.update(status=s["status"], error=error_of(case, m), wall_s=time.perf_counter() - t0,
               compile_s=s.get("compile_time_s"), n_particles=s["n_particles"], n_steps=s["n_steps"],
               updates_per_s=s.get("particle_updates_per_s"))
    return row


def time_to_target(rows: list[dict], target: float) -> dict:
    """Per (scheme, frame, layout): the wall time of the cheapest run whose error <= target."""
    best: dict = {}
    for r in rows:
        key = f"{r['scheme']} | {r['frame']} | {r['layout']}"
        best.setdefault(key, None)
        if r.get("error") is not None and r["error"] <= target:
            if best[key] is None or r["wall_s"] < best[key]["wall_s"]:
                best[key] = {"n": r["n"], "wall_s": r["wall_s"], "error": r["error"]}
    return best


def plot(rows: list[dict], case: str, path: Path, target: float) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, 4.2))
    FigureCanvasAgg(fig)
    ax1, ax2 = fig.subplots(1, 2)
    groups: dict[str, list[dict]] = {}
    for r in rows:
        if r.get("error") is not None:
            groups.setdefault(f"{r['scheme']}, {r['frame']}, {r['layout']}", []).append(r)
    for label, rs in groups.items():
        rs = sorted(rs, key=lambda r: r["n_particles"])
        ax1.loglog([r["n_particles"] for r in rs], [r["error"] for r in rs], "o-", label=label)
        ax2.loglog([r["wall_s"] for r in rs], [r["error"] for r in rs], "o-", label=label)
    for ax, xl in ((ax1, "particles"), (ax2, "wall time incl. compile [s]")):
        ax.axhline(target, color="k", lw=0.8, ls="--")
        ax.set_xlabel(xl)
        ax.set_ylabel("error")
        ax.grid(True, which="both", alpha=0.3)
    ax1.legend(fontsize=6)
    fig.suptitle(f"time to accuracy: {case}")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", choices=sorted(CASES), default="taylor_green")
    ap.add_argument("--sizes", type=int, nargs="+", default=[16, 25, 32, 50])
    ap.add_argument("--schemes", nargs="+", default=list(SCHEMES), choices=list(SCHEMES))
    ap.add_argument("--frames", nargs="+", default=["eulerian"], choices=list(FRAMES))
    ap.add_argument("--layouts", nargs="+", default=["cartesian"], choices=["cartesian", "perturbed"])
    ap.add_argument("--re", type=float, default=None, help="cavity Reynolds number (100, 400, 1000)")
    ap.add_argument("--target", type=float, default=None, help="error target (default: 1 %% / 0.01)")
    ap.add_argument("--set", nargs="+", default=[], metavar="KEY=VALUE", dest="extra",
                    help="overrides applied to every run after the variant's (e.g. eos.c0=20 time.cfl=0.15)")
    ap.add_argument("--tag", default="", help="suffix of the output JSON / figure names")
    ap.add_argument("--plot", action="store_true")
    ap.add_argument("--quick", action="store_true", help="two sizes and two schemes")
    args = ap.parse_args(argv)
    if args.quick:
        args.sizes, args.schemes = [12, 16], ["deg2 rusanov", "deg3 rusanov+thornber"]
    target = args.target if args.target is not None else CASES[args.case][2]
    if args.case == "cavity" and args.layouts != ["cartesian"]:
        ap.error("--layouts: the cavity has a Cartesian layout only")
    rows = []
    if args.extra:
        print("overrides of every run:", " ".join(args.extra))
    print("| case | n | scheme | frame | layout | error | signed | wall [s] | compile [s] | steps | updates/s "
          "| status |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for frame in args.frames:
        for layout in args.layouts:
            for scheme in args.schemes:
                for n in args.sizes:
                    r = run_one(args.case, n, scheme, frame, layout, args.re, tuple(args.extra))
                    rows.append(r)
                    err = r.get("error", math.nan)
                    print(f"| {args.case}{'' if args.re is None else f' Re {args.re:g}'} | {n} | {scheme} | {frame} | "
                          f"{layout} | {err:.3g} | {r.get('ke_signed_error', math.nan):+.3g} | {r['wall_s']:.1f} | "
                          f"{r.get('compile_s') or math.nan:.1f} | "
                          f"{r.get('n_steps', '-')} | {r.get('updates_per_s') or math.nan:.3g} | {r['status']} |",
                          flush=True)
    best = time_to_target(rows, target)
    print(f"\nwall time to error <= {target:g} (cheapest run that reaches it):")
    for key, b in best.items():
        got = "not reached" if b is None else f"{b['wall_s']:.1f} s (n = {b['n']}, error {b['error']:.3g})"
        print(f"  {key:<50} {got}")
    OUT.mkdir(parents=True, exist_ok=True)
    tag = (args.case + ("" if args.re is None else f"_re{args.re:g}") + ("_quick" if args.quick else "")
           + (f"_{args.tag}" if args.tag else ""))
    (OUT / f"time_to_accuracy_{tag}.json").write_text(json.dumps({"target": target, "runs": rows,
                                                                  "time_to_target": best}, indent=1))
    if args.plot:
        plot(rows, tag, FIG / f"time_to_accuracy_{tag}.png", target)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
