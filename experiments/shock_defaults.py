"""Defaults from evidence on the shock configs (issue 14, item 2): today's scheme against candidates.

For each shock config (R1, R2, Sod, the 2D blast) runs the config as shipped (quadratic
reconstruction with MOOD) and each candidate (the same config with ``--set`` overrides, one change
at a time), one run after the other, and prints one table row per run:

* 1D tubes: ``l1_rho``, ``l1_u``, ``l1_p`` and ``overshoot`` (the largest new extremum relative to
  the jump, :func:`mlsph_jax.cases.riemann_1d.l1_errors`), ``rho_min`` (the smallest fluid density:
  R2's 5e9 Pa state must keep it positive);
* blast: ``l1_rho_radial`` in the ``l1_rho`` column and ``radial_spread_linear`` (the summary's
  metrics, :mod:`mlsph_jax.cases.blast_2d`); ``overshoot`` is the 1D definition applied to the
  radial profile averaged over bins of width dx (new extrema of the bin means beyond the radial
  reference's extremum within +-5 dx, relative to the reference's density range);
* ``demoted``: mean fraction of fluid particles MOOD sent to first order per step;
  ``RHS/st``: right-hand-side evaluations per Runge-Kutta stage; ``steps``; ``ms/step``: wall time
  of the stepping (compile time excluded) per step, for the 1D tubes the best of ``--repeat`` runs
  of each arm's compiled chunk with the arms interleaved (the machine is shared), for the blast
  its one run; ``cost``: ms/step relative to the default; ``wall``: the first run including
  compilation.

Candidates (``--arms``, default all): ``control`` (the default once more: its ``cost`` shows
how well the shared machine resolves cost differences), ``deg3`` (cubic reconstruction, MOOD
3 -> 0), ``hllc`` and ``hllc_zha`` (the low-dissipation fluxes, parachute Rusanov), ``thornber``
(low-Mach reconstruction), ``w_i`` (particles moved with their own velocity instead of the
method's interpolant of w), ``mlsph_ale`` (R2, an SPH-ALE config, with the MLS approximation
of MLSPH-ALE instead of the kernel gradients), ``sph_ale`` (the thesis' SPH-ALE with its Shepard
motion, ``position_update = "mls_literal"``: the blast's scheme before decision 114).
``--blast-dx`` runs the blast at another spacing (every arm alike); ``--set`` overrides config
keys in every arm (e.g. ``--cases sod --set scheme.position_update=mls`` gives the Sod scheme from
before its config moved to ``w_i``).

Writes experiments/output/shock_defaults.json (numbers quoted in docs/validation.md, "Defaults
from evidence: shocks").

    python experiments/shock_defaults.py [--cases r1 r2 sod blast] [--arms deg3 hllc] [--blast-dx 3e-3]
                                         [--set KEY=VALUE ...]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.eos import get_eos, to_primitive
from mlsph_jax.simulation import Simulation
from mlsph_jax.state import Kind

ROOT = Path(__file__).resolve().parents[1]
CASES = {"r1": "configs/riemann_r1_tait.toml", "r2": "configs/riemann_r2_tammann.toml",
         "sod": "configs/sod_ideal_gas.toml", "blast": "configs/blast_2d.toml"}
ARMS = {
    "default": [],
    "control": [],  # the default again, compiled and timed separately: its cost ratio is the timing resolution
    "deg3": ["scheme.reconstruction_degree=3"],
    "hllc": ["scheme.flux=hllc", "scheme.parachute_flux=rusanov"],
    "hllc_zha": ["scheme.flux=hllc_zha", "scheme.parachute_flux=rusanov"],
    "thornber": ["scheme.low_mach_reconstruction=thornber"],
    "w_i": ["scheme.position_update=w_i"],
    "mlsph_ale": ["scheme.method=mlsph_ale"],
    "sph_ale": ["scheme.method=sph_ale", "scheme.position_update=mls_literal"],
}


def run_one(case: str, arm: str, extra: list[str]):
    """First run of one arm (compiles it): the table row and the simulation (for the timing rounds)."""
    cfg = config.load(ROOT / CASES[case], ["output.progress=false", *extra, *ARMS[arm]])
    pb = build_problem(cfg)
    t, snaps = cfg["time"], cfg["output"]["snapshots"]
    sim = Simulation(pb, cfl=t.get("cfl", 0.3), dt=t.get("dt", 0.0), chunk=t.get("chunk", 50),  # as run_problem
                     max_steps=t.get("max_steps", 1_000_000), dt_min=t.get("dt_min", 1e-14),
                     headroom=cfg["scheme"].get("neighbor_headroom", 1.3), cfl_viscous=t.get("cfl_viscous", 0.125))
    t0 = time.perf_counter()
    res = sim.run(snapshots=snaps, progress=False)
    wall = time.perf_counter() - t0
    s = res.summary
    m, mood = dict(s["metrics"]), s.get("mood", {})
    fluid = np.asarray(res.particles.kind) == int(Kind.FLUID)
    rho = np.asarray(to_primitive(res.particles.U, get_eos(cfg["eos"]["kind"]), pb.params).rho)[fluid]
    if case == "blast":
        m["l1_rho"] = m["l1_rho_radial"]
    row = {"case": case, "arm": arm, "overrides": [*extra, *ARMS[arm]], "status": s["status"],
           "t_final": s["t_final"], "n_particles": s["n_particles"], "metrics": m,
           "rho_min": float(rho.min()), "conservation": s["conservation"], "mood": mood, "n_steps": s["n_steps"],
           "stepping_s": [s["wall_time_s"] - s["compile_time_s"]], "compile_time_s": s["compile_time_s"],
           "wall_time_s": wall}
    return row, (sim, snaps)


def time_rounds(rows: list[dict], sims: dict, rounds: int) -> None:
    """Rerun every arm's compiled chunk ``rounds`` times, the arms interleaved (default, a, b, ...,
    default, a, b, ...) so that the load of the shared machine hits them alike; the cost is the
    smallest stepping time (``ms_per_step`` = min / steps)."""
    for _ in range(rounds):
        for row in rows:
            if row["arm"] in sims:
                sim, snaps = sims[row["arm"]]
                again = sim.run(snapshots=snaps, progress=False).summary
                assert again["n_steps"] == row["n_steps"], "rerun differs"
                row["stepping_s"].append(again["wall_time_s"] - again["compile_time_s"])


def finish(rows: list[dict]) -> None:
    base = next((r for r in rows if r["arm"] == "default" and "n_steps" in r), None)
    for r in rows:
        if "n_steps" in r:
            r["ms_per_step"] = 1e3 * min(r["stepping_s"]) / max(int(r["n_steps"]), 1)
            r["timing_runs"] = len(r["stepping_s"])
            r["cost_vs_default"] = r["ms_per_step"] / base["ms_per_step"] if base else None


def fmt(row: dict) -> str:
    m, mood = row["metrics"], row["mood"]

    def g(k):
        v = m.get(k)
        return f"{v:>8.4f}" if v is not None else f"{'':>8}"

    return (f"{row['case']:<6} {row['arm']:<9} {g('l1_rho')} {g('l1_u')} {g('l1_p')} "
            f"{g('radial_spread_linear')} {m['overshoot']:>9.4f} {row['rho_min']:>10.1f} "
            f"{mood.get('flagged_fraction_mean', 0):>8.3f} {mood.get('rhs_evaluations_per_stage', 1):>6.2f} "
            f"{row['n_steps']:>6} {row['ms_per_step']:>8.2f} {row['cost_vs_default']:>5.2f} {row['wall_time_s']:>7.1f}"
            f"  {row['status']}")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    ap.add_argument("--arms", nargs="+", default=[a for a in ARMS if a != "default"],
                    choices=[a for a in ARMS if a != "default"], help="candidates (the default always runs)")
    ap.add_argument("--blast-dx", type=float, default=None, help="blast particle spacing (default: the config)")
    ap.add_argument("--repeat", type=int, default=25,
                    help="1D runs: best-of-n stepping time, arms interleaved (the blast runs once)")
    ap.add_argument("--set", nargs="+", default=[], metavar="KEY=VALUE", help="overrides for every arm")
    ap.add_argument("--out", default=str(ROOT / "experiments" / "output" / "shock_defaults.json"))
    args = ap.parse_args()
    print(f"{'case':<6} {'arm':<9} {'l1_rho':>8} {'l1_u':>8} {'l1_p':>8} {'spread':>8} {'overshoot':>9} "
          f"{'rho_min':>10} {'demoted':>8} {'RHS/st':>6} {'steps':>6} {'ms/step':>8} {'cost':>5} {'wall s':>7}",
          flush=True)
    rows = []
    for case in args.cases:
        extra = [*args.set, *([f"case.dx={args.blast_dx}"] if case == "blast" and args.blast_dx else [])]
        case_rows, sims = [], {}
        for arm in ["default", *args.arms]:
            try:
                row, sims[arm] = run_one(case, arm, extra)
            except Exception as e:  # a candidate that cannot run is a result, not a crash of the study
                row = {"case": case, "arm": arm, "overrides": [*extra, *ARMS[arm]], "status": f"error: {e}"}
            case_rows.append(row)
            if case == "blast":  # one run each (minutes); its first run's stepping is the cost
                sims.pop(arm, None)
        time_rounds(case_rows, sims, args.repeat - 1)
        finish(case_rows)
        for row in case_rows:
            print(fmt(row) if "n_steps" in row else f"{case:<6} {row['arm']:<9} {row['status']}", flush=True)
        rows += case_rows
    dest = Path(args.out)
    dest.parent.mkdir(parents=True, exist_ok=True)
    old = json.loads(dest.read_text())["runs"] if dest.exists() else []
    keep = [r for r in old if (r["case"], r["arm"]) not in {(x["case"], x["arm"]) for x in rows}]
    dest.write_text(json.dumps({"machine": platform.node(), "cpu_count": os.cpu_count(),
                                "runs": keep + rows}, indent=2))
    print(f"wrote {dest}")


if __name__ == "__main__":
    main()
