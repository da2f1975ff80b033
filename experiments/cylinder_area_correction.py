"""Why the area correction (decision 59) destabilises the cylinder's graded polar layout (decision 88).

Builds the cylinder's geometry with ``scheme.area_correction = none`` and with the correction given
by ``--correction`` and prints, per ring of the polar layout (ring 0 at the body; the last rings are
the frozen far field), the size of the correction relative to the areas, |Delta A_ij| / |A_ij|, the
pairs whose A_ij . dx_ij changes sign, and the closure C_i = sum_j A_ij in units of V_i / h_i before
and after.  With the self-flux term (thesis eq. 4.36) the rate of a linearly advected scalar u
(speed a) is V_i du_i/dt = -sum_j (a . A_ij) (u_j - u_i) / 2 - dissipation, so its energy changes by
(1/2) sum_i u_i^2 a . C_i: a closure that is not small is a local source of energy that only the
upwind dissipation can hold.  Also prints the largest real part of the eigenvalues of that
advection operator (central part only, a = (1, 0)), whose positive part is that source.
Writes ``experiments/output/cylinder_area_correction.json``.  Not a test.

Usage::

    python experiments/cylinder_area_correction.py --n-theta 32 --r-far 10 --correction quadratic
"""

from __future__ import annotations

import argparse
import json
import pathlib

import jax
import numpy as np

from mlsph_jax import config
from mlsph_jax.area_correction import complete_rows
from mlsph_jax.cases import build_problem
from mlsph_jax.run import setup_run
from mlsph_jax.state import Kind
from mlsph_jax.testing import CONFIG_DIR

jax.config.update("jax_enable_x64", True)


def _geometry(n_theta: int, r_far: float, correction: str, extra=()):
    cfg = config.load(CONFIG_DIR / "cylinder.toml", [f"case.n_theta={n_theta}", f"case.r_far={r_far!r}",
                                                      f"scheme.area_correction={correction}", *extra])
    pb = build_problem(cfg)
    geom = setup_run(pb).geometry_fn(pb.particles)(pb.particles)
    return pb, geom


def _advection_growth(A, idx, pm, vol, a=(1.0, 0.0)):
    """Largest real part of the eigenvalues of du_i/dt = -sum_j (a . A_ij)(u_j - u_i) / (2 V_i)."""
    n = len(vol)
    aA = np.einsum("nkd,d->nk", A, np.asarray(a)) * pm
    M = np.zeros((n, n))
    rows = np.repeat(np.arange(n), idx.shape[1])
    np.add.at(M, (rows, idx.reshape(-1)), -0.5 * aA.reshape(-1))
    M[np.arange(n), np.arange(n)] += 0.5 * aA.sum(1)
    M /= vol[:, None]
    ev = np.linalg.eigvals(M)
    return float(ev.real.max())


def diagnose(n_theta: int, r_far: float, correction: str, extra=(), eigen: bool = True) -> dict:
    pb, g0 = _geometry(n_theta, r_far, "none", extra)
    _, g1 = _geometry(n_theta, r_far, correction, extra)
    p = pb.particles
    x, vol, kind = np.asarray(p.x), np.asarray(p.vol), np.asarray(p.kind)
    h = np.asarray(g0.h)
    pm = np.asarray(g0.pair_mask)
    A0, A1, dx = np.asarray(g0.A), np.asarray(g1.A), np.asarray(g0.dx)
    overflow = int(np.asarray(g1.overflow))
    dA = np.linalg.norm(A1 - A0, axis=-1)
    nA = np.linalg.norm(A0, axis=-1)
    s0, s1 = np.einsum("nkd,nkd->nk", A0, dx), np.einsum("nkd,nkd->nk", A1, dx)
    flipped = pm & (np.sign(s0) != np.sign(s1))
    unit = vol / h
    C0 = np.linalg.norm(A0.sum(1), axis=-1) / unit
    C1 = np.linalg.norm(A1.sum(1), axis=-1) / unit
    r = np.hypot(x[:, 0], x[:, 1])
    radii = np.unique(np.round(r, 6))
    out = {"n_theta": n_theta, "r_far": r_far, "correction": correction, "extra": list(extra),
           "status_bits": overflow, "rings": []}
    print(f"{correction}: status bits {overflow} (0: CG converged); per ring: max |dA|/|A| over pairs, "
          "sign flips of A.dx, max closure |sum_j A_ij| h/V before -> after")
    # per class of row (decision 92): fluid rows with a wall term, the other (complete) fluid rows,
    # the frozen far field; the graded layout's cloud has no rings, so this is its summary
    pb_rows = np.asarray(complete_rows(p, pb.boundary))
    fluid = kind == Kind.FLUID
    out["classes"] = {}
    for name, m in (("wall rows", fluid & ~pb_rows), ("complete fluid rows", pb_rows), ("frozen", ~fluid)):
        rel = np.where(pm[m], dA[m] / np.maximum(nA[m], 1e-300), 0.0)
        row = {"rows": int(m.sum()), "median_rel_dA": float(np.median(rel[pm[m]])), "max_rel_dA": float(rel.max()),
               "sign_flips": int(flipped[m].sum()), "closure_before_median": float(np.median(C0[m])),
               "closure_before_max": float(C0[m].max()), "closure_after_max": float(C1[m].max())}
        out["classes"][name] = row
        print(f"{name:20s} {row['rows']:5d} rows: |dA|/|A| median {row['median_rel_dA']:.3g} max "
              f"{row['max_rel_dA']:.3g}, flips {row['sign_flips']}, closure median {row['closure_before_median']:.3g} "
              f"max {row['closure_before_max']:.3g} -> max {row['closure_after_max']:.3g}")
    if len(radii) > 200:            # a cloud: no rings to print
        radii = radii[:0]
    for k, rr in enumerate(radii):
        m = np.abs(r - rr) < 1e-5
        rel = np.where(pm[m], dA[m] / np.maximum(nA[m], 1e-300), 0.0)
        kinds = sorted({Kind(int(v)).name for v in kind[m]})
        row = {"ring": k, "r": float(rr), "kind": kinds, "max_rel_dA": float(rel.max()),
               "median_rel_dA": float(np.median(rel[pm[m]])), "sign_flips": int(flipped[m].sum()),
               "closure_before": float(C0[m].max()), "closure_after": float(C1[m].max())}
        out["rings"].append(row)
        print(f"ring {k:2d} r = {rr:7.3f} {'/'.join(kinds):12s} |dA|/|A| max {row['max_rel_dA']:.3g} "
              f"median {row['median_rel_dA']:.3g}  flips {row['sign_flips']:3d}  "
              f"closure {row['closure_before']:.3g} -> {row['closure_after']:.3g}")
    if eigen:
        fluid = kind == Kind.FLUID
        for name, A in (("none", A0), (correction, A1)):
            # frozen rows held fixed: only the fluid block of the operator evolves
            sub = np.where(fluid)[0]
            pos = -np.ones(len(vol), int)
            pos[sub] = np.arange(len(sub))
            idx = np.asarray(g0.jsafe)[sub]
            pmf = pm[sub] & fluid[np.minimum(idx, len(vol) - 1)]
            grow = _advection_growth(A[sub], np.where(pmf, pos[idx], 0), pmf, vol[sub])
            out[f"advection_growth_{name}"] = grow
            print(f"central advection operator, fluid block, a = (1, 0): largest Re(lambda) {grow:.4g} ({name})")
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--correction", default="quadratic", help="the corrected areas' option")
    ap.add_argument("--no-eigen", action="store_true", help="skip the eigenvalues")
    for flag, typ, default in (("--n-theta", int, 32), ("--r-far", float, 10.0)):
        ap.add_argument(flag, type=typ, default=default)
    ap.add_argument("--set", nargs="*", default=[], help="further config overrides")
    args = ap.parse_args(argv)
    path = pathlib.Path(__file__).parent / "output" / "cylinder_area_correction.json"
    path.parent.mkdir(exist_ok=True)
    path.write_text(json.dumps(diagnose(args.n_theta, args.r_far, args.correction, args.set,
                                        eigen=not args.no_eigen), indent=1))

if __name__ == "__main__":
    main()
