"""Why moving particles lose accuracy on the §4.5.1 Taylor-Green vortex, and what fixes it (issue 14;
the write-up with every number is docs/moving_particles.md).

Three parts (``--part``, several allowed; JSON per part in experiments/output/):

``layouts``  The operator on the layouts moving particles reach, without time stepping: the 50 x 50
             lattice is carried by the *exact* Taylor-Green velocity (plus, optionally, a shifting
             drift computed from the current layout) to T = 0.5, 1, 1.5, 2; on each layout the exact
             state is put on the particles (Voronoi volumes) and the Eulerian right-hand side is
             compared with the exact time derivative (d rho/dt = 0, d(rho u)/dt = -2 nu rho u).
             This separates "the layout is bad for the operator" from "the dynamics go wrong".
             Rows: area-vector degree (scheme.degree) x reconstruction degree x MLS fallback
             threshold (scheme.rcond) x shift law / coefficient; with the closure defect
             |sum_j A_ij| and the fraction of particles at reduced MLS degree.  (~10 min)
``suspects`` Dynamic runs of configs/taylor_green_2d_mlsph.toml at ``--suspect-n`` (32) to
             ``--suspect-t`` (2), each suspect switched on and off, with time series of the errors
             and of the layout diagnostics (volume against the Voronoi area, total volume, fraction
             at reduced degree, elongation of the Voronoi cells, closure defect).  (~40 min)
``final``    The 50 x 50, t = 2 table: before / after the fix, Lagrangian and ale_shift frames,
             reconstruction degree 2 and 3, and the Eulerian reference.  (~60 min)

    python experiments/diagnose_moving_particles.py [--part layouts suspects final] [--quick]
        [--suspect-n 32] [--suspect-t 2.0] [--final-n 50] [--final-t 2.0] [--only NAME ...]

``--quick`` runs a reduced version of every part (24 x 24, t = 0.5; for checking the script).
"""

from __future__ import annotations

import argparse
import json
import math
import time
import types
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from scipy.integrate import solve_ivp
from scipy.spatial import ConvexHull, Voronoi

from mlsph_jax import approximation as apx
from mlsph_jax import config
from mlsph_jax import neighbors as nb
from mlsph_jax.cases import build_problem
from mlsph_jax.cases.taylor_green_2d import TaylorGreen, error_metrics
from mlsph_jax.eos import get_eos, to_conservative, to_primitive
from mlsph_jax.errors import SimulationError
from mlsph_jax.frames import SHIFT_LAWS
from mlsph_jax.rhs import geometry, rhs
from mlsph_jax.simulation import run_problem

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "taylor_green_2d_mlsph.toml"
OUT = ROOT / "experiments" / "output"

#: The scheme of the §4.5.1 config before the fix (commit 514ec0f: the thesis' literal motion, in
#: which the fluxes use the un-interpolated w_i) and the settings of the fix.
BEFORE = ("scheme.degree=2", "scheme.reconstruction_degree=2", "scheme.shift_coefficient=0.02",
          "scheme.position_update=mls_literal", "scheme.rcond=1e-6")
AFTER = ("scheme.degree=1", "scheme.reconstruction_degree=3", "scheme.shift_coefficient=1.0",
         "scheme.position_update=w_i", "scheme.rcond=1e-2")


# ----------------------------------------------------------------------------------------------
# geometric measures and layout diagnostics
# ----------------------------------------------------------------------------------------------

def voronoi_cells(x: np.ndarray, length: float) -> tuple[np.ndarray, np.ndarray]:
    """Areas of the Voronoi cells of the points ``x[N, 2]`` in the periodic square [0, L)^2 and
    their elongation: largest distance from the point to a vertex of its cell over sqrt(area)
    (0.707 on a square lattice; a lattice stretched s : 1/s gives about s / 2)."""
    n = len(x)
    offs = [(a, b) for a in (-1, 0, 1) for b in (-1, 0, 1)]
    xm = np.mod(x, length)
    pts = np.concatenate([xm + length * np.asarray(o, float) for o in offs])
    vor = Voronoi(pts)
    c = offs.index((0, 0))
    area, elong = np.empty(n), np.empty(n)
    for i in range(n):
        v = vor.vertices[vor.regions[vor.point_region[c * n + i]]]
        area[i] = ConvexHull(v).volume
        elong[i] = np.sqrt(np.max(np.sum((v - xm[i]) ** 2, axis=1)) / area[i])
    return area, elong


def voronoi_areas(x: np.ndarray, length: float) -> np.ndarray:
    """Areas of the Voronoi cells of ``x`` in the periodic square (see :func:`voronoi_cells`)."""
    return voronoi_cells(x, length)[0]


class Probe:
    """Layout diagnostics of a Taylor-Green state (host side; operators jitted once per run)."""

    def __init__(self, problem, cfg):
        self.pb = problem
        self.scheme = problem.scheme
        self.exact = TaylorGreen.from_config(cfg)
        self.length = float(cfg["case"]["length"])
        p = problem.particles
        h = self.scheme.beta * np.sqrt(np.asarray(p.vol))
        self.nspec, _ = nb.allocate(np.asarray(p.x), h, problem.domain, support=self.scheme.support,
                                    headroom=3.0, cell_size=self.scheme.support * float(h.max()) * 1.8)
        self.rows: list[dict] = []
        sch, dom, nspec = self.scheme, problem.domain, self.nspec
        box = (jnp.asarray(dom.length), jnp.asarray(dom.periodic))

        @jax.jit
        def ops(x, vol):
            h = sch.beta * jnp.sqrt(vol)
            nl = nb.update(x, h, nspec)
            g = geometry(x, vol, nl, sch, dom)
            dx = apx.pair_offsets(x, nl.idx, nl.mask, *box)
            area_deg = apx.build_from_offsets(dx, h, vol, nl.idx, nl.mask, sch.area_spec()).degree
            fit_deg = apx.build_from_offsets(dx, h, vol, nl.idx, nl.mask, sch.reconstruction_spec(),
                                             coeffs_only=True).degree
            closure = jnp.sqrt(jnp.sum(jnp.sum(g.A, axis=1) ** 2, axis=-1) / vol)
            return area_deg, fit_deg, closure, nl.overflow

        self._ops = ops

    def __call__(self, p, t, params):
        sch = self.scheme
        m = error_metrics(p, t, params, self.exact, sch.eos)
        x, vol = np.asarray(p.x), np.asarray(p.vol)
        va, elong = voronoi_cells(x, self.length)
        area_deg, fit_deg, closure, overflow = (np.asarray(a) for a in self._ops(p.x, p.vol))
        pe = np.asarray(self.exact.pressure(x, t))
        p0 = float(params["eos.p0"]) if "eos.p0" in params else 0.0
        pg = np.asarray(to_primitive(p.U, get_eos(sch.eos), params).p) - p0
        w = vol / vol.sum()
        dp = (pg - np.sum(w * pg)) - (pe - np.sum(w * pe))
        dv = vol / va - 1.0
        row = {"t": float(t), "ke_rel_error": m["ke_rel_error"], "l2_pressure_error": m["l2_pressure_error"],
               "l2_velocity_error": m["l2_velocity_error"],
               "vol_vs_voronoi_rms": float(np.sqrt(np.mean(dv ** 2))),
               "vol_vs_voronoi_max": float(np.abs(dv).max()),
               "voronoi_std": float(np.std(va) / np.mean(va)),
               "vol_total_drift": float(vol.sum() / self.length ** 2 - 1.0),
               "area_reduced_fraction": float(np.mean(area_deg < sch.degree)),
               "fit_reduced_fraction": float(np.mean(fit_deg < sch.fit_degree)),
               "closure_median": float(np.median(closure)), "closure_max": float(closure.max()),
               "elongation_p99": float(np.quantile(elong, 0.99)), "elongation_max": float(elong.max()),
               "p_error_vs_volume_error_corr": float(np.corrcoef(dp, dv)[0, 1]) if dv.std() > 0 else 0.0,
               "probe_overflow": bool(overflow)}
        self.rows.append(row)
        return {k: float(v) for k, v in row.items()}


# ----------------------------------------------------------------------------------------------
# dynamic runs
# ----------------------------------------------------------------------------------------------

def run_variant(name: str, overrides, n: int, t_end: float, samples: int = 8, probe: bool = True) -> dict:
    """Run the §4.5.1 config with ``overrides`` at n x n to ``t_end``; metrics, time series, wall time."""
    ov = [f"case.n={n}", f"time.t_end={t_end!r}", *overrides, "output.plots=false", "output.progress=false",
          f"output.snapshots={samples}"]
    cfg = config.load(CONFIG, ov)
    pb = build_problem(cfg)
    pr = Probe(pb, cfg) if probe else None
    if pr is not None:
        pb.diagnostics = pr
    t0 = time.perf_counter()
    row = {"name": name, "overrides": list(overrides), "n": n, "t_end": t_end}
    try:
        res = run_problem(pb, cfg, out_dir=None, quiet=True)
        s = res.summary
        row.update(status="ok", metrics=s["metrics"], conservation=s["conservation"], n_steps=s["n_steps"],
                   wall_time_s=s["wall_time_s"], compile_time_s=s["compile_time_s"])
    except SimulationError as e:
        row.update(status=f"failed at t={e.time:.4g}: {e}", metrics={}, conservation={}, n_steps=e.step,
                   wall_time_s=time.perf_counter() - t0, compile_time_s=float("nan"))
    row["total_time_s"] = time.perf_counter() - t0
    if pr is not None:
        row["timeseries"] = pr.rows
    return row


def _fmt(v, spec=".4f"):
    return "   -   " if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, spec)


def print_runs(title: str, rows: list[dict]) -> None:
    print(f"\n{title}")
    print(f"{'variant':<44} {'KE err':>8} {'p L2':>8} {'u L2':>8} {'mass':>9} {'V/vor':>7} {'sumV-1':>9} "
          f"{'red.area':>8} {'red.fit':>7} {'elong':>7} {'steps':>5} {'wall s':>7}  status")
    for r in rows:
        m = r["metrics"]
        ts = (r.get("timeseries") or [{}])[-1]
        print(f"{r['name']:<44} {_fmt(m.get('ke_rel_error'))} {_fmt(m.get('l2_pressure_error'))} "
              f"{_fmt(m.get('l2_velocity_error'))} {_fmt(r['conservation'].get('mass'), '9.1e')} "
              f"{_fmt(ts.get('vol_vs_voronoi_rms'), '7.4f')} {_fmt(ts.get('vol_total_drift'), '9.1e')} "
              f"{_fmt(ts.get('area_reduced_fraction'), '8.3f')} {_fmt(ts.get('fit_reduced_fraction'), '7.3f')} "
              f"{_fmt(ts.get('elongation_max'), '7.1f')} {r['n_steps']:>5} {r['total_time_s']:>7.1f}  "
              f"{r['status'][:60]}", flush=True)


def print_series(rows: list[dict], keys=("ke_rel_error", "l2_pressure_error", "vol_vs_voronoi_rms",
                                         "area_reduced_fraction", "fit_reduced_fraction", "elongation_max")):
    for r in rows:
        print(f"  {r['name']}")
        for s in r.get("timeseries", []):
            print("    t={:.2f} ".format(s["t"]) + " ".join(f"{k}={s[k]:.3g}" for k in keys), flush=True)


def _frame(f):
    return f"scheme.frame={f}"


def suspects(n: int, t_end: float, only=None) -> list[tuple[str, list[str]]]:
    """(name, overrides) of the suspect runs: each switch on and off around the fixed scheme."""
    after = list(AFTER)

    def swap(key, value, base=after):
        return [o for o in base if not o.startswith(key + "=")] + [f"{key}={value}"]

    v = []
    for fr in ("lagrangian", "ale_shift"):
        v.append((f"{fr}: before (shipped, degree 2)", [_frame(fr), *BEFORE]))
        v.append((f"{fr}: before, degree 3", [_frame(fr), *swap("scheme.degree", 3, BEFORE),
                                              "scheme.reconstruction_degree=3"]))
    v.append(("eulerian: degree 3", ["scheme.frame=eulerian", "scheme.degree=3", "scheme.reconstruction_degree=3"]))
    v.append(("eulerian: areas 1, reconstruction 3", ["scheme.frame=eulerian", "scheme.degree=1",
                                                      "scheme.reconstruction_degree=3"]))
    sh = "ale_shift"
    v.append((f"{sh}: fixed", [_frame(sh), *after]))
    # motion / frame-velocity consistency (eq. 4.28 vs the fluxes and eq. 4.32)
    v.append((f"{sh}: fixed, position mls_literal (fluxes use w_i)",
              [_frame(sh), *swap("scheme.position_update", "mls_literal")]))
    v.append((f"{sh}: fixed, position mls (fluxes use the motion)",
              [_frame(sh), *swap("scheme.position_update", "mls")]))
    v.append((f"{sh}: fixed, position shepard (fluxes use the motion)",
              [_frame(sh), *swap("scheme.position_update", "shepard")]))
    # MLS conditioning: area degree and fallback threshold
    v.append((f"{sh}: fixed, areas degree 3", [_frame(sh), *swap("scheme.degree", 3)]))
    v.append((f"{sh}: fixed, areas degree 2", [_frame(sh), *swap("scheme.degree", 2)]))
    v.append((f"{sh}: fixed, rcond 1e-6", [_frame(sh), *swap("scheme.rcond", 1e-6)]))
    # shifting law and coefficient
    for c in (0.02, 0.3, 3.0):
        v.append((f"{sh}: fixed, xu C={c}", [_frame(sh), *swap("scheme.shift_coefficient", c)]))
    for c in (0.5, 2.0):
        v.append((f"{sh}: fixed, fickian C={c}", [_frame(sh), *swap("scheme.shift_coefficient", c),
                                                  "scheme.shift_law=fickian"]))
    # self flux, beta
    v.append((f"{sh}: fixed, self_flux off", [_frame(sh), *after, "scheme.self_flux=false"]))
    v.append((f"{sh}: fixed, beta 1.5", [_frame(sh), *after, "scheme.beta=1.5"]))
    v.append((f"{sh}: fixed, reconstruction degree 2", [_frame(sh), *swap("scheme.reconstruction_degree", 2)]))
    # the Lagrangian frame with the fixed scheme (no drift)
    lg = "lagrangian"
    v.append((f"{lg}: fixed", [_frame(lg), *after]))
    v.append((f"{lg}: fixed, rcond 1e-6", [_frame(lg), *swap("scheme.rcond", 1e-6)]))
    v.append((f"{lg}: fixed, rcond 0.1", [_frame(lg), *swap("scheme.rcond", 0.1)]))
    v.append((f"{lg}: fixed, position mls", [_frame(lg), *swap("scheme.position_update", "mls")]))
    v.append((f"{lg}: fixed, areas degree 3", [_frame(lg), *swap("scheme.degree", 3)]))
    if only:
        v = [x for x in v if any(o in x[0] for o in only)]
    return v


def final_table(n: int, t_end: float, only=None) -> list[tuple[str, list[str]]]:
    v = [("eulerian: degree 2 (shipped)", ["scheme.frame=eulerian", *BEFORE]),
         ("eulerian: degree 3", ["scheme.frame=eulerian", "scheme.degree=3", "scheme.reconstruction_degree=3"]),
         ("eulerian: areas 1, reconstruction 3", ["scheme.frame=eulerian", "scheme.degree=1",
                                                  "scheme.reconstruction_degree=3"])]
    for fr in ("lagrangian", "ale_shift"):
        v.append((f"{fr}: before, degree 2", [_frame(fr), *BEFORE]))
        v.append((f"{fr}: before, degree 3", [_frame(fr), *BEFORE, "scheme.degree=3",
                                              "scheme.reconstruction_degree=3"]))
        v.append((f"{fr}: after, reconstruction 2", [_frame(fr), *AFTER, "scheme.reconstruction_degree=2"]))
        v.append((f"{fr}: after, reconstruction 3", [_frame(fr), *AFTER]))
    if only:
        v = [x for x in v if any(o in x[0] for o in only)]
    return v


# ----------------------------------------------------------------------------------------------
# layouts: the operator on the layouts moving particles reach (no time stepping)
# ----------------------------------------------------------------------------------------------

def kinematic_layouts(n: int, times, law: str | None, coefficient: float, beta: float) -> dict[float, np.ndarray]:
    """Positions of the n x n lattice carried by the exact Taylor-Green velocity plus the drift of
    shift law ``law`` (None: none) times ``coefficient`` (U_max = 1), SSP-RK3 with dt = dx / 4."""
    cfg = config.load(CONFIG, [f"case.n={n}", "scheme.frame=eulerian", f"scheme.beta={beta!r}"])
    pb = build_problem(cfg)
    ex = TaylorGreen.from_config(cfg)
    L = float(cfg["case"]["length"])
    sch = pb.scheme
    x0 = np.asarray(pb.particles.x)
    if law is None:       # exact trajectories (the flow is steady up to its decay factor)
        f = lambda t, y: np.asarray(ex.velocity(y.reshape(-1, 2), 0.0)).ravel()
        sol = solve_ivp(f, (0.0, max(times)), x0.ravel(), rtol=1e-10, atol=1e-12, t_eval=sorted(times))
        return {float(t): np.mod(sol.y[:, k].reshape(-1, 2), L) for k, t in enumerate(sorted(times))}
    vol = jnp.full(len(x0), (L / n) ** 2)
    h = sch.beta * jnp.sqrt(vol)
    nspec, _ = nb.allocate(x0, np.asarray(h), pb.domain, support=sch.support, headroom=2.5,
                           cell_size=sch.support * float(h.max()) * 1.5)
    box = (jnp.asarray(pb.domain.length), jnp.asarray(pb.domain.periodic))
    shift = SHIFT_LAWS.get(law)

    @jax.jit
    def velocity(x):
        nl = nb.update(x, h, nspec)
        dx = apx.pair_offsets(x, nl.idx, nl.mask, *box)
        me = jnp.arange(x.shape[0])[:, None]
        g = types.SimpleNamespace(dx=dx, h=h, pair_mask=nl.mask & (nl.idx != me),
                                  jsafe=jnp.where(nl.mask, nl.idx, me))
        return ex.velocity(x, 0.0) + coefficient * shift.drift(g, sch, vol), nl.overflow

    out, x, t = {0.0: x0}, jnp.asarray(x0), 0.0
    dt = 0.25 * L / n
    for T in sorted(times):
        while t < T - 1e-12:
            d = min(dt, T - t)
            k1, o1 = velocity(x)
            x1 = x + d * k1
            k2, o2 = velocity(x1)
            x2 = 0.75 * x + 0.25 * (x1 + d * k2)
            k3, o3 = velocity(x2)
            x = jnp.mod(x / 3.0 + 2.0 / 3.0 * (x2 + d * k3), L)
            t += d
            if bool(o1 | o2 | o3):
                raise RuntimeError("neighbour overflow in the kinematic layout study")
        out[float(T)] = np.asarray(x)
    return out


def truncation_error(x: np.ndarray, overrides, n: int) -> dict:
    """Eulerian right-hand side of the exact state on the layout ``x`` (Voronoi volumes) minus the
    exact time derivative: rms over particles of d rho/dt and d(rho u)/dt, closure defect, and the
    fraction of particles at reduced area / fit degree."""
    cfg = config.load(CONFIG, [f"case.n={n}", "scheme.frame=eulerian", *overrides])
    pb = build_problem(cfg)
    ex = TaylorGreen.from_config(cfg)
    L = float(cfg["case"]["length"])
    sch = pb.scheme
    va = voronoi_areas(x, L)
    h = sch.beta * np.sqrt(va)
    _, nl = nb.allocate(x, h, pb.domain, support=sch.support, headroom=1.6)
    xj, vj = jnp.asarray(x), jnp.asarray(va)
    g = geometry(xj, vj, nl, sch, pb.domain)
    e = cfg["eos"]
    pe, ue = np.asarray(ex.pressure(x, 0.0)), np.asarray(ex.velocity(x, 0.0))
    rho = e["rho0"] * (1.0 + e["gamma"] * pe / (e["rho0"] * e["c0"] ** 2)) ** (1.0 / e["gamma"])
    U = to_conservative(jnp.asarray(rho), jnp.asarray(ue), None, get_eos(sch.eos), pb.params)
    p = pb.particles.replace(x=xj, vol=vj, q=U * vj[:, None])
    _, _, dq = rhs(p, pb.params, g, sch)
    err = np.asarray(dq) / va[:, None] - np.concatenate([np.zeros((len(x), 1)), -2.0 * ex.nu * rho[:, None] * ue], 1)
    closure = np.linalg.norm(np.asarray(g.A).sum(1), axis=1) / np.sqrt(va)
    box = (jnp.asarray(pb.domain.length), jnp.asarray(pb.domain.periodic))
    dx = apx.pair_offsets(xj, nl.idx, nl.mask, *box)
    hj = jnp.asarray(h)
    area_deg = np.asarray(apx.build_from_offsets(dx, hj, vj, nl.idx, nl.mask, sch.area_spec()).degree)
    fit_deg = np.asarray(apx.build_from_offsets(dx, hj, vj, nl.idx, nl.mask, sch.reconstruction_spec(),
                                                coeffs_only=True).degree)
    return {"drho_rms": float(np.sqrt(np.mean(err[:, 0] ** 2))),
            "dmom_rms": float(np.sqrt(np.mean(err[:, 1:] ** 2))),
            "closure_median": float(np.median(closure)), "closure_max": float(closure.max()),
            "area_reduced_fraction": float(np.mean(area_deg < sch.degree)),
            "fit_reduced_fraction": float(np.mean(fit_deg < sch.fit_degree)),
            "voronoi_std": float(np.std(va) / np.mean(va))}


def layouts_part(n: int, times, quick: bool) -> dict:
    operators = [("areas 3, reconstruction 3", ["scheme.degree=3", "scheme.reconstruction_degree=3"]),
                 ("areas 3, reconstruction 3, rcond 1e-2", ["scheme.degree=3", "scheme.reconstruction_degree=3",
                                                           "scheme.rcond=1e-2"]),
                 ("areas 3, fixed-centre derivative", ["scheme.degree=3", "scheme.reconstruction_degree=3",
                                                       "scheme.derivative=fixed_centre"]),
                 ("areas 2, reconstruction 2", ["scheme.degree=2", "scheme.reconstruction_degree=2"]),
                 ("areas 2, reconstruction 3", ["scheme.degree=2", "scheme.reconstruction_degree=3"]),
                 ("areas 1, reconstruction 3", ["scheme.degree=1", "scheme.reconstruction_degree=3"]),
                 ("areas 1, reconstruction 3, beta 3", ["scheme.degree=1", "scheme.reconstruction_degree=3",
                                                        "scheme.beta=3.0"])]
    motions = [("lagrangian (exact trajectories)", None, 0.0),
               ("xu C=0.02", "xu", 0.02), ("xu C=0.3", "xu", 0.3), ("xu C=1", "xu", 1.0),
               ("fickian C=2", "fickian", 2.0)]
    if quick:
        operators, motions = operators[:1] + operators[-2:-1], motions[:1] + motions[-2:-1]
    out = {}
    print(f"\nlayouts: {n} x {n} lattice moved by the exact velocity (+ drift); truncation error of the "
          "Eulerian RHS of the exact state (lattice: T = 0)")
    print(f"{'motion':<32} {'operator':<40} " + " ".join(f"{'T=' + format(t, 'g'):>17}" for t in [0.0, *times]))
    print(f"{'':<73}" + " ".join(f"{'dmom / closure':>17}" for _ in [0.0, *times]))
    for mname, law, c in motions:
        xs = kinematic_layouts(n, times, law, c, 2.0)
        out[mname] = {}
        for oname, ov in operators:
            rows = {str(T): truncation_error(x, ov, n) for T, x in xs.items()}
            out[mname][oname] = rows
            print(f"{mname:<32} {oname:<40} " + " ".join(
                f"{r['dmom_rms']:>8.2g}/{r['closure_median']:<8.2g}" for r in rows.values()), flush=True)
    return out


def stretch_table(n: int, times) -> list[dict]:
    """Column spacing at a hyperbolic stagnation point for exact Lagrangian trajectories: along
    y = pi, x - pi obeys tan((x - pi)/2) = tan((x0 - pi)/2) e^t (u = sin x cos y, nu -> 0)."""
    L = 2.0 * math.pi
    dx = L / n
    rows = []
    for t in times:
        cols = [2.0 * math.atan(math.tan((k + 0.5) * dx / 2.0) * math.exp(t)) for k in range(3)]
        rows.append({"t": t, "first_columns_over_dx": [c / dx for c in cols],
                     "gap_over_dx": 2.0 * cols[0] / dx})
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", nargs="+", default=["layouts", "suspects", "final"],
                    choices=["layouts", "suspects", "final"])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--suspect-n", type=int, default=32)
    ap.add_argument("--suspect-t", type=float, default=2.0)
    ap.add_argument("--final-n", type=int, default=50)
    ap.add_argument("--final-t", type=float, default=2.0)
    ap.add_argument("--layout-n", type=int, default=50)
    ap.add_argument("--only", nargs="*", default=None, help="run only variants whose name contains one of these")
    args = ap.parse_args(argv)
    if args.quick:
        args.suspect_n = args.final_n = args.layout_n = 24
        args.suspect_t = args.final_t = 0.5
    OUT.mkdir(parents=True, exist_ok=True)
    suffix = "_quick" if args.quick else ""
    if "layouts" in args.part:
        times = [0.5, 1.0] if args.quick else [0.5, 1.0, 1.5, 2.0]
        data = {"n": args.layout_n, "stretch": stretch_table(args.layout_n, [0.5, 0.75, 1.0, 1.25, 1.5, 2.0]),
                "truncation": layouts_part(args.layout_n, times, args.quick)}
        print("\nexact Lagrangian column spacing at a hyperbolic stagnation point (units of dx; support radius "
              "2 beta dx = 4 dx for beta = 2):")
        for r in data["stretch"]:
            print(f"  t={r['t']:<5g} gap between the two central columns {r['gap_over_dx']:6.2f} dx; "
                  f"columns at x - pi = " + ", ".join(f"{c:.2f}" for c in r["first_columns_over_dx"]) + " dx")
        (OUT / f"moving_particles_layouts{suffix}.json").write_text(json.dumps(data, indent=1))
    for part, builder, n, t in (("suspects", suspects, args.suspect_n, args.suspect_t),
                                ("final", final_table, args.final_n, args.final_t)):
        if part not in args.part:
            continue
        variants = builder(n, t, args.only)
        if args.quick:
            variants = variants[:4]
        rows = []
        path = OUT / f"moving_particles_{part}{suffix}.json"
        old = json.loads(path.read_text()) if (args.only and path.is_file()) else {"runs": []}
        for name, ov in variants:
            rows.append(run_variant(name, ov, n, t))
            print_runs(f"{part}: {n} x {n}, t = {t:g} (so far)", rows[-1:])
        keep = [r for r in old["runs"] if r["name"] not in {x["name"] for x in rows}]
        allrows = keep + rows
        path.write_text(json.dumps({"n": n, "t_end": t, "before": BEFORE, "after": AFTER, "runs": allrows}, indent=1))
        print_runs(f"{part}: {n} x {n}, t = {t:g}", allrows)
        print_series(rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
