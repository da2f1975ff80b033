"""Can a fixed-support isotropic stencil follow the Lagrangian §4.5.1 vortex to t = 2?  (issue 14)

The Taylor-Green vortex of ``configs/taylor_green_2d_mlsph.toml`` (2 pi box, 50 x 50, beta = 2,
the MLSPH-ALE cubic-spline kernel: support radius R_i = 2 h_i = 2 beta sqrt(V_i), 4 dx on the lattice) has hyperbolic
stagnation points at (0, 0), (pi, 0), (0, pi), (pi, pi), where Lagrangian particles are stretched
by ~e^t along one axis and compressed by ~e^-t along the other (the flow keeps areas).  This script
measures what that does to the stencils, on two kinds of layouts:

``--exact``    the lattice carried by the *exact* velocity (exact trajectories; volumes dx^2, the
               flow is area-preserving), t = 0, 0.25, ..., 2: the geometry alone, no dynamics;
``--runs DIR`` the snapshots of ``mlsph run`` output directories (fields.h5: x, vol and the MLS
               degrees after fallback, ``area_degree`` / ``fit_degree``).

Per layout, over the fluid particles:

* kernel sum S_i = sum_j V_j W(r_ij, h_i) (self included): minimum and fraction below 0.9 (the
  stencils the solver treats as truncated, where ``scheme.wall_rcond`` raises the pivot threshold);
* largest angular gap between the neighbours inside R_i: maximum and fraction >= 180 degrees (the
  whole stencil in a half plane, as at a wall, but with fluid on the empty side);
* R*_i / R_i, where R*_i is the smallest isotropic radius with a neighbour in each of the eight
  45-degree cones around the axes and diagonals (1.41 dx on the lattice, i.e. 0.35 R): above 1 the
  support has an empty cone; and the number of neighbours an isotropic support of radius R*_i would
  hold (the list width K such a variable-support kernel would need);
* the eigenvalue ratio of the kernel-weighted second moment sum_j W_ij dx_ij dx_ij^T (1 on the
  lattice; large on compressed-and-stretched stencils), its maximum and its value at particle 0;
* R = 4 dx on the lattice, with about 50 neighbours; K* = 8 and R*/R = 0.35 there.

    python experiments/lagrangian_stretch.py [--exact] [--runs DIR ...] [--n 50]

Writes experiments/output/lagrangian_stretch.json.  Not a test.
"""

from __future__ import annotations

import argparse
import json
import math
import os
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from mlsph_jax import config
from mlsph_jax.cases import build_problem
from mlsph_jax.io import read_snapshots
from mlsph_jax.kernels import get_kernel
from mlsph_jax.state import Kind

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "taylor_green_2d_mlsph.toml"
OUT = ROOT / "experiments" / "output" / "lagrangian_stretch.json"
CONES = 8


def stencil_stats(x: np.ndarray, vol: np.ndarray, length: float, beta: float, kernel: str) -> dict:
    """Kernel sums, angular gaps and the isotropic radius R* of every particle of ``x`` (periodic
    square of side ``length``); see the module docstring."""
    ker = get_kernel(kernel)
    h = beta * np.sqrt(vol)
    reach = ker.support * h
    xm = np.mod(x, length)
    tree = cKDTree(xm, boxsize=length)
    n = len(x)
    ksum, gap, rstar, nstar, aniso = (np.empty(n) for _ in range(5))
    half = math.pi / CONES
    axes = np.arange(CONES) * 2.0 * half
    for i in range(n):
        kmax = 64
        while True:       # enough nearest neighbours for every cone (stretched stencils need many)
            dist, idx = tree.query(xm[i], k=min(kmax, n))
            d = xm[idx[1:]] - xm[i]
            d -= length * np.round(d / length)
            ang = np.arctan2(d[:, 1], d[:, 0])
            diff = np.abs((ang[:, None] - axes[None, :] + math.pi) % (2.0 * math.pi) - math.pi)
            inside = diff <= half
            if inside.any(axis=0).all() or kmax >= n:
                break
            kmax *= 4
        r = dist[1:]
        near = np.where(inside, r[:, None], np.inf).min(axis=0)
        rstar[i] = near.max() / reach[i]
        nstar[i] = np.count_nonzero(r <= near.max())
        inr = r < reach[i]
        wj = np.asarray(ker.w(r[inr], h[i], 2))
        ksum[i] = float(vol[i] * ker.w(0.0, h[i], 2)) + float(np.sum(vol[idx[1:]][inr] * wj))
        ev = np.linalg.eigvalsh(np.einsum("k,ka,kb->ab", wj, d[inr], d[inr]))
        aniso[i] = ev[1] / ev[0]
        a = np.sort(ang[inr])
        gap[i] = math.degrees(np.max(np.diff(np.concatenate([a, a[:1] + 2.0 * math.pi])))) if a.size else 360.0
    return {"kernel_sum_min": float(ksum.min()), "kernel_sum_below_0.9": float(np.mean(ksum < 0.9)),
            "gap_max_deg": float(gap.max()), "gap_ge_180_fraction": float(np.mean(gap >= 180.0 - 1e-9)),
            "rstar_over_R_max": float(rstar.max()), "rstar_over_R_p99": float(np.quantile(rstar, 0.99)),
            "empty_cone_fraction": float(np.mean(rstar > 1.0)),
            "moment_ratio_max": float(aniso.max()), "moment_ratio_particle0": float(aniso[0]),
            "neighbours_needed_max": int(nstar.max()), "neighbours_at_R_median": int(np.median(
                [len(tree.query_ball_point(xm[i], reach[i])) - 1
                 for i in range(0, n, max(1, n // 200))]))}


def exact_layouts(n: int, times) -> tuple[dict[float, np.ndarray], float, object]:
    """The n x n lattice carried by the exact Taylor-Green velocity to each of ``times``; the box
    side and the config's scheme."""
    from diagnose_moving_particles import kinematic_layouts

    cfg = config.load(CONFIG, [f"case.n={n}"])
    sch = build_problem(cfg).scheme
    return kinematic_layouts(n, times, None, 0.0, float(sch.beta)), float(cfg["case"]["length"]), sch


def reduced_fraction(degree, nominal) -> float:
    """Fraction of particles below the nominal degree; NaN where the snapshot has no degrees (-1:
    not computed, the initial snapshot of a moving-particle run)."""
    known = degree >= 0
    return float(np.mean(degree[known] < nominal)) if known.any() else float("nan")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=50)
    ap.add_argument("--exact", action="store_true")
    ap.add_argument("--runs", nargs="*", default=[])
    a = ap.parse_args(argv)
    out = {"n": a.n, "load_average": os.getloadavg(), "exact": [], "runs": {}}
    cols = ("t", "kernel_sum_min", "kernel_sum_below_0.9", "gap_max_deg", "gap_ge_180_fraction", "rstar_over_R_max",
            "empty_cone_fraction", "neighbours_needed_max", "moment_ratio_max", "moment_ratio_particle0")
    if a.exact:
        times = [0.25 * k for k in range(9)]
        xs, length, sch = exact_layouts(a.n, times)
        print(f"exact trajectories, {a.n} x {a.n}, beta {sch.beta}, {sch.kernel}:  " + "  ".join(cols[1:]), flush=True)
        for t in times:
            row = {"t": t, **stencil_stats(xs[t], np.full(a.n * a.n, (length / a.n) ** 2), length, sch.beta,
                                      sch.kernel)}
            out["exact"].append(row)
            print("  " + "  ".join(f"{row[c]:.4g}" for c in cols), flush=True)
    for d in a.runs:
        cfg = config.load(Path(d) / "config.toml")
        pb = build_problem(cfg)
        length, beta, kernel = float(cfg["case"]["length"]), float(pb.scheme.beta), pb.scheme.kernel
        rows = []
        print(f"{d}:  " + "  ".join(cols[1:]) + "  area_reduced  fit_reduced", flush=True)
        for t, f in read_snapshots(d):
            fluid = f["kind"] == Kind.FLUID
            row = {"t": t, **stencil_stats(f["x"][fluid], f["vol"][fluid], length, beta, kernel),
                   "area_reduced_fraction": reduced_fraction(f["area_degree"][fluid], pb.scheme.degree),
                   "fit_reduced_fraction": reduced_fraction(f["fit_degree"][fluid], pb.scheme.fit_degree)}
            rows.append(row)
            print("  " + "  ".join(f"{row[c]:.4g}" for c in (*cols, "area_reduced_fraction", "fit_reduced_fraction")),
                  flush=True)
        out["runs"][str(d)] = rows
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
