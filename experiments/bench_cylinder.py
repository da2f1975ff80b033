"""Cost of the flow past a cylinder (``configs/cylinder.toml``, issue 17): step throughput,
compile time and the share of the boundary-integral body in the right-hand side.

For each ``--set``-style layout (``--n-theta`` values; the config's other settings):

* ``rhs``: the interior right-hand side alone (no body), ``rhs+walls``: with the body's boundary
  term, ``walls``: the body's ``wall_terms`` alone, and ``band``: the in-run crossing/overflow
  check of every committed step, all with the walls as the run uses them (Eulerian particles:
  the wall-point stencils and near-wall rows searched once, ``integrate.fixed_boundary``), and
  ``walls+search``: ``wall_terms`` with the searches redone at every call (what a moving frame
  pays per stage); each compiled ahead of time (compile time reported) and timed as the best of
  ``--repeat`` runs interleaved (A, B, C, D, A, ...) so machine load affects all alike;
* ``run``: ``--steps`` SSP-RK3 steps of the full simulation at a fixed step near the CFL step (no output):
  particle-steps per second over the stepping chunks (summary ``chunk_time_s``: set-up, compilation
  and output excluded), and the compile time.

``--steady``: steps to the steady state (``case.steady_tol``) with and without the convergence
accelerator, local time stepping (``time.local_time_stepping``, decision 62), for each
``--ratios`` value of ``time.local_step_ratio``: steps, wall time, C_D and C_p of each run
(``--steady-set`` adds overrides; default the study's coarse layout: n_theta 32, far field at
40 D, Mach 0.2).

The load average is recorded beside every timing ("contended" above 2.5).  Prints a line per
layout and writes ``experiments/output/bench_cylinder.json``.  Not a test.

Usage::

    python experiments/bench_cylinder.py --n-theta 32 48 --steps 200 --repeat 5
    python experiments/bench_cylinder.py --n-theta --steady --ratios 8 16
    python experiments/bench_cylinder.py --n-theta 32 --set case.layout=blend case.blend_radius=1.5 case.r_far=4

``--set`` adds config overrides to the timed layouts (e.g. another ``case.layout``, decision 72).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys
import time

from mlsph_jax import config as config_mod
from mlsph_jax import neighbors
from mlsph_jax.cases import build_problem
from mlsph_jax.integrate import fixed_boundary
from mlsph_jax.rhs import geometry
from mlsph_jax.simulation import run_problem
from mlsph_jax.testing import CONFIG_DIR, time_interleaved

sys.path.insert(0, str(pathlib.Path(__file__).parent))
from bench_wall_integral import variants as wall_variants  # noqa: E402  (the same three timed functions)


def load(n_theta: int, extra=()):
    return config_mod.load(CONFIG_DIR / "cylinder.toml", [f"case.n_theta={n_theta}", "output.plots=false",
                                                          "output.progress=false", *extra])


def variants(walls, scheme, searched=None) -> dict:
    """``rhs``, ``rhs+walls``, ``walls`` of experiments/bench_wall_integral.py and the ``band`` check
    for ``walls``; ``walls+search``: ``walls`` of the unfixed ``searched`` walls, if given."""
    out = {k: v for k, v in wall_variants(walls, scheme).items() if k != "walls_brute"}
    out["band"] = lambda p, params, geom: walls.band_status(p, params)
    if searched is not None:
        out["walls+search"] = wall_variants(searched, scheme)["walls"]
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n-theta", type=int, nargs="*", default=[32, 48], help="layouts timed (none: only --steady)")
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--steady", action="store_true", help="steps to steady state with/without local time steps")
    ap.add_argument("--ratios", type=float, nargs="+", default=[4.0], help="time.local_step_ratio values")
    ap.add_argument("--steady-set", nargs="*", default=list(STEADY_STUDY), help="overrides of the steady study")
    ap.add_argument("--set", nargs="*", default=[], dest="overrides", help="config overrides of the timed layouts")
    args = ap.parse_args(argv)
    rows = []
    steady = steady_study(args.steady_set, args.ratios) if args.steady else []
    for nt in args.n_theta:
        cfg = load(nt, args.overrides)
        t_setup = time.perf_counter()
        pb = build_problem(cfg)
        setup_s = time.perf_counter() - t_setup
        p, params, scheme, walls = pb.particles, pb.params, pb.scheme, pb.boundary
        h = scheme.beta * p.vol ** 0.5
        _, nl = neighbors.allocate(p.x, h, pb.domain)
        geom = geometry(p.x, p.vol, nl, scheme, pb.domain)
        run_walls = fixed_boundary(walls, scheme, p, params)
        best, compile_s = time_interleaved(variants(run_walls, scheme, None if run_walls is walls else walls),
                                           (p, params, geom), args.repeat)
        load_rhs = os.getloadavg()[0]
        dt = 1e-3 * 48 / nt     # about the CFL step at cfl 0.3 (fixed: the step count is exact)
        run_cfg = load(nt, [*args.overrides, f"time.dt={dt!r}", f"time.t_end={args.steps * dt!r}", "case.steady_tol=0",
                            "output.snapshots=1", "time.local_time_stepping=false"])
        res = run_problem(build_problem(run_cfg), run_cfg, out_dir=None, quiet=True)
        s = res.summary
        run_s = s["chunk_time_s"]   # the stepping chunks alone (wall time less set-up, compilation and output)
        load_run = os.getloadavg()[0]
        row = {"n_theta": nt, "overrides": args.overrides, "setup_s": setup_s,
               "n_particles": p.n, "n_wall_points": nt, "capacity": walls.capacity,
               "best_s": best, "compile_s": compile_s, "wall_cost_ratio": best["walls"] / best["rhs"],
               "band_cost_ratio": best["band"] / best["rhs"], "walls_fixed": run_walls is not walls,
               "run_steps": int(s["n_steps"]),
               "run_s": run_s, "run_compile_s": s["compile_time_s"], "dt_last": s["dt_last"],
               "particle_steps_per_s": p.n * int(s["n_steps"]) / run_s, "load_average_rhs": load_rhs,
               "load_average_run": load_run}
        rows.append(row)
        tag = lambda v: f"load {v:.1f}" + (" (contended)" if v > 2.5 else "")  # noqa: E731
        print(f"n_theta={nt} {' '.join(args.overrides)} N={p.n} K_b={walls.capacity} (set-up {setup_s:.1f} s):\n"
              f"  rhs {best['rhs'] * 1e3:.2f} ms, rhs+walls "
              f"{best['rhs+walls'] * 1e3:.2f} ms, walls {best['walls'] * 1e3:.2f} ms ({row['wall_cost_ratio']:.2f} "
              f"of rhs), band check {best['band'] * 1e3:.2f} ms"
              + (f", walls with the searches {best['walls+search'] * 1e3:.2f} ms" if "walls+search" in best else "")
              + f"; {tag(load_rhs)}\n"
              f"  run: {row['run_steps']} steps in {run_s:.1f} s = {row['particle_steps_per_s']:.3g} particle-steps/s "
              f"(dt {s['dt_last']:.3g}), compile {s['compile_time_s']:.1f} s; {tag(load_run)}", flush=True)
    out = pathlib.Path(__file__).parent / "output"
    out.mkdir(exist_ok=True)
    (out / "bench_cylinder.json").write_text(json.dumps({"argv": sys.argv[1:], "rows": rows, "steady": steady},
                                                        indent=1))


#: the steady study's layout: the config's far field (40 D) at the coarse n_theta = 32, Mach 0.2
STEADY_STUDY = ("case.n_theta=32", "case.mach=0.2", "time.t_end=80", "output.snapshots=80", "case.steady_tol=1e-3")


def steady_study(overrides, ratios) -> list[dict]:
    """One run with the global step, one per local-step ratio, each to ``case.steady_tol``."""
    out = []
    for ratio in [None, *ratios]:
        extra = (["time.local_time_stepping=false"] if ratio is None
                 else ["time.local_time_stepping=true", f"time.local_step_ratio={ratio!r}"])
        cfg = config_mod.load(CONFIG_DIR / "cylinder.toml", ["output.plots=false", "output.progress=false",
                                                             *overrides, *extra])
        try:
            s = run_problem(build_problem(cfg), cfg, out_dir=None, quiet=True).summary
            m = s["metrics"]
            row = {"local_step_ratio": ratio, "status": s["status"], "steps": int(s["n_steps"]),
                   "t_final": s["t_final"], "steady": s["steady_state"], "wall_s": s["wall_time_s"],
                   "compile_s": s.get("compile_time_s"), "updates_per_s": s.get("particle_updates_per_s"),
                   **{k: m[k] for k in ("cd", "cd_pressure", "cp_front", "cp_base", "recirculation_length")}}
        except Exception as e:   # a diverging variant is a result of the study, not a crash of it
            row = {"local_step_ratio": ratio, "status": f"failed: {e}"}
        row["load_average"] = os.getloadavg()[0]
        out.append(row)
        print("steady study", {k: (round(v, 5) if isinstance(v, float) else v) for k, v in row.items()}, flush=True)
    return out


if __name__ == "__main__":
    main()
