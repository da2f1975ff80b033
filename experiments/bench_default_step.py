"""Cost of a change of a built-in config's default scheme: the step of the old default against the
new one, interleaved in one process (A, B, A, B, ... best of ``--repeat``) so that the load of a
shared machine hits both alike (issue 14: "the default scheme's step at most 1.3x today's").

Each variant is the built-in config with ``--set``-style overrides, stepped ``--steps`` times at
a fixed dt (the CFL step of the config's c0 at cfl 0.3, the same for both variants) in one jitted
chunk; ``--n`` is ``case.n`` of the lattice cases (Taylor-Green, the cavity) and the particles
across the gap of the channels (Couette, Poiseuille: ``case.ny = n``, ``case.nx = n / 2``); the
time is the compiled chunk's execution (``summary["chunk_time_s"]``), compilation is reported
beside it.  Prints particle-updates/s and the ratio B / A of the best step times, and
writes experiments/output/bench_default_step.json.

    python experiments/bench_default_step.py [--config taylor_green_2d] [--n 50] [--steps 100]
        [--repeat 3] [--a scheme.low_mach_reconstruction=none eos.c0=10]
        [--b scheme.low_mach_reconstruction=thornber]
    python experiments/bench_default_step.py --config lid_driven_cavity --n 40 --steps 1000 --repeat 5 \
        --a scheme.reconstruction_degree=2 scheme.low_mach_reconstruction=none scheme.ghost_shear_dissipation=true
    python experiments/bench_default_step.py --config couette --n 40 --steps 1000 --repeat 5 \
        --a scheme.reconstruction_degree=2
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.simulation import Simulation

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "experiments" / "output" / "bench_default_step.json"


def resolution(name: str, n: int) -> list[str]:
    """The overrides that set the particle count: ``case.n`` (lattice cases), or ``case.ny = n``
    across the gap and ``case.nx = n / 2`` along it for the channels (their shipped aspect)."""
    case = config.load(ROOT / "configs" / f"{name}.toml")["case"]
    return [f"case.ny={n}", f"case.nx={max(n // 2, 1)}"] if "ny" in case else [f"case.n={n}"]


def run_once(name: str, n: int, steps: int, sets: list[str]) -> dict:
    size = resolution(name, n)
    cfg = config.load(ROOT / "configs" / f"{name}.toml", [*size, *sets, "output.plots=false", "output.progress=false"])
    c = cfg["case"]
    c0, u0 = cfg["eos"]["c0"], c.get("u0", c.get("u_lid", c.get("u_plate") or 1.0))
    dt = 0.3 * c.get("length", c.get("gap", 1.0)) / n / (c0 + u0)
    cfg = config.load(ROOT / "configs" / f"{name}.toml", [*size, *sets, "output.plots=false",
                                                         "output.progress=false", f"time.t_end={steps * dt!r}",
                                                         f"time.dt={dt!r}"])
    pb = build_problem(cfg)
    sim = Simulation(pb, dt=dt, chunk=steps, max_steps=steps + 1, headroom=cfg["scheme"]["neighbor_headroom"])
    s = sim.run(None, snapshots=1, progress=False, plots=False).summary
    return {"steps": s["n_steps"], "stepping_s": s["chunk_time_s"], "compile_s": s["compile_time_s"],
            "particle_updates_per_s": pb.particles.n * s["n_steps"] / s["chunk_time_s"]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default="taylor_green_2d")
    ap.add_argument("--n", type=int, default=50)
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--a", nargs="*", default=["scheme.low_mach_reconstruction=none", "eos.c0=10"],
                    help="overrides of variant A (the old default)")
    ap.add_argument("--b", nargs="*", default=[], help="overrides of variant B (default: the config as it is)")
    args = ap.parse_args(argv)
    rows = {"A": [], "B": []}
    for _ in range(args.repeat):
        for key, sets in (("A", args.a), ("B", args.b)):
            rows[key].append(run_once(args.config, args.n, args.steps, list(sets)))
            r = rows[key][-1]
            print(f"{key}: {r['stepping_s']:.3f} s for {r['steps']} steps "
                  f"({r['particle_updates_per_s']:.3g} particle-updates/s, compile {r['compile_s']:.1f} s)",
                  flush=True)
    best = {k: min(r["stepping_s"] / r["steps"] for r in v) for k, v in rows.items()}
    ratio = best["B"] / best["A"]
    load = os.getloadavg()
    print(f"best step: A {best['A'] * 1e3:.2f} ms, B {best['B'] * 1e3:.2f} ms, B/A = {ratio:.3f} "
          f"(load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}{', contended' if load[0] > 2.5 else ''})")
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps({"config": args.config, "n": args.n, "a": args.a, "b": args.b, "runs": rows,
                               "best_step_s": best, "ratio": ratio, "loadavg": load}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
