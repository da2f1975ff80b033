"""Residual of the exact steady Poiseuille profile, row by row from the walls (the consistency
probe of the boundary-integral walls, docs/architecture.md decision 54).

Sets every fluid particle of the built-in ``poiseuille`` config (``--ny`` across the gap, nx = 8)
to the exact steady state u = f L^2/(2 nu) (y/L)(1 - y/L), rho = rho0, and prints the largest
|du/dt| (the x-momentum rate per unit mass: zero for a linearly consistent scheme) in each of
the first ``--rows`` particle rows from the bottom wall, for ``--walls`` (mirror ghosts and/or
boundary-integral walls).  Not a test; ``tests/test_wall_integral.py`` asserts the result.

Usage::

    python experiments/wall_row_residual.py --ny 10 20 40
"""

from __future__ import annotations

import argparse
import os

import jax
import jax.numpy as jnp
import numpy as np

from mlsph_jax import config, neighbors
from mlsph_jax.cases import build_problem
from mlsph_jax.eos import get_eos, to_conservative
from mlsph_jax.rhs import geometry, rhs
from mlsph_jax.state import Kind


def row_residuals(walls: str, ny: int, rows: int = 4, overrides=()) -> np.ndarray:
    """Largest |du/dt| of the exact steady Poiseuille state in each of the first ``rows`` rows."""
    cfg = config.load("configs/poiseuille.toml", ["output.progress=false", "case.nx=8", f"case.ny={ny}",
                                                  f"case.walls={walls}", *overrides])
    prob = build_problem(cfg)
    p, params, scheme, domain = prob.particles, prob.params, prob.scheme, prob.domain
    nu = float(params["physics.mu"]) / cfg["eos"]["rho0"]
    f = float(params["physics.body_force"][0])
    y = np.asarray(p.x[:, 1])
    u = f / (2 * nu) * y * (1.0 - y)                       # gap 1
    fluid = np.asarray(p.kind) == Kind.FLUID
    vel = np.stack([np.where(fluid, u, 0.0), np.zeros(p.n)], axis=1)
    U = to_conservative(jnp.full(p.n, cfg["eos"]["rho0"]), jnp.asarray(vel), None, get_eos(scheme.eos), params)
    p = p.replace(q=U * p.vol[:, None])
    if prob.boundary is not None:
        p = prob.boundary.apply(p, params)
    h = scheme.beta * p.vol ** (1.0 / p.dim)
    _, nl = neighbors.allocate(p.x, h, domain)
    boundary = prob.boundary if getattr(prob.boundary, "wall_terms", None) is not None else None

    @jax.jit
    def rate(p):
        geom = geometry(p.x, p.vol, nl, scheme, domain)
        return rhs(p, params, geom, scheme, boundary)[2]

    dudt = np.asarray(rate(p)[:, 1] / p.vol) / cfg["eos"]["rho0"]
    dx = 1.0 / ny
    row = np.rint(y / dx - 0.5).astype(int)
    return np.array([np.abs(dudt[fluid & (row == r)]).max() for r in range(rows)])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--ny", type=int, nargs="+", default=[10, 20, 40])
    ap.add_argument("--rows", type=int, default=5)
    ap.add_argument("--walls", nargs="+", default=["boundary_integral", "mirror_ghosts"])
    ap.add_argument("--set", nargs="*", default=[], help="further config overrides")
    args = ap.parse_args(argv)
    for walls in args.walls:
        for ny in args.ny:
            r = row_residuals(walls, ny, args.rows, args.set)
            print(f"{walls:17s} ny={ny:3d} |du/dt| rows 1..{args.rows}: "
                  + " ".join(f"{v:.3e}" for v in r) + f"   load {os.getloadavg()[0]:.1f}", flush=True)


if __name__ == "__main__":
    main()
