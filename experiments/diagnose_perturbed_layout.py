"""Why the Eulerian Taylor-Green vortex loses accuracy on a perturbed layout (issue 14; the write-up
is docs/validation.md, "Taylor-Green on the perturbed layout").

Operator measurements on the t = 0 state of ``configs/taylor_green_2d.toml`` (no time stepping),
for the Cartesian and the perturbed layout (``case.layout``, ``case.perturbation``, ``case.seed``)
at several resolutions, so that the observed order of each defect says which one dominates:

* the moments of the area vectors A_ij per particle (thesis eq. 4.36):
  ``closure`` rms |sum_j A_ij| / dx (zero in a periodic box for exact integrals);
  ``lin`` rms |sum_j A_ij (x) (x_j - x_i) / (2 V_i) - I| (the linear consistency of the
  midpoint-flux divergence; its defect is a zeroth-order error of the divergence);
  ``quad`` rms |sum_j A_ij (x) d (x) d| / (8 V_i dx) (vanishes on a lattice by symmetry);
* ``div_area``: rms error of the divergence sum_j (F(x_ij) - F_i) . A_ij / V_i of the exact
  momentum flux F = rho u u + p I evaluated *exactly* at the pair midpoints (the areas alone),
  relative to rms |div(rho u u)|; ``div_area_noself``: the same without the self term;
* ``recon``: rms error of the reconstructed midpoint states against the exact ones, relative to
  U0 (the reconstruction alone);
* ``rhs``: rms error of the scheme's inviscid momentum rate (``rhs`` at Re = 1e12) against
  -div F, relative to rms |div(rho u u)| (everything together, with the config's flux);
* ``fallback``: fraction of particles below the nominal degree (area shape functions, fit).

    python experiments/diagnose_perturbed_layout.py [--sizes 25 50 100] [--set KEY=VALUE ...]
        [--variants NAME ...]
    python experiments/diagnose_perturbed_layout.py --runs T_END ...   # whole runs instead
    python experiments/diagnose_perturbed_layout.py --bench --sizes 50 100  # cost of the correction

Writes experiments/output/diagnose_perturbed_layout.json.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from mlsph_jax import config
from mlsph_jax import neighbors as nb
from mlsph_jax.cases import build_problem
from mlsph_jax.cases.taylor_green_2d import TaylorGreen
from mlsph_jax.eos import get_eos, to_conservative
from mlsph_jax.rhs import geometry, rhs
from mlsph_jax.simulation import run_problem

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "taylor_green_2d.toml"
OUT = ROOT / "experiments" / "output"

#: name -> overrides of the built-in config
VARIANTS: dict[str, tuple[str, ...]] = {
    "default": (),
    "area deg 3": ("scheme.degree=3",),
    "area deg 1": ("scheme.degree=1",),
    "beta 2": ("scheme.beta=2.0",),
    "no thornber": ("scheme.low_mach_reconstruction=none",),
    "recon deg 2": ("scheme.reconstruction_degree=2",),
    "corr linear": ("scheme.area_correction=linear",),
    "corr quadratic": ("scheme.area_correction=quadratic",),
    "no corr": ("scheme.area_correction=none",),
}


def exact_fields(cfg):
    """Exact rho, rho u, p (functions of x) of the t = 0 state the case builds, and the flux."""
    ex = TaylorGreen.from_config(cfg)
    e = cfg["eos"]

    def prim(x):
        p = ex.pressure(x, 0.0)
        rho = e["rho0"] * (1.0 + e["gamma"] * p / (e["rho0"] * e["c0"] ** 2)) ** (1.0 / e["gamma"])
        return rho, ex.velocity(x, 0.0), p

    def flux(x):                                   # momentum flux [2, 2] at one point
        rho, u, p = prim(x)
        return rho * jnp.outer(u, u) + p * jnp.eye(2)

    def conv(x):
        rho, u, _ = prim(x)
        return rho * jnp.outer(u, u)

    def div(f):
        return jax.vmap(lambda y: jnp.einsum("abb->a", jax.jacfwd(f)(y)))

    return prim, jax.vmap(flux), div(flux), div(conv)


def measure(n: int, layout: str, overrides: tuple[str, ...]) -> dict:
    cfg = config.load(CONFIG, [f"case.n={n}", f"case.layout={layout}", "case.re=1e12", *overrides])
    pb = build_problem(cfg)
    sch = pb.scheme
    p = pb.particles
    x, vol = p.x, p.vol
    h = sch.beta * jnp.sqrt(vol)
    _, nl = nb.allocate(np.asarray(x), np.asarray(h), pb.domain, support=sch.support, headroom=1.6)
    g = geometry(x, vol, nl, sch, pb.domain)
    dxl = 1.0 / n * float(cfg["case"]["length"])
    A, d, pm = g.A, g.dx, g.pair_mask
    S = jnp.sum(A, axis=1)
    M1 = jnp.einsum("nka,nkb->nab", A, d) / (2.0 * vol[:, None, None]) - jnp.eye(2)
    M2 = jnp.einsum("nka,nkb,nkc->nabc", A, d, d) / (8.0 * vol[:, None, None, None] * dxl)
    prim, flux, divF, divC = exact_fields(cfg)
    xm = (x[:, None, :] + 0.5 * d).reshape(-1, 2)
    Fm = flux(xm).reshape(d.shape[0], d.shape[1], 2, 2)
    Fi = flux(x)
    GA = jnp.einsum("nkab,nkb->na", jnp.where(pm[..., None, None], Fm, 0.0), A)
    exact_div = divF(x)
    scale = float(jnp.sqrt(jnp.mean(jnp.sum(divC(x) ** 2, axis=-1))))
    div_self = (GA - jnp.einsum("nab,nb->na", Fi, S)) / vol[:, None]
    div_noself = GA / vol[:, None]
    # reconstruction alone: midpoint states against the exact conservative state at x_ij
    eos = get_eos(sch.eos)
    variables = sch.component("reconstruction_variables")
    F = variables.from_conservative(p.q / vol[:, None], eos, pb.params)
    own = sch.component("reconstruction").midpoint_states(F, g, sch.reconstruction_degree)
    if isinstance(own, tuple):
        own = own[0]
    rho_m, u_m, _ = prim(xm)
    U_m = to_conservative(rho_m, u_m, None, eos, pb.params).reshape(own.shape)
    F_m = variables.from_conservative(U_m.reshape(-1, U_m.shape[-1]), eos, pb.params).reshape(own.shape)
    rerr = jnp.where(pm[..., None], own - F_m, 0.0)
    recon = float(jnp.sqrt(jnp.sum(rerr[..., 1:] ** 2) / jnp.sum(pm)))
    # the whole inviscid scheme
    _, _, dq = rhs(p, pb.params, g, sch)
    rerr_rhs = dq[:, 1:] / vol[:, None] + exact_div
    fd = g.degree

    def rms(a):
        return float(jnp.sqrt(jnp.mean(jnp.sum(a.reshape(a.shape[0], -1) ** 2, axis=-1))))

    return {"n": n, "layout": layout, "overrides": list(overrides),
            "closure": rms(S) / dxl, "lin": rms(M1), "quad": rms(M2),
            "div_area": rms(div_self - exact_div) / scale, "div_area_noself": rms(div_noself - exact_div) / scale,
            "recon": recon, "rhs": rms(rerr_rhs) / scale,
            "area_fallback": float(jnp.mean(fd[:, 0] < sch.degree)),
            "fit_fallback": float(jnp.mean(fd[:, 1] < sch.fit_degree))}


def run(n: int, layout: str, overrides: tuple[str, ...], t_end: float) -> dict:
    """A whole run of the built-in config (as ``mlsph run`` with ``--set``): errors at ``t_end``."""
    sets = [f"case.n={n}", f"case.layout={layout}", f"time.t_end={t_end!r}", "output.plots=false",
            "output.progress=false", "output.snapshots=1", *overrides]
    cfg = config.load(CONFIG, sets)
    t0 = time.perf_counter()
    s = run_problem(build_problem(cfg), cfg, out_dir=None, quiet=True).summary
    m = s["metrics"]
    return {"n": n, "layout": layout, "overrides": list(overrides), "t_end": t_end,
            "ke_signed_error": m["ke"] / m["ke_exact"] - 1.0, "ke_rel_error": m["ke_rel_error"],
            "l2_velocity_error": m["l2_velocity_error"], "l2_pressure_error": m["l2_pressure_error"],
            "mass_drift": abs(s["conservation"]["mass"]), "n_steps": s["n_steps"],
            "wall_s": time.perf_counter() - t0, "status": s["status"]}


def bench(n: int, repeat: int = 3) -> dict:
    """Cost of the correction: the geometry (areas, fit, weights) of the perturbed n x n layout with
    ``area_correction`` none (A) and quadratic (B), each jitted once, timed interleaved A B A B ...,
    best of ``repeat``; plus one whole right-hand side for scale."""
    import os
    out = {"n": n, "particles": n * n, "load_average": os.getloadavg()}
    fns = {}
    for name in ("none", "quadratic"):
        cfg = config.load(CONFIG, [f"case.n={n}", "case.layout=perturbed", f"scheme.area_correction={name}"])
        pb = build_problem(cfg)
        sch, p = pb.scheme, pb.particles
        h = sch.beta * jnp.sqrt(p.vol)
        _, nl = nb.allocate(np.asarray(p.x), np.asarray(h), pb.domain, support=sch.support, headroom=1.6)
        f = jax.jit(lambda x, v, nl=nl, sch=sch, dom=pb.domain: geometry(x, v, nl, sch, dom).A)
        t0 = time.perf_counter()
        f(p.x, p.vol).block_until_ready()
        out[f"compile_s_{name}"] = time.perf_counter() - t0
        fns[name] = (f, p)
    best = {k: float("inf") for k in fns}
    for _ in range(repeat):
        for name, (f, p) in fns.items():
            t0 = time.perf_counter()
            f(p.x, p.vol).block_until_ready()
            best[name] = min(best[name], time.perf_counter() - t0)
    for name, t in best.items():
        out[f"geometry_s_{name}"] = t
        out[f"particle_updates_per_s_{name}"] = n * n / t
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[25, 50, 100])
    ap.add_argument("--layouts", nargs="+", default=["cartesian", "perturbed"])
    ap.add_argument("--variants", nargs="+", default=["default"], choices=sorted(VARIANTS))
    ap.add_argument("--set", nargs="*", default=[], help="extra KEY=VALUE overrides for every row")
    ap.add_argument("--runs", type=float, default=None, metavar="T_END",
                    help="instead of the operator measurements: whole runs to T_END")
    ap.add_argument("--bench", action="store_true",
                    help="instead: time the geometry with and without the correction at each size")
    args = ap.parse_args(argv)
    if args.bench:
        rows = [bench(n) for n in args.sizes]
        for r in rows:
            print(json.dumps(r), flush=True)
        OUT.mkdir(parents=True, exist_ok=True)
        (OUT / "diagnose_perturbed_layout_bench.json").write_text(json.dumps(rows, indent=1))
        return
    if args.runs is not None:
        keys = ("ke_signed_error", "l2_velocity_error", "l2_pressure_error", "mass_drift", "n_steps", "wall_s")
        print("| variant | layout | n | " + " | ".join(keys) + " |", flush=True)
        rows = []
        for v in args.variants:
            for lay in args.layouts:
                for n in args.sizes:
                    r = run(n, lay, VARIANTS[v] + tuple(args.set), args.runs)
                    r["variant"] = v
                    rows.append(r)
                    print(f"| {v} | {lay} | {n} | " + " | ".join(f"{r[k]:.4g}" for k in keys) + " |", flush=True)
        OUT.mkdir(parents=True, exist_ok=True)
        (OUT / f"diagnose_perturbed_layout_runs_{args.runs:g}.json").write_text(json.dumps(rows, indent=1))
        return
    keys = ("closure", "lin", "quad", "div_area", "div_area_noself", "recon", "rhs", "area_fallback", "fit_fallback")
    print("| variant | layout | n | " + " | ".join(keys) + " |")
    print("|---" * (3 + len(keys)) + "|")
    rows = []
    for v in args.variants:
        for lay in args.layouts:
            for n in args.sizes:
                t0 = time.perf_counter()
                r = measure(n, lay, VARIANTS[v] + tuple(args.set))
                r["variant"], r["wall"] = v, time.perf_counter() - t0
                rows.append(r)
                print(f"| {v} | {lay} | {n} | " + " | ".join(f"{r[k]:.3g}" for k in keys) + " |", flush=True)
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "diagnose_perturbed_layout.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
