"""Linear consistency of the cylinder's right-hand side (docs/validation.md, "Flow past a cylinder").

A fluid at rest with uniform density and a linear pressure p = p0 + g.x has the exact rate
d(rho u)/dt = -g.  Prints the largest relative residual |rhs_mom / V + g| / |g| in each of the
first rings around the body, with the near-wall first-moment correction (decision 60) and with it
switched off, and in the interior (3 D < r < 0.8 r_far).  Writes
``experiments/output/cylinder_linear_residual.json``.  Not a test.

Usage::

    python experiments/cylinder_linear_residual.py --n-theta 48 --r-far 10 [--set scheme.area_correction=quadratic]
"""

from __future__ import annotations

import argparse
import json
import pathlib

import jax
import jax.numpy as jnp
import numpy as np

from mlsph_jax import config
from mlsph_jax import wall_integral as wi
from mlsph_jax.cases import build_problem
from mlsph_jax.eos import get_eos, to_conservative
from mlsph_jax.rhs import rhs
from mlsph_jax.run import setup_run
from mlsph_jax.state import Kind
from mlsph_jax.testing import CONFIG_DIR

jax.config.update("jax_enable_x64", True)

GRAD_P = np.array([0.3, 0.1])


def residuals(n_theta: int, r_far: float, rings: int = 5, extra=()) -> dict:
    cfg = config.load(CONFIG_DIR / "cylinder.toml", [f"case.n_theta={n_theta}", f"case.r_far={r_far!r}", *extra])
    pb = build_problem(cfg)
    p, params, scheme = pb.particles, pb.params, pb.scheme
    x = np.asarray(p.x)
    r = np.hypot(x[:, 0], x[:, 1])
    U = to_conservative(jnp.ones(len(x)), jnp.zeros_like(p.x), jnp.asarray(71.4 + x @ GRAD_P), get_eos(scheme.eos),
                        params)
    p = p.replace(q=U * p.vol[:, None])
    geom = setup_run(pb).geometry_fn(p)(p)
    fluid = np.asarray(p.kind) == Kind.FLUID

    def residual():
        _, _, dq = jax.jit(lambda z: rhs(z, params, geom, scheme, pb.boundary))(p)
        mom = np.asarray(dq)[:, 1:3] / np.asarray(p.vol)[:, None]
        return np.linalg.norm(mom + GRAD_P, axis=1) / np.linalg.norm(GRAD_P)

    with_corr = residual()
    orig = wi.moment_defect
    wi.moment_defect = lambda *a, **k: jnp.zeros_like(orig(*a, **k))
    try:
        without = residual()
    finally:
        wi.moment_defect = orig
    radii = np.unique(np.round(r[fluid], 6))[:rings]
    out = {"n_theta": n_theta, "r_far": r_far, "rings": []}
    for k, rr in enumerate(radii):
        m = fluid & (np.abs(r - rr) < 1e-5)
        out["rings"].append({"ring": k, "r": float(rr), "with_correction": float(with_corr[m].max()),
                             "without_correction": float(without[m].max())})
        print(f"ring {k} (r = {rr:.3f}): largest relative residual {with_corr[m].max():.2e} with the correction, "
              f"{without[m].max():.2e} without")
    inner = fluid & (r > 3.0) & (r < 0.8 * r_far)
    out["interior_with_correction"] = float(with_corr[inner].max())
    print(f"interior (3 < r < {0.8 * r_far:g}): largest relative residual {with_corr[inner].max():.2e}")
    # every fluid row, also those next to the frozen rings and in the graded cloud (decision 92)
    out["all_fluid_with_correction"] = float(with_corr[fluid].max())
    out["status_bits"] = int(np.asarray(geom.overflow))
    print(f"all {int(fluid.sum())} fluid rows: largest relative residual {with_corr[fluid].max():.2e} "
          f"(geometry status bits {out['status_bits']}: 0 = area correction converged)")
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n-theta", type=int, default=48)
    ap.add_argument("--r-far", type=float, default=10.0)
    ap.add_argument("--set", nargs="*", default=[], help="config overrides, e.g. scheme.area_correction=quadratic")
    args = ap.parse_args(argv)
    res = residuals(args.n_theta, args.r_far, extra=args.set)
    out = pathlib.Path(__file__).parent / "output"
    out.mkdir(exist_ok=True)
    (out / "cylinder_linear_residual.json").write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
