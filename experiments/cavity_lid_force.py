"""The tangential force a mirror-ghost lid exerts on a prescribed lid layer, split into its viscous
and inviscid parts (decision 81: the Rusanov flux' wall friction of fluid-ghost pairs).

The lid-driven cavity config with a steady layer u = U(s), s = 1 - y, v = 0, rho = rho0 below the
lid (``--delta`` its thickness), the ghosts regenerated from it, and one right-hand side: the
x-momentum rate of the particle rows below the lid, averaged over the central columns
|x - 0.5| < 0.2 (the state does not depend on x, so what they receive comes through the lid).
The inviscid part is the rate with physics.mu = 0, the viscous part the rest.  The exact rate is
mu U''(s) (the layer is a steady parallel flow with no pressure gradient), so the inviscid part
should vanish; summed over the rows, the column integral is the force per unit lid length.
Two profiles: U = exp(-s/delta) (U''(0) != 0: the odd ghost extension u_G = 2 u_W - u_F has a
curvature kink at the wall) and U = 1 - tanh(s/delta) (U''(0) = 0: the extension is exact).

    python experiments/cavity_lid_force.py --n 50 --re 1000
    python experiments/cavity_lid_force.py --n 50 --re 1000 --set scheme.ghost_shear_dissipation=false
"""

from __future__ import annotations

import argparse
import sys

import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=50, help="particles per side")
    ap.add_argument("--re", type=float, default=1000.0)
    ap.add_argument("--delta", type=float, default=0.03, help="thickness of the prescribed lid layer")
    ap.add_argument("--rows", type=int, default=6, help="particle rows below the lid summed")
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="config overrides")
    a = ap.parse_args(argv)

    import jax
    import jax.numpy as jnp

    from mlsph_jax import config
    from mlsph_jax import neighbors as nb
    from mlsph_jax.cases import build_problem
    from mlsph_jax.eos import get_eos, to_conservative
    from mlsph_jax.rhs import geometry, rhs
    from mlsph_jax.state import Kind, Params
    from mlsph_jax.testing import CONFIG_DIR

    cfg = config.load(CONFIG_DIR / "lid_driven_cavity.toml",
                      [f"case.n={a.n}", f"case.re={a.re!r}", "output.progress=false", "output.plots=false", *a.set])
    pb = build_problem(cfg)
    p, scheme, params = pb.particles, pb.scheme, pb.params
    _, nlist = nb.allocate(p.x, scheme.beta * p.vol ** 0.5, pb.domain)
    rate = jax.jit(lambda q, P: rhs(q, P, geometry(q.x, q.vol, nlist, scheme, pb.domain), scheme, pb.boundary)[2])
    inviscid_params = Params({**{k: params[k] for k in params}, "physics.mu": jnp.asarray(0.0)})
    x = np.asarray(p.x)
    fluid = np.asarray(p.kind) == int(Kind.FLUID)
    dx, mu, d = 1.0 / a.n, float(params["physics.mu"]), a.delta
    columns = fluid & (np.abs(x[:, 0] - 0.5) < 0.2)
    rows = np.sort(np.unique(np.round(x[columns, 1], 10)))[::-1][:a.rows]
    profiles = {
        "exp(-s/delta) (U''(0) != 0)": (lambda s: np.exp(-s / d), lambda s: np.exp(-s / d) / d ** 2),
        "1 - tanh(s/delta) (U''(0) = 0)": (lambda s: 1.0 - np.tanh(s / d),
                                           lambda s: 2.0 * np.tanh(s / d) / np.cosh(s / d) ** 2 / d ** 2),
    }
    print(f"n = {a.n}, Re = {a.re:g}, mu = {mu:g}, delta = {d:g} ({d / dx:.2f} dx), "
          f"scheme.ghost_shear_dissipation = {scheme.ghost_shear_dissipation}")
    for name, (U, Upp) in profiles.items():
        s = 1.0 - x[:, 1]
        vel = np.stack([U(s), 0.0 * s], axis=1)
        cons = to_conservative(jnp.ones(len(x)), jnp.asarray(vel), None, get_eos(scheme.eos), params)
        q = pb.boundary.apply(p.replace(q=cons * p.vol[:, None]), params)
        total = np.asarray(rate(q, params))[:, 1] / np.asarray(p.vol)
        inviscid = np.asarray(rate(q, inviscid_params))[:, 1] / np.asarray(p.vol)
        print(f"== U = {name}\n  row y    s/dx   exact mu U''   viscous      inviscid")
        force = {"exact": 0.0, "viscous": 0.0, "inviscid": 0.0}
        for y in rows:
            m = columns & (np.abs(x[:, 1] - y) < 1e-9)
            exact, visc, inv = mu * Upp(1.0 - y), (total - inviscid)[m].mean(), inviscid[m].mean()
            print(f"  {y:.4f}  {(1.0 - y) / dx:5.2f}  {exact:11.4e}  {visc:11.4e}  {inv:11.4e}")
            force["exact"] += exact * dx
            force["viscous"] += visc * dx
            force["inviscid"] += inv * dx
        print(f"  force per unit lid length over these rows: exact {force['exact']:.4e}, viscous "
              f"{force['viscous']:.4e}, inviscid {force['inviscid']:.4e} "
              f"({force['inviscid'] / force['exact']:.2f} x the exact)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
