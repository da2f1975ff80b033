"""Experiment (c): sensitivity of the Poiseuille centre-line velocity to the viscosity, by reverse-
mode autodiff through the whole run, against central finite differences and the exact series.

Start-up Poiseuille flow between mirror walls (thesis §3.7.4): u_c(t) = u(y = H/2, t), recorded
as the differentiable diagnostic ``u_centre`` (volume-weighted mean x-velocity of the fluid
particles within half a spacing of the centre line).  Prints d u_c(t_end) / d mu from
:func:`mlsph_jax.sensitivity.sensitivity` (with ``check_fd``) and the derivative of the exact
series solution (central differences of :func:`mlsph_jax.reference.viscous.poiseuille_startup`),
and writes experiments/output/sensitivity_poiseuille.json.

    python experiments/sensitivity_poiseuille.py [--set case.nx=20 ...] [--t-end 0.5]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.reference.viscous import poiseuille_startup
from mlsph_jax.sensitivity import sensitivity
from mlsph_jax.state import Kind

ROOT = Path(__file__).resolve().parents[1]

def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", default=str(ROOT / "configs/poiseuille.toml"))
    ap.add_argument("--t-end", type=float, default=0.5)
    ap.add_argument("--set", nargs="*", default=[])
    ap.add_argument("--out", default=str(ROOT / "experiments" / "output" / "sensitivity_poiseuille.json"))
    args = ap.parse_args()
    cfg = config.load(args.config, [f"time.t_end={args.t_end}", *args.set])
    pb = build_problem(cfg)
    fluid = np.asarray(pb.particles.kind) == Kind.FLUID
    y = np.asarray(pb.particles.x[:, 1])
    H = float(y[fluid].max() + y[fluid].min())           # walls at 0 and H, layers symmetric
    dy = float(np.sqrt(np.asarray(pb.particles.vol)[fluid].mean()))
    sel = jnp.asarray(fluid & (np.abs(y - H / 2) < 0.51 * dy))

    def u_centre(p, t, params):
        u = p.q[:, 1] / p.q[:, 0]
        w = jnp.where(sel, p.vol, 0.0)
        return {"u_centre": jnp.sum(w * u) / jnp.sum(w)}

    t0 = time.perf_counter()
    res = sensitivity(pb, ["physics.mu"], "u_centre_final", check_fd=True, diagnostics=u_centre)
    wall = time.perf_counter() - t0
    e = res["gradients"]["physics.mu"]
    mu = float(pb.params["physics.mu"])
    rho0 = float(pb.params["eos.rho0"]) if "eos.rho0" in pb.params else 1.0
    g = float(np.asarray(pb.params["physics.body_force"])[0])
    yc = float(y[np.asarray(sel)].mean())
    h = 1e-4 * mu
    t_end = res["n_steps"] * res["dt"]

    def u_exact(m):
        return float(poiseuille_startup(np.array([yc]), t_end, f_x=g, nu=m / rho0, gap=H)[0])

    exact = (u_exact(mu + h) - u_exact(mu - h)) / (2 * h)
    out = {"u_centre": res["value"], "du_dmu_autodiff": e["gradient"], "du_dmu_fd": e["fd"],
           "fd_step": e["fd_step"], "rel_disagreement": e["rel_disagreement"], "du_dmu_exact_series": exact,
           "mu": mu, "t_end": t_end, "n_steps": res["n_steps"], "wall_time_s": wall}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=2))
    print(f"u_centre(t={t_end:.3g}) = {res['value']:.6g}; d u_centre / d mu: autodiff {e['gradient']:.8g}, "
          f"finite differences {e['fd']:.8g} (step {e['fd_step']:.2e}, relative disagreement "
          f"{e['rel_disagreement']:.1e}), exact series {exact:.6g}; {wall:.1f} s; wrote {args.out}")


if __name__ == "__main__":
    main()
