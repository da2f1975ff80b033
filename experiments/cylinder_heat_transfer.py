"""Heat transfer from an isothermal cylinder (issue 17 item 2; docs/architecture.md decision 102).

Runs the ``cylinder`` config twice, with the body hotter and colder than the free stream by the
same amount (``case.wall_temperature`` = 1 + d and 1 - d, ``case.prandtl`` = Pr), and reports the
Nusselt number of each run (``nusselt``: Q D / (P k (T_w - T_inf))) and of their difference,

    Nu = (Q_hot - Q_cold) D / (P k (T_hot - T_cold)),

which removes the recovery temperature: at Mach M the adiabatic wall is ~ r (gamma - 1) M^2 / 2
above T_inf (r ~ Pr^(1/2)), so each single run's heat is h (T_w - T_aw), not h (T_w - T_inf).  The
same two runs give the heat-flux-weighted recovery temperature T_aw / T_inf = 1 + d (Nu_cold -
Nu_hot) / (Nu_cold + Nu_hot).  Local Nu(theta) of the difference -> a figure; every number, the
runs' wall and compile times and particle-steps per second -> JSON.  Reference: the correlations of
Churchill & Bernstein and of Hilpert (:mod:`mlsph_jax.reference.cylinder`), fits of experiments
with a scatter of ~20 %, printed beside the result (no traceable two-dimensional simulation value
is in ``../shared/reference``).

    python experiments/cylinder_heat_transfer.py [--re 40] [--n-theta 48] [--delta 0.01] [--prandtl 0.72]
        [--set KEY=VALUE ...] [--keep DIR] [--from HOT_DIR COLD_DIR]

``--from`` evaluates two finished runs (their ``config.toml`` and ``checkpoint.h5``) instead of
running them.
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import tempfile
from pathlib import Path

import numpy as np

from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.cases.cylinder import body_values, free_stream_energy
from mlsph_jax.checkpoint import read_checkpoint
from mlsph_jax.eos import get_eos, to_primitive
from mlsph_jax.plotting import subplots
from mlsph_jax.reference.cylinder import nusselt_churchill_bernstein, nusselt_hilpert
from mlsph_jax.simulation import run_problem

ROOT = Path(__file__).resolve().parents[1]


def wall_heat(out: Path) -> dict:
    """The final state of the run in ``out``: its summary numbers and the local heat flux into the
    fluid q_b at the body's quadrature points (angle theta from the base), with the scales."""
    cfg = config.load(out / "config.toml", [])
    pb = build_problem(cfg)
    p = read_checkpoint(out).particles
    P = pb.params
    prim = to_primitive(p.U, get_eos(pb.scheme.eos), P)
    bp, _, _, _, _, qb = pb.boundary.wall_state(p, P, pb.scheme, prim)
    theta, q = body_values(pb.boundary, bp.x, bp.curve, qb)
    summary = json.loads((out / "summary.json").read_text())
    return {"cfg": cfg, "theta": theta, "q": q, "kappa": float(P["physics.kappa"]), "e_inf": free_stream_energy(cfg),
            "ratio": cfg["case"]["wall_temperature"], "D": 2.0 * cfg["case"]["radius"], "summary": summary}


def run(overrides: list[str], out: Path) -> None:
    cfg = config.load(ROOT / "configs/cylinder.toml", [*overrides, "output.plots=false", "output.progress=false"])
    run_problem(build_problem(cfg), cfg, out_dir=out, quiet=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--re", type=float, default=40.0)
    ap.add_argument("--n-theta", type=int, default=48)
    ap.add_argument("--delta", type=float, default=0.01, help="T_w / T_inf = 1 +- delta")
    ap.add_argument("--prandtl", type=float, default=0.72)
    ap.add_argument("--set", nargs="*", default=[], help="further config overrides")
    ap.add_argument("--keep", type=Path, help="keep the two runs' folders here")
    ap.add_argument("--from", dest="dirs", nargs=2, type=Path, metavar=("HOT_DIR", "COLD_DIR"),
                    help="evaluate two finished runs instead of running them")
    ap.add_argument("--json", type=Path, default=ROOT / "experiments/output/cylinder_heat_transfer.json")
    ap.add_argument("--figure", type=Path, default=ROOT / "docs/figures/cylinder_heat_transfer_nu.png")
    a = ap.parse_args()

    if not a.dirs and not 0.0 < a.delta < 1.0:
        ap.error(f"invalid --delta {a.delta!r}: the runs need T_w / T_inf = 1 +- delta > 0 and != 1; "
                 "allowed: 0 < delta < 1")
    base = None
    try:
        if a.dirs:
            dirs = dict(zip(("hot", "cold"), a.dirs, strict=True))
        else:
            base = a.keep or Path(tempfile.mkdtemp(prefix="mlsph_heat_"))
            dirs = {"hot": base / "hot", "cold": base / "cold"}
            for name, sign in (("hot", 1.0), ("cold", -1.0)):
                run([f"case.re={a.re}", f"case.n_theta={a.n_theta}", f"case.prandtl={a.prandtl}",
                     f"case.wall_temperature={1.0 + sign * a.delta}", *a.set], dirs[name])
        report(dirs, a.json, a.figure)
    finally:
        if base is not None and not a.keep:
            shutil.rmtree(base, ignore_errors=True)


def report(dirs: dict, json_path: Path, figure: Path) -> None:
    """Nu of each run and of the pair, the recovery temperature, the local Nu figure and the JSON."""
    hot, cold = wall_heat(dirs["hot"]), wall_heat(dirs["cold"])
    for name, r in (("hot", hot), ("cold", cold)):
        if r["ratio"] in (0.0, 1.0):
            raise SystemExit(f"invalid {name} run {str(dirs[name])!r}: not a heated or cooled body "
                             f"(case.wall_temperature = {r['ratio']}); allowed: runs with T_w / T_inf > 0 and != 1")
    if not hot["ratio"] > 1.0 > cold["ratio"]:
        raise SystemExit(f"invalid runs: T_w / T_inf = {hot['ratio']} (hot) and {cold['ratio']} (cold); allowed: the "
                         "hot run above 1 and the cold run below")
    unsteady = [name for name, r in (("hot", hot), ("cold", cold))
                if not r["summary"].get("steady_state", {}).get("converged", False)]
    if unsteady:
        print(f"warning: the {' and '.join(unsteady)} run did not reach the steady stop (case.steady_tol): its Nu is "
              "that of the final state, not of a steady flow")
    d_e = (hot["ratio"] - cold["ratio"]) * hot["e_inf"]
    order = np.argsort(hot["theta"])
    local = (hot["q"] - cold["q"]) * hot["D"] / (hot["kappa"] * d_e)
    nu_h, nu_c = (r["summary"]["metrics"]["nusselt"] for r in (hot, cold))
    d_hot, d_cold = hot["ratio"] - 1.0, 1.0 - cold["ratio"]
    # Q = h (T_w - T_aw) on both: Nu_hot d_hot = Nu (d_hot - s), Nu_cold d_cold = Nu (d_cold + s)
    nu = (nu_h * d_hot + nu_c * d_cold) / (d_hot + d_cold)
    s = (nu_c * d_cold - nu_h * d_hot) / (nu_h * d_hot + nu_c * d_cold) * (d_hot + d_cold) / 2.0
    c = hot["cfg"]["case"]
    re, pr = c["re"], c["prandtl"]
    res = {"re": re, "prandtl": pr, "mach": c["mach"], "n_theta": c["n_theta"],
           "t_w_over_t_inf": [hot["ratio"], cold["ratio"]],
           "nusselt_hot": nu_h, "nusselt_cold": nu_c, "nusselt": nu, "recovery_temperature_ratio": 1.0 + s,
           "nusselt_front": float(np.interp(math.pi, hot["theta"][order], local[order])),
           "nusselt_base": float(local[np.argmin(np.abs(np.angle(np.exp(1j * hot["theta"]))))]),
           "churchill_bernstein": nusselt_churchill_bernstein(re, pr),
           "hilpert": nusselt_hilpert(re, pr) if 4.0 <= re < 4000.0 else None,
           "cd": [hot["summary"]["metrics"]["cd"], cold["summary"]["metrics"]["cd"]],
           "steps": [hot["summary"]["n_steps"], cold["summary"]["n_steps"]],
           "t_final": [hot["summary"]["t_final"], cold["summary"]["t_final"]],
           "n_particles": hot["summary"]["n_particles"],
           **{k: [r["summary"][k] for r in (hot, cold)]
              for k in ("wall_time_s", "compile_time_s", "particle_updates_per_s")},
           "steady": [r["summary"].get("steady_state", {}).get("converged", False) for r in (hot, cold)],
           "runs": [str(dirs["hot"]), str(dirs["cold"])]}
    for k, v in res.items():
        print(f"{k:28s} {v}")
    json_path.parent.mkdir(parents=True, exist_ok=True)
    json_path.write_text(json.dumps(res, indent=1))
    fig, ax = subplots(figsize=(6.0, 4.2))
    for r, name in ((hot, "hot"), (cold, "cold")):
        alone = r["q"] * r["D"] / (r["kappa"] * (r["ratio"] - 1.0) * r["e_inf"])
        ax.plot(np.degrees(r["theta"][order]), alone[order], ":", lw=1,
                label=f"{name} alone (T_w/T_inf = {r['ratio']:g})")
    ax.plot(np.degrees(hot["theta"][order]), local[order], "o-", ms=3, label=f"hot - cold: mean Nu = {nu:.3f}")
    ax.set_xlabel("theta [deg] (0 = base, 180 = front)")
    ax.set_ylabel("local Nu")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    ax.set_title(f"isothermal cylinder, Re = {re:g}, Pr = {pr:g}, M = {c['mach']:g}, {c['n_theta']} on the body "
                 f"(Churchill-Bernstein {res['churchill_bernstein']:.2f})", fontsize=8)
    fig.tight_layout()
    figure.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(figure, dpi=120)
    print(f"wrote {json_path} and {figure}")


if __name__ == "__main__":
    main()
