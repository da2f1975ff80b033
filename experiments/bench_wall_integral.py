"""Cost of the boundary-integral walls (:mod:`mlsph_jax.wall_integral`) against the interior RHS.

Layout: a circular cylinder (radius 0.5, one quadrature point per particle spacing) in a
periodic box [-L, L]^2 of lattice particles with the body cut out, ideal gas at rest with a
smooth pressure perturbation, viscous (no-slip wall), Eulerian MLSPH-ALE (degree 2, beta 1.5).
For each spacing the geometry is computed once (not timed), then

* ``rhs``:  ``rhs(p, params, geom, scheme)`` without walls (the interior sweep alone);
* ``rhs+walls``: the same with the boundary-integral walls (stencil search, wall state,
  constrained wall fit, scatter);
* ``walls``: ``wall_terms`` alone (cell-list stencil search);
* ``walls_brute``: the same with the O(N_b N) brute-force stencil search (``grid=None``);

each compiled ahead of time (compile time reported) and timed as the best of ``--repeat`` runs
interleaved (A, B, C, A, B, C, ...) so machine load affects all alike; the load average is
recorded.  Prints particle updates per second and writes
``experiments/output/bench_wall_integral.json``.  Not a test.

Usage::

    python experiments/bench_wall_integral.py --dx 0.05 0.025 --repeat 5
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import pathlib
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from mlsph_jax import neighbors
from mlsph_jax.boundaries import BOUNDARIES
from mlsph_jax.eos import get_eos, to_conservative, to_primitive
from mlsph_jax.geometry import Circle, curve_params
from mlsph_jax.geometry.checks import inside_polygon, outline
from mlsph_jax.rhs import geometry, rhs
from mlsph_jax.scheme import Scheme
from mlsph_jax.state import Domain, Params, make_particles


def problem(dx: float, half: float):
    m = int(round(2 * half / dx))
    g = -half + (np.arange(m) + 0.5) * dx
    X, Y = np.meshgrid(g, g, indexing="ij")
    x = np.stack([X.ravel(), Y.ravel()], axis=1)
    circ = Circle("cyl", radius=0.5, n_points=int(math.ceil(math.pi / dx)))
    x = x[~inside_polygon(x, outline(circ, Params(curve_params([circ]))))]
    n = len(x)
    scheme = Scheme(eos="ideal_gas", viscous=True)
    params = Params({"eos.gamma": 1.4, "physics.mu": 0.025})
    pr = 1.0 + 0.01 * np.cos(np.pi * x[:, 0] / half) * np.cos(np.pi * x[:, 1] / half)
    U = to_conservative(jnp.ones(n), jnp.zeros((n, 2)), jnp.asarray(pr), get_eos("ideal_gas"), params)
    pf = make_particles(x, np.full(n, dx * dx), U)
    domain = Domain((-half, -half), (half, half), (True, True))
    p, walls = BOUNDARIES.get("boundary_integral").setup(pf, [], 2 * dx, params, "ideal_gas", scheme=scheme,
                                                          domain=domain, curves=(circ,))
    h = scheme.beta * p.vol ** 0.5
    _, nl = neighbors.allocate(p.x, h, domain)
    geom = jax.jit(lambda p: geometry(p.x, p.vol, nl, scheme, domain))(p)
    return p, walls, geom, scheme, params


def variants(walls, scheme) -> dict:
    """The three timed functions of (particles, params, geometry)."""
    eos = get_eos(scheme.eos)

    def wall_only(w):
        def f(p, params, geom):
            U = p.q / p.vol[:, None]
            return w.wall_terms(p, params, geom, scheme, U, to_primitive(U, eos, params), jnp.zeros_like(p.x))
        return f

    return {"rhs": lambda p, params, geom: rhs(p, params, geom, scheme),
            "rhs+walls": lambda p, params, geom: rhs(p, params, geom, scheme, walls),
            "walls": wall_only(walls), "walls_brute": wall_only(dataclasses.replace(walls, grid=None))}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dx", type=float, nargs="+", default=[0.05, 0.025])
    ap.add_argument("--half", type=float, default=2.0, help="half width of the periodic box")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)
    rows = []
    for dx in args.dx:
        p, walls, geom, scheme, params = problem(dx, args.half)
        fns = variants(walls, scheme)
        compiled, compile_s = {}, {}
        for k, f in fns.items():
            t0 = time.perf_counter()
            compiled[k] = jax.jit(f).lower(p, params, geom).compile()
            compile_s[k] = time.perf_counter() - t0
        best = {k: math.inf for k in fns}
        for _ in range(args.repeat):
            for k, f in compiled.items():
                t0 = time.perf_counter()
                jax.block_until_ready(f(p, params, geom))
                best[k] = min(best[k], time.perf_counter() - t0)
        load = os.getloadavg()[0]
        row = {"dx": dx, "n_particles": p.n, "n_wall_points": walls.curves[0].n_points,
               "capacity": walls.capacity, "best_s": best, "compile_s": compile_s,
               "particle_updates_per_s": {k: p.n / v for k, v in best.items()},
               "wall_cost_ratio": best["walls"] / best["rhs"],
               "wall_brute_cost_ratio": best["walls_brute"] / best["rhs"], "load_average": load}
        rows.append(row)
        print(f"dx={dx:g} N={p.n} Nb={row['n_wall_points']} K_b={walls.capacity}: rhs {best['rhs'] * 1e3:.2f} ms, "
              f"rhs+walls {best['rhs+walls'] * 1e3:.2f} ms, walls {best['walls'] * 1e3:.2f} ms "
              f"({row['wall_cost_ratio']:.2f} of rhs), brute-force stencils {best['walls_brute'] * 1e3:.2f} ms "
              f"({row['wall_brute_cost_ratio']:.2f}); {p.n / best['rhs+walls']:.3g} particle updates/s; "
              f"compile rhs+walls {compile_s['rhs+walls']:.1f} s; load {load:.1f}"
              + (" (contended)" if load > 2.5 else ""))
    out = pathlib.Path(__file__).parent / "output"
    out.mkdir(exist_ok=True)
    (out / "bench_wall_integral.json").write_text(json.dumps({"argv": sys.argv[1:], "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
