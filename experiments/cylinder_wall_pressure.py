"""The parts of the cylinder's front (and base) pressure coefficient on a finished run.

For the final state of ``mlsph run configs/cylinder.toml --out OUT`` (its ``checkpoint.h5`` and
``config.toml``) prints, at the body's quadrature points nearest to theta = pi (front) and 0 (base):
C_p of the nearest first-ring particle, of the MLS interpolation of the particles' pressure at the
wall (linear and quadratic, the case's own wall stencils) and of the wall pressure p* of the
scheme (``BoundaryIntegralWalls.wall_state``: the linear wall state plus the acoustic term of the
mirror Riemann problem, decisions 54, 71 and 108), with the scheme's wall-normal velocity vn_b
(into the wall; on no-slip walls the fit of decision 108), the linear wall state's, and the
acoustic term rho_b vn_b (vn_b + |vn_b| + c_b) of p* in C_p units.  For viscous runs also the
pressure drop from the front wall point to its first-ring particle against Hiemenz's
stagnation-point flow with the run's own strain rate (:func:`hiemenz_check`).
docs/validation.md "The front stagnation pressure".

Also the pressure drag's parts: C_D,p from the scheme's wall pressure p* (the summary's
``cd_pressure``), from the interpolated p_b alone (p* without its acoustic term), and the acoustic
term's share at the quadrature points within ``CORNER_REACH`` D of a polygon body's vertices
(docs/validation.md "Bodies given by points", corners), with the wall-normal velocity vn_b at
those points from the scheme's stencil, from the stencil cut to the half-space in front of the
point and from the stencil cut to its face's strip (evaluation only), and the wall-normal
velocities of the nearest stencil particles.

    python experiments/cylinder_wall_pressure.py OUT [OUT ...]

``--potential-flow N [N ...]`` instead: the exact potential flow past the circle set into the
particles of ``configs/cylinder.toml`` at n_theta = N (r_far = 10 D), and the wall-normal velocity
vn_b / U that the wall state extrapolates at the front point (exact: 0) with the linear MLS of the
scheme, the quadratic and cubic MLS, and the linear MLS corrected by the flow's exact Hessians at
the stencil particles, vn_b = sum_k N_k (u_k - (x_k - x_b)^T H_k (x_k - x_b) / 2) . n_b, and the
scheme's own vn_b on the body of an inviscid run (``case.inviscid``: the quadratic MLS of decision
109) (docs/validation.md "Euler flow past the circle"; evaluation only).

    python experiments/cylinder_wall_pressure.py --potential-flow 48 96

``--hiemenz N [N ...]``: the same with Hiemenz's viscous stagnation-point flow (no penetration,
u_n = O(y^2) at the body) and the scheme's vn_b on the no-slip body (decision 108) beside the
linear wall state's (docs/validation.md "The no-slip wall's normal velocity").

    python experiments/cylinder_wall_pressure.py --hiemenz 48 96
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import math
from pathlib import Path

import jax.numpy as jnp
import numpy as np
from scipy.integrate import solve_bvp

from mlsph_jax import config
from mlsph_jax.approximation import mls
from mlsph_jax.cases import build_problem
from mlsph_jax.cases.cylinder import RHO_INF, U_INF, body_cf, free_stream
from mlsph_jax.checkpoint import read_checkpoint
from mlsph_jax.eos import get_eos, to_primitive
from mlsph_jax.kernels import get_kernel

ROOT = Path(__file__).resolve().parents[1]
#: Quadrature points closer than this (in D) to a polygon body's vertex count as "next to a corner".
CORNER_REACH = 0.1
#: How many of the nearest stencil particles to list for each point next to a corner.
CORNER_NEAREST = 4


def _in_face_strip(vertices, xb, xj):
    """``[Nb, K]``: the particles ``xj[b, k]`` whose projection on the polygon edge nearest to the
    wall point ``xb[b]`` lies within that edge (no particle beyond the edge's ends)."""
    a, e = vertices, np.roll(vertices, -1, axis=0) - vertices            # edges a + s e, s in [0, 1]
    s_b = np.clip(np.einsum("bed,ed->be", xb[:, None] - a[None], e) / np.sum(e * e, axis=1), 0.0, 1.0)
    edge = np.argmin(np.linalg.norm(xb[:, None] - (a[None] + s_b[..., None] * e[None]), axis=-1), axis=1)
    a_b, e_b = a[edge], e[edge]
    s = np.einsum("bkd,bd->bk", xj - a_b[:, None], e_b) / np.sum(e_b * e_b, axis=1)[:, None]
    return (s >= -1e-9) & (s <= 1.0 + 1e-9)


def wall_pressure_parts(out: str | Path) -> dict:
    """C_p parts at the front and base quadrature points of the final state in ``out``."""
    cfg = config.load(Path(out) / "config.toml", [])
    pb = build_problem(cfg)
    p = read_checkpoint(out).particles
    P, sc, walls = pb.params, pb.scheme, pb.boundary
    prim = to_primitive(p.U, get_eos(sc.eos), P)
    bp = walls.points(P)
    st = walls.stencils(p, bp.x)
    p_inf = float(free_stream(cfg, np.zeros((1, 2)), P)[2][0])
    q_inf = 0.5 * RHO_INF * U_INF ** 2
    cp = lambda v: (float(v) - p_inf) / q_inf  # noqa: E731
    xb = np.asarray(bp.x)
    theta = np.mod(np.arctan2(xb[:, 1], xb[:, 0]), 2.0 * math.pi)
    interp = {}
    for deg in (1, 2):
        vals, _, _, _ = mls.operators_block(st.dx, st.mask, st.h, kernel=get_kernel(walls.kernel), degree=deg,
                                            rcond=sc.rcond, derivative="fixed_centre", with_coeffs=False)
        interp[deg] = np.asarray(jnp.einsum("bk,bk->b", vals, prim.p[st.idx]))
    # the scheme's own wall state (its stencils and linear weights): p*, the interpolated p_b and
    # the wall-normal velocity into the wall (the scheme's, decision 108 on no-slip walls, and the
    # linear wall state's)
    bp_w, st_w, vals_w, pstar, tn, _ = walls.wall_state(p, P, sc, prim)
    pstar = np.asarray(pstar)
    p_w = np.asarray(jnp.einsum("bk,bk->b", vals_w, prim.p[st_w.idx]))
    vel_w = np.asarray(jnp.einsum("bk,bkd->bd", vals_w, prim.vel[st_w.idx]))
    vn_linear = np.sum((vel_w - np.asarray(bp.velocity)) * np.asarray(bp.normal), axis=1)
    vn = np.asarray(walls.normal_velocity(sc, bp_w, st_w, vals_w, prim.vel))
    x = np.asarray(p.x)
    fluid = np.asarray(p.kind) == 0
    D = 2.0 * cfg["case"]["radius"]
    # drag along the stream: geometry.body.alpha turns it (ellipses and bodies given by points)
    alpha = float(P["geometry.body.alpha"]) if "geometry.body.alpha" in P else 0.0
    n_drag = np.asarray(bp.normal) @ np.array([math.cos(alpha), math.sin(alpha)])
    dg = np.asarray(bp.dgamma)
    cdp = lambda pw: float(np.sum((pw - p_inf) * n_drag * dg) / (q_inf * D))  # noqa: E731
    out_ = {"cd_pressure": {"scheme_wall": cdp(pstar), "interpolated_wall": cdp(p_w)}}
    if "geometry.body.vertices" in P:          # a polygon body: the points next to its corners
        v = np.asarray(P["geometry.body.vertices"])
        corner = np.min(np.linalg.norm(xb[:, None] - v[None], axis=-1), axis=1) < CORNER_REACH * D
        out_["cd_pressure"]["acoustic_next_to_corners"] = cdp(np.where(corner, pstar, p_w)) - cdp(p_w)
        out_["cd_pressure"]["acoustic_elsewhere"] = cdp(np.where(corner, p_w, pstar)) - cdp(p_w)
        out_["cd_pressure"]["points_next_to_corners"] = int(corner.sum())
        # the wall-normal velocity on the stencil cut to the half-space in front of each wall point
        # (n_b points into the body, so the fluid side has -n_b . (x_j - x_b) > 0; evaluation only)
        ahead = np.einsum("bkd,bd->bk", np.asarray(st_w.dx), -np.asarray(bp.normal)) > \
            -1e-9 * np.asarray(st_w.h)[:, None]
        def vn_on(keep):   # vn_b of the linear wall state on the stencil slots ``keep``
            vals_k, _, _, _ = mls.operators_block(st_w.dx, st_w.mask & jnp.asarray(keep), st_w.h,
                                                  kernel=get_kernel(walls.kernel), degree=1, rcond=sc.rcond,
                                                  derivative="fixed_centre", with_coeffs=False)
            vel_k = np.asarray(jnp.einsum("bk,bkd->bd", vals_k, prim.vel[st_w.idx]))
            return np.sum((vel_k - np.asarray(bp.velocity)) * np.asarray(bp.normal), axis=1)

        vn_h = vn_on(ahead)
        # ... and to the face's strip: in front of the point's own face and no further along it than
        # the face reaches (no particle round the corner; evaluation only)
        strip = np.asarray(ahead) & _in_face_strip(v, xb, np.asarray(p.x)[np.asarray(st_w.idx)])
        vn_s = vn_on(strip)
        # the wall-normal velocities of the stencil's particles themselves (the spread a linear fit
        # must reconcile over one spacing round the corner)
        vn_j = np.einsum("bkd,bd->bk", np.asarray(prim.vel)[np.asarray(st_w.idx)] - np.asarray(bp.velocity)[:, None],
                         np.asarray(bp.normal))
        dist = np.where(np.asarray(st_w.mask), np.linalg.norm(np.asarray(st_w.dx), axis=-1), np.inf)
        nearest = np.argsort(dist, axis=1)[:, :CORNER_NEAREST]
        out_["corner_points"] = [
            {"theta_deg": math.degrees(theta[b]), "x": xb[b].tolist(), "cp_interpolated": cp(p_w[b]),
             "cp_scheme": cp(pstar[b]), "acoustic_term": (float(pstar[b]) - p_w[b]) / q_inf,
             "wall_normal_velocity": float(vn[b]), "linear_wall_normal_velocity": float(vn_linear[b]),
             "half_space_wall_normal_velocity": float(vn_h[b]),
             "face_strip_wall_normal_velocity": float(vn_s[b]),
             "face_strip_particles": int((strip[b] & np.asarray(st_w.mask)[b]).sum()),
             "nearest_particles_vn": vn_j[b, nearest[b]].tolist(),
             "nearest_particles_distance": dist[b, nearest[b]].tolist()}
            for b in np.flatnonzero(corner)[np.argsort(theta[corner])]]
    for name, th0 in (("front", math.pi), ("base", 0.0)):
        b = int(np.argmin(np.abs(np.angle(np.exp(1j * (theta - th0))))))
        near = np.where(fluid)[0][np.argmin(np.sum((x[fluid] - xb[b]) ** 2, axis=1))]
        out_[name] = {"theta_deg": math.degrees(theta[b]), "first_ring_particle": cp(prim.p[near]),
                      "linear_wall": cp(interp[1][b]), "quadratic_wall": cp(interp[2][b]), "scheme_wall": cp(pstar[b]),
                      "wall_normal_velocity": float(vn[b]), "linear_wall_normal_velocity": float(vn_linear[b]),
                      "acoustic_term": (float(pstar[b]) - p_w[b]) / q_inf}
        if name == "front" and sc.viscous:
            out_[name]["hiemenz"] = hiemenz_check(cfg, P, walls, bp_w, tn, q_inf, float(x[near] @ x[near]) ** 0.5
                                                  - cfg["case"]["radius"])
            out_[name]["hiemenz"]["scheme_wall_minus_particle"] = cp(pstar[b]) - cp(prim.p[near])
    return out_


@functools.cache
def _hiemenz_solution():
    e = np.linspace(0.0, 8.0, 400)
    return solve_bvp(lambda _, y: np.vstack([y[1], y[2], -y[0] * y[2] - 1.0 + y[1] ** 2]),
                     lambda a, b: np.array([a[0], a[1], b[1] - 1.0]), e,
                     np.vstack([e, np.tanh(e), 1.0 / np.cosh(e) ** 2]), tol=1e-8).sol


def hiemenz_f(eta):
    """``(f''(0), f(eta), f'(eta))`` of Hiemenz's planar stagnation-point flow, f''' + f f'' + 1 -
    f'^2 = 0, f(0) = f'(0) = 0, f'(inf) = 1 (scipy's boundary-value solver on 0 <= eta <= 8, solved
    once); ``eta`` a number or an array."""
    sol = _hiemenz_solution()
    return float(sol(0.0)[2]), sol(eta)[0], sol(eta)[1]


def hiemenz_check(cfg, P, walls, bp, tn, q_inf: float, y1: float) -> dict:
    """The pressure drop from the wall to the first-ring particle at the front stagnation point that
    Hiemenz's flow predicts, p_w - p(y1) = rho a nu (f'(eta1) + f(eta1)^2 / 2), eta1 = y1 (a / nu)^(1/2)
    (planar, so an estimate on the curved body), with the strain rate a taken from the run's own
    skin-friction slope at the front, dC_f / ds = f''(0) mu a^(3/2) nu^(-1/2) / q_inf (least
    squares over the quadrature points within 0.3 R of arc length from the front)."""
    R = cfg["case"]["radius"]
    mu = float(P["physics.mu"])
    nu = mu / RHO_INF
    phi, _, cf = body_cf(walls, bp.x, bp.normal, bp.curve, tn, (0.0, 0.0), (U_INF, 0.0), q_inf)
    s = (math.pi - np.asarray(phi)) * R
    near = s < 0.3 * R
    slope = float(np.polyfit(s[near], np.asarray(cf)[near], 1)[0])
    fpp0 = hiemenz_f(0.0)[0]
    a = (slope * q_inf * math.sqrt(nu) / (fpp0 * mu)) ** (2.0 / 3.0)
    eta1 = y1 * math.sqrt(a / nu)
    _, f1, fp1 = hiemenz_f(eta1)
    return {"strain_rate": a, "first_ring_distance": y1, "eta1": eta1,
            "predicted_wall_minus_particle": RHO_INF * a * nu * (fp1 + 0.5 * f1 ** 2) / q_inf}


def potential_flow_velocity(x: np.ndarray, radius: float) -> np.ndarray:
    """``[..., 2]``: the potential flow past the circle of ``radius`` at ``x[..., 2]`` (U_inf = 1)."""
    r, th = np.hypot(x[..., 0], x[..., 1]), np.arctan2(x[..., 1], x[..., 0])
    ur, ut = (1.0 - radius ** 2 / r ** 2) * np.cos(th), -(1.0 + radius ** 2 / r ** 2) * np.sin(th)
    return np.stack([ur * np.cos(th) - ut * np.sin(th), ur * np.sin(th) + ut * np.cos(th)], axis=-1)


def potential_flow_wall_velocity(n_theta: int) -> dict:
    """vn_b / U at the front quadrature point of the exact potential flow (module docstring)."""
    cfg = config.load(ROOT / "configs" / "cylinder.toml", [f"case.n_theta={n_theta}", "case.r_far=10.0"])
    pb = build_problem(cfg)
    R, walls, x = cfg["case"]["radius"], pb.boundary, np.asarray(pb.particles.x)
    vel = potential_flow_velocity(x, R)
    bp = walls.points(pb.params)
    st = walls.point_stencils(pb.particles, bp.x)
    xb, normal = np.asarray(bp.x), np.asarray(bp.normal)
    front = int(np.argmin(np.abs(np.angle(np.exp(1j * (np.arctan2(xb[:, 1], xb[:, 0]) - math.pi))))))
    idx, dx = np.asarray(st.idx)[front], np.asarray(st.dx)[front]
    out = {"n_theta": n_theta, "theta_deg": math.degrees(math.atan2(xb[front, 1], xb[front, 0]) % (2 * math.pi))}
    for deg in (1, 2, 3):
        vals, _, _, _ = mls.operators_block(st.dx, st.mask, st.h, kernel=get_kernel(walls.kernel), degree=deg,
                                            rcond=1e-6, derivative="fixed_centre", with_coeffs=False)
        out[f"degree_{deg}"] = float(np.asarray(vals)[front] @ vel[idx] @ normal[front])
        if deg == 1:
            eps, xk, H = 1e-4, x[idx], np.zeros((len(idx), 2, 2, 2))     # H[k, component, a, b]
            for a in range(2):
                for b in range(2):
                    ea, eb = np.eye(2)[a] * eps, np.eye(2)[b] * eps
                    H[:, :, a, b] = (potential_flow_velocity(xk + ea + eb, R) - potential_flow_velocity(xk + ea - eb, R)
                                     - potential_flow_velocity(xk - ea + eb, R)
                                     + potential_flow_velocity(xk - ea - eb, R)) / (4 * eps * eps)
            corrected = vel[idx] - 0.5 * np.einsum("kd,kcde,ke->kc", dx, H, dx)
            out["degree_1_exact_hessians"] = float(np.asarray(vals)[front] @ corrected @ normal[front])
    # the scheme's own vn_b on the same body in an inviscid run (`case.inviscid`, a wall without
    # friction: the quadratic MLS of decision 109)
    inviscid = dataclasses.replace(pb.scheme, viscous=False)
    bp_e, st_e, vals_e = walls.state_weights(pb.particles, pb.params, inviscid)
    vn_e = walls.normal_velocity(inviscid, bp_e, st_e, vals_e, jnp.asarray(vel))
    out["scheme_inviscid"] = float(np.asarray(vn_e)[front])
    return out


def hiemenz_wall_velocity(n_theta: int, strain: float = 2.9) -> dict:
    """vn_b / U at the front quadrature point of Hiemenz's stagnation-point flow set into the
    particles of ``configs/cylinder.toml`` at n_theta = N (r_far = 10 D, nu = D U / 40): u_r =
    -(a nu)^(1/2) f(eta), u_theta = a R phi f'(eta), eta = (r - R) (a / nu)^(1/2), phi the angle
    from the front, a = ``strain`` (2.9 U / D, the runs' own, ``hiemenz_check``).  No penetration
    (exact: vn_b = 0): the scheme's vn_b (decision 108's fit on the no-slip body) and the linear
    wall state's are the closures' truncation on a boundary layer the stencil only partly resolves;
    also how far the stencil reaches into it (eta)."""
    cfg = config.load(ROOT / "configs" / "cylinder.toml", [f"case.n_theta={n_theta}", "case.r_far=10.0"])
    pb = build_problem(cfg)
    R, walls, p = cfg["case"]["radius"], pb.boundary, pb.particles
    nu = float(pb.params["physics.mu"]) / RHO_INF
    x = np.asarray(p.x)
    r, th = np.hypot(x[:, 0], x[:, 1]), np.arctan2(x[:, 1], x[:, 0])
    phi = np.angle(np.exp(1j * (th - math.pi)))
    eta = np.minimum(np.maximum(r - R, 0.0) / math.sqrt(nu / strain), 8.0)
    _, f, fp = hiemenz_f(eta)
    ur, ut = -math.sqrt(strain * nu) * f, strain * R * phi * fp
    vel = jnp.asarray(np.stack([ur * np.cos(th) - ut * np.sin(th), ur * np.sin(th) + ut * np.cos(th)], 1))
    bp, st, vals = walls.state_weights(p, pb.params, pb.scheme)
    vn = np.asarray(walls.normal_velocity(pb.scheme, bp, st, vals, vel))
    xb, normal = np.asarray(bp.x), np.asarray(bp.normal)
    front = int(np.argmin(np.abs(np.angle(np.exp(1j * (np.arctan2(xb[:, 1], xb[:, 0]) - math.pi))))))
    vj = np.asarray(vel)[np.asarray(st.idx)[front]] @ normal[front]
    reach = float(np.max(np.where(np.asarray(st.mask)[front], -np.asarray(st.dx)[front] @ normal[front], 0.0)))
    return {"n_theta": n_theta, "scheme": float(vn[front]), "linear": float(np.asarray(vals)[front] @ vj),
            "stencil_reach_eta": reach / math.sqrt(nu / strain)}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="*", help="output directories of finished cylinder runs")
    ap.add_argument("--potential-flow", type=int, nargs="+", metavar="N_THETA",
                    help="the exact potential flow's wall-normal velocity at the front point instead")
    ap.add_argument("--hiemenz", type=int, nargs="+", metavar="N_THETA",
                    help="Hiemenz's stagnation-point flow's wall-normal velocity at the front point instead")
    args = ap.parse_args()
    # the exact flows set into the particles: (n_theta list, evaluation, line printed)
    exact = [(args.hiemenz, hiemenz_wall_velocity, lambda n, v: (
                 f"n_theta {n}, Hiemenz flow (a = 2.9 U/D): front vn_b / U of the scheme {v['scheme']:+.2e}, of "
                 f"the linear wall state {v['linear']:+.2e} (exact 0; the stencil reaches eta "
                 f"{v['stencil_reach_eta']:.2f})")),
             (args.potential_flow, potential_flow_wall_velocity, lambda n, v: (
                 f"n_theta {n}, front point {v['theta_deg']:.2f} deg: vn_b / U linear {v['degree_1']:+.4f} "
                 f"(C_p of rho c vn_b at M = 0.1: {20.0 * v['degree_1']:+.3f}), quadratic {v['degree_2']:+.4f}, "
                 f"cubic {v['degree_3']:+.4f}, linear with the exact Hessians {v['degree_1_exact_hessians']:+.4f}; "
                 f"the scheme's on an inviscid run (decision 109) {v['scheme_inviscid']:+.4f}"))]
    for sizes, evaluate, line in exact:
        for n in sizes or ():
            print(line(n, evaluate(n)))
    if args.hiemenz or args.potential_flow:
        return
    if not args.runs:
        ap.error("give output directories of finished cylinder runs, or --potential-flow / --hiemenz N_THETA")
    res = {}
    for out in args.runs:
        res[str(out)] = parts = wall_pressure_parts(out)
        print(f"{out} C_D,p: " + ", ".join(f"{k} {v:.4f}" if isinstance(v, float) else f"{k} {v}"
                                           for k, v in parts["cd_pressure"].items()))
        for c in parts.get("corner_points", []):
            print(f"{out} next to a corner: theta {c['theta_deg']:7.2f}  p_b {c['cp_interpolated']:+.3f}  "
                  f"p* {c['cp_scheme']:+.3f}  (acoustic {c['acoustic_term']:+.3f}, vn_b "
                  f"{c['wall_normal_velocity']:+.4f}; linear state {c['linear_wall_normal_velocity']:+.4f}, on the "
                  f"half-space {c['half_space_wall_normal_velocity']:+.4f}, on the face "
                  f"strip {c['face_strip_wall_normal_velocity']:+.4f} from {c['face_strip_particles']} particles; "
                  "nearest particles' vn " + " ".join(f"{u:+.3f}" for u in c["nearest_particles_vn"]) +
                  " at " + " ".join(f"{r:.3f}" for r in c["nearest_particles_distance"]) + ")")
        for name, v in parts.items():
            if name in ("cd_pressure", "corner_points"):
                continue
            print(f"{out} {name:5s} theta {v['theta_deg']:7.2f}  particle {v['first_ring_particle']:.4f}  "
                  f"linear {v['linear_wall']:.4f}  quadratic {v['quadratic_wall']:.4f}  "
                  f"scheme p* {v['scheme_wall']:.4f}  (vn_b {v['wall_normal_velocity']:+.2e}: "
                  f"acoustic term {v['acoustic_term']:+.4f}; linear wall state's vn_b "
                  f"{v['linear_wall_normal_velocity']:+.2e})")
            if "hiemenz" in v:
                hz = v["hiemenz"]
                print(f"{out} front wall - first-ring particle {hz['scheme_wall_minus_particle']:+.4f}, Hiemenz "
                      f"{hz['predicted_wall_minus_particle']:+.4f} (strain a {hz['strain_rate']:.3f} U/D from the "
                      f"skin friction, particle at {hz['first_ring_distance']:.4f} D, eta {hz['eta1']:.3f})")
    dest = ROOT / "experiments" / "output" / "cylinder_wall_pressure.json"
    dest.parent.mkdir(parents=True, exist_ok=True)
    dest.write_text(json.dumps(res, indent=2))
    print(f"wrote {dest}")


if __name__ == "__main__":
    main()
