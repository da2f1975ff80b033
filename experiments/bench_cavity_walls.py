"""Right-hand-side cost of the lid-driven cavity with mirror ghosts and with boundary-integral walls
(``case.walls``; docs/architecture.md decision 61), and of the boundary-integral pieces.

The built-in config (cubic reconstruction) at ``--n`` particles per side, fluid at rest with the
lid moving; the geometry is computed inside each timed function (as in a step).  Timed, each
compiled ahead of time and run interleaved (best of ``--repeat``; the load average is recorded):

* ``ghosts_rhs``: ghost regeneration + geometry + ``rhs`` with the mirror ghosts;
* ``bi_rhs``: geometry + ``rhs`` with the boundary-integral walls; ``bi_interior``: without them;
* ``bi_wall_state``: the wall stencils, wall state, Riemann pressure and wall stress alone;
* ``bi_near_rows``: the search for the rows of the first-moment correction (decision 60) alone.

Prints milliseconds and particle updates per second (fluid particles / RHS time) and writes
``experiments/output/bench_cavity_walls.json``.  Not a test.

    python experiments/bench_cavity_walls.py [--n 40] [--repeat 7]
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib

from mlsph_jax import config, neighbors
from mlsph_jax.cases import build_problem
from mlsph_jax.eos import get_eos, to_primitive
from mlsph_jax.rhs import geometry, rhs
from mlsph_jax.testing import time_interleaved

ROOT = pathlib.Path(__file__).resolve().parents[1]


def cavity(n: int, walls: str):
    pb = build_problem(config.load(ROOT / "configs/lid_driven_cavity.toml",
                                   [f"case.n={n}", f"case.walls={walls}", "output.progress=false"]))
    p, sch = pb.particles, pb.scheme
    _, nl = neighbors.allocate(p.x, sch.beta * p.vol ** (1.0 / p.dim), pb.domain)
    return pb, nl


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=40)
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args(argv)
    pg, nlg = cavity(args.n, "mirror_ghosts")
    pb, nlb = cavity(args.n, "boundary_integral")
    sch, bw = pb.scheme, pb.boundary
    eos = get_eos(sch.eos)

    def with_ghosts(p, P):
        p = pg.boundary.apply(p, P)
        return rhs(p, P, geometry(p.x, p.vol, nlg, pg.scheme, pg.domain), pg.scheme, pg.boundary)

    def bi(p, P, walls=True):
        return rhs(p, P, geometry(p.x, p.vol, nlb, sch, pb.domain), sch, bw if walls else None)

    def wall_state(p, P):
        return bw.wall_state(p, P, sch, to_primitive(p.q / p.vol[:, None], eos, P))[3]

    fns = {"ghosts_rhs": lambda a, b, c, d: with_ghosts(a, b), "bi_rhs": lambda a, b, c, d: bi(c, d),
           "bi_interior": lambda a, b, c, d: bi(c, d, walls=False),
           "bi_wall_state": lambda a, b, c, d: wall_state(c, d),
           "bi_near_rows": lambda a, b, c, d: bw.near_rows(c, bw.points(d).x)[0]}
    best, compile_s = time_interleaved(fns, (pg.particles, pg.params, pb.particles, pb.params), args.repeat)
    n_fluid = args.n ** 2
    load = os.getloadavg()
    out = {"n": args.n, "fluid_particles": n_fluid, "ghost_particles": int(pg.particles.n - n_fluid),
           "wall_points": int(bw.points(pb.params).n), "correction_rows": bw.n_rows,
           "near_rows_cell_grid": bw.near_grid is not None, "load_average": load,
           "contended": load[0] > 2.5, "ms": {k: v * 1e3 for k, v in best.items()},
           "particle_updates_per_s": {k: n_fluid / best[k] for k in ("ghosts_rhs", "bi_rhs", "bi_interior")},
           "compile_s": compile_s}
    for k, v in best.items():
        pups = f"{n_fluid / v:10.3g} particle-updates/s" if k in out["particle_updates_per_s"] else ""
        print(f"{k:15s} {v * 1e3:8.2f} ms  compile {compile_s[k]:5.1f} s  {pups}")
    print(f"load average {load} ({'contended' if load[0] > 2.5 else 'idle'})")
    dest = ROOT / "experiments" / "output"
    dest.mkdir(parents=True, exist_ok=True)
    (dest / "bench_cavity_walls.json").write_text(json.dumps(out, indent=1) + "\n")
    return out


if __name__ == "__main__":
    main()
