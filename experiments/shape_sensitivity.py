"""Shape sensitivity of the drag of an elliptic body at Re = 40 (issue 17 item 8): d C_D / d alpha
and d C_D / d aspect by reverse-mode autodiff through the whole run, against central finite
differences, and a short optax optimisation of the angle of attack.

The body is the ``cylinder`` case's ``case.body = "ellipse"`` (docs/architecture.md decision 65):
equal-area radius R = 0.5 (D = 2R, the coefficients' length), aspect ratio A = a/b, angle of
attack alpha (realised by turning the free stream to (cos alpha, sin alpha); drag and lift are
the force along and across it); the body-fitted layout is the polar one carried by a conformal
(Joukowski) map, so particle positions and volumes are jnp functions of A and the initial and
far-field state one of alpha (``problem.particles_at``).  The
run is a fixed number of global SSP-RK3 steps (``make_simulate``, checkpoint ``step``) from the
impulsive start to ``--t-end``; the objective is C_D at t_end.  The finite differences use the
same compiled run (same neighbour lists), steps ``--fd-rel`` x |value|.

The optimisation minimises C_D(t_end) over alpha at fixed A with optax L-BFGS (no line search,
unit learning rate: its first step is the plain gradient step, later ones use the secant
curvature), starting from ``--opt-alpha0`` degrees.  By the body's symmetry the optimum is alpha = 0
exactly, which checks the whole chain.

Prints the derivatives with their relative AD/FD difference, the compile and run times, the
gradient/forward cost ratio and the load average; writes experiments/output/shape_sensitivity.json
and shape_sensitivity_opt.png (not committed).

    python experiments/shape_sensitivity.py [--t-end 4] [--aspect 2] [--alpha 5] [--opt-iters 4]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.differentiable import check, make_simulate, with_param
from mlsph_jax.run import default_steps
from mlsph_jax.testing import CONFIG_DIR

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "experiments" / "output"
ALPHA, ASPECT = "geometry.body.alpha", "geometry.body.aspect"
F64 = jnp.float64


def load():
    return os.getloadavg()[0]


def build(args):
    cfg = config.load(CONFIG_DIR / "cylinder.toml", [
        f"case.n_theta={args.n_theta}", f"case.r_far={args.r_far}", f"case.mach={args.mach}", "case.body=ellipse",
        f"case.aspect={args.aspect}", f"case.alpha={args.alpha}", f"time.t_end={args.t_end}", "case.steady_tol=0",
        "time.local_time_stepping=false", "output.plots=false", "output.progress=false", *args.set])
    return cfg, build_problem(cfg)


def make_objective(pb, args, t_end, records=10):
    """``(f(theta) -> (C_D(t_end), SimOutput), simulate)`` with theta = {alpha, aspect}."""
    n = default_steps(pb, cfl=args.cfl, t_end=t_end)
    n = records * math.ceil(n / records)
    coeffs = pb.differentiable_metrics

    def diag(p, t, P):
        co = coeffs(p, t, P)
        return {"cd": co["cd"], "cl": co["cl"]}

    sim = make_simulate(pb, n_steps=n, t_end=t_end, cfl=args.cfl, checkpoint="step", record_every=n // records,
                        diagnostics=diag)

    def f(theta):
        P = pb.params
        for k, v in theta.items():
            P = with_param(P, k, v)
        out = sim(P, pb.particles_at(P))
        return out.series["cd"][-1], out

    return f, sim


def timed(fn, *a):
    t0 = time.perf_counter()
    r = fn(*a)
    jax.block_until_ready(r)
    return r, time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n-theta", type=int, default=32)
    ap.add_argument("--r-far", type=float, default=3.0, help="outer radius of the fluid (R = 0.5: 3.0 = 6 D)")
    ap.add_argument("--mach", type=float, default=0.2)
    ap.add_argument("--aspect", type=float, default=2.0)
    ap.add_argument("--alpha", type=float, default=5.0, help="angle of attack of the sensitivity point, degrees")
    ap.add_argument("--t-end", type=float, default=4.0)
    ap.add_argument("--cfl", type=float, default=0.6)
    ap.add_argument("--fd-rel", type=float, default=1e-5)
    ap.add_argument("--steady-t", type=float, default=20.0,
                    help="also run forward to this time to measure how far C_D(t_end) is from steady (0: skip)")
    ap.add_argument("--opt-iters", type=int, default=4)
    ap.add_argument("--opt-alpha0", type=float, default=10.0, help="start of the optimisation, degrees")
    ap.add_argument("--once", action="store_true",
                    help="time the gradient once (its compile included) instead of a second, compiled call")
    ap.add_argument("--set", nargs="*", default=[])
    ap.add_argument("--out", default=str(OUT / "shape_sensitivity.json"))
    args = ap.parse_args()

    cfg, pb = build(args)
    f, sim = make_objective(pb, args, args.t_end)
    theta0 = {ALPHA: jnp.asarray(math.radians(args.alpha), F64), ASPECT: jnp.asarray(args.aspect, F64)}
    res = {"config": {k: v for k, v in vars(args).items()}, "particles": pb.particles.n,
           "n_steps": sim.n_steps, "dt": sim.dt, "load_start": load()}
    print(f"ellipse A={args.aspect:g}, alpha={args.alpha:g} deg, Re={cfg['case']['re']:g}, M={args.mach:g}: "
          f"{pb.particles.n} particles, {sim.n_steps} steps of dt={sim.dt:.4g} to t={args.t_end:g} "
          f"(load {load():.2f})")

    fwd = jax.jit(f)
    (cd, out), t_first = timed(fwd, theta0)
    check(out, sim)
    (cd, out), t_fwd = timed(fwd, theta0)
    vg = jax.jit(jax.value_and_grad(f, has_aux=True))
    ((cd_g, out_g), g), t_gfirst = timed(vg, theta0)
    check(out_g, sim)
    t_grad = t_gfirst
    if not args.once:
        ((cd_g, out_g), g), t_grad = timed(vg, theta0)
    res.update(cd=float(cd), cl=float(out.series["cl"][-1]), cd_series=np.asarray(out.series["cd"]).tolist(),
               times=np.asarray(out.times).tolist(), compile_forward_s=t_first - t_fwd, forward_s=t_fwd,
               compile_gradient_s=None if args.once else t_gfirst - t_grad, gradient_s=t_grad,
               gradient_includes_compile=bool(args.once), gradient_over_forward=t_grad / t_fwd,
               load_after_timing=load())
    print(f"C_D(t={args.t_end:g}) = {float(cd):.6f}, C_L = {res['cl']:.6f}; forward {t_fwd:.1f} s (compile "
          f"{t_first - t_fwd:.1f} s), value+gradient {t_grad:.1f} s "
          f"({'its compile included' if args.once else f'compile {t_gfirst - t_grad:.1f} s'}): "
          f"ratio {t_grad / t_fwd:.1f} (load {load():.2f})")

    grads = {}
    for k, name in ((ALPHA, "alpha [per rad]"), (ASPECT, "aspect")):
        h = args.fd_rel * abs(float(theta0[k]))
        up, dn = dict(theta0), dict(theta0)
        up[k], dn[k] = theta0[k] + h, theta0[k] - h
        (cu, ou), (cdn, odn) = fwd(up), fwd(dn)
        check(ou, sim)
        check(odn, sim)
        fd = (float(cu) - float(cdn)) / (2 * h)
        ad = float(g[k])
        rel = abs(ad - fd) / max(abs(ad), abs(fd))
        grads[k] = {"autodiff": ad, "fd": fd, "fd_step": h, "rel_difference": rel}
        print(f"d C_D / d {name}: autodiff {ad:.10g}, central FD {fd:.10g} (step {h:.2e}): relative difference "
              f"{rel:.2e}")
    res["gradients"] = grads

    if args.steady_t > args.t_end:
        f_long, sim_long = make_objective(pb, args, args.steady_t)
        (cd_long, out_long), t_long = timed(jax.jit(f_long), theta0)
        check(out_long, sim_long)
        s = np.asarray(out_long.series["cd"])
        res["steady_check"] = {"t": args.steady_t, "n_steps": sim_long.n_steps, "cd": float(cd_long),
                               "cd_series": s.tolist(), "times": np.asarray(out_long.times).tolist(),
                               "last_record_change": float(abs(s[-1] - s[-2]) / abs(s[-1])), "wall_s": t_long}
        print(f"forward to t={args.steady_t:g}: C_D = {float(cd_long):.6f} (C_D(t={args.t_end:g}) is "
              f"{(float(cd) / float(cd_long) - 1) * 100:+.1f} % from it; last record-to-record change "
              f"{res['steady_check']['last_record_change']:.1e}), {t_long:.0f} s")

    if args.opt_iters > 0:
        res["optimisation"] = optimise(vg, theta0, args, sim)
    res["load_end"] = load()
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(res, indent=2))
    print(f"wrote {args.out}")


def optimise(vg, theta0, args, sim):
    """Minimise C_D(t_end) over alpha at fixed aspect with optax L-BFGS (module docstring)."""
    import optax

    opt = optax.lbfgs(learning_rate=1.0, linesearch=None)
    a = jnp.asarray(math.radians(args.opt_alpha0), F64)
    state = opt.init(a)
    hist = []
    for it in range(args.opt_iters + 1):
        ((cd, out), g), dt = timed(vg, {**theta0, ALPHA: a})
        check(out, sim)
        hist.append({"iteration": it, "alpha_deg": math.degrees(float(a)), "cd": float(cd),
                     "cl": float(out.series["cl"][-1]), "dcd_dalpha": float(g[ALPHA]), "wall_s": dt})
        print(f"  it {it}: alpha = {hist[-1]['alpha_deg']:+.5f} deg, C_D = {float(cd):.7f}, "
              f"C_L = {hist[-1]['cl']:+.5f}, d C_D / d alpha = {float(g[ALPHA]):+.3e} ({dt:.0f} s)")
        if it == args.opt_iters:
            break
        upd, state = opt.update(g[ALPHA], state, a, value=cd, grad=g[ALPHA])
        a = jnp.asarray(optax.apply_updates(a, upd), F64)   # same type: no retrace
    plot(hist, Path(args.out).with_name("shape_sensitivity_opt.png"))
    return hist


def plot(hist, path):
    from mlsph_jax.plotting import subplots

    fig, ax = subplots(1, 2, figsize=(9.0, 3.4))
    it = [h["iteration"] for h in hist]
    ax[0].plot(it, [h["alpha_deg"] for h in hist], "o-")
    ax[0].axhline(0.0, color="0.6", lw=0.8)
    ax[0].set_xlabel("L-BFGS iteration")
    ax[0].set_ylabel("angle of attack [deg]")
    ax[1].plot(it, [h["cd"] for h in hist], "s-")
    ax[1].set_xlabel("L-BFGS iteration")
    ax[1].set_ylabel("C_D(t_end)")
    fig.suptitle("minimise C_D over the angle of attack (ellipse, Re = 40)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
