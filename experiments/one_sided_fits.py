"""Conditioning of the reconstruction/viscous fits near boundaries (docs/architecture.md decision 77).

For each layout: per fluid particle, the pivot ratio at which its fit would lose the nominal
degree (min over the monomials up to that degree of s_j / M_jj, mls.cholesky_pivots), the
one-sidedness of its stencil |sum_k w_k (x_k - x_i)| / (h_i sum_k w_k) and whether a
boundary-integral wall point has it in its stencil.  Prints, per layout and boundary class, the
counts of particles whose fit survives rcond = 0.01 but not 0.1, and the ranges.

    python experiments/one_sided_fits.py            (a few seconds per layout)
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

from mlsph_jax import config as config_mod  # noqa: E402
from mlsph_jax import neighbors  # noqa: E402
from mlsph_jax.approximation import basis, pair_offsets, smoothing_length  # noqa: E402
from mlsph_jax.cases import build_problem  # noqa: E402
from mlsph_jax.kernels import get_kernel  # noqa: E402
from mlsph_jax.state import Kind  # noqa: E402
from mlsph_jax.testing import CONFIG_DIR  # noqa: E402

LAYOUTS = {
    "cylinder n32 r3": ("cylinder", ["case.n_theta=32", "case.r_far=3.0"]),
    "cylinder n48": ("cylinder", []),
    "cylinder n96 r10": ("cylinder", ["case.n_theta=96", "case.r_far=10"]),
    "cylinder n120 r10": ("cylinder", ["case.n_theta=120", "case.r_far=10"]),
    "ellipse A2 5deg n32 r3": ("cylinder", ['case.body="ellipse"', "case.aspect=2.0", "case.alpha=5.0",
                                            "case.n_theta=32", "case.r_far=3.0"]),
    "cavity n12 ghosts": ("lid_driven_cavity", ["case.n=12"]),
    "cavity n12 BI": ("lid_driven_cavity", ["case.n=12", 'case.walls="boundary_integral"']),
    "cavity n40 BI": ("lid_driven_cavity", ['case.walls="boundary_integral"']),
    "couette ny10 BI cubic": ("couette", ["case.ny=10", "case.nx=8", 'case.walls="boundary_integral"',
                                          "scheme.reconstruction_degree=3"]),
    "poiseuille ny10 ghosts cubic": ("poiseuille", ["case.ny=10", "case.nx=8", "scheme.reconstruction_degree=3"]),
    "sod n60": ("sod_ideal_gas", ["case.n=60"]),
    "riemann_r1 n50": ("riemann_r1_tait", ["case.n=50"]),
    "blast dx8e-3": ("blast_2d", ["case.dx=8e-3"]),
    "taylor_green n12": ("taylor_green_2d", ["case.n=12"]),
    # a disordered interior: the lattice moved by uniform random offsets of up to 0.3 dx per axis
    "taylor_green n24 jitter 0.3": ("taylor_green_2d", ["case.n=24"], 0.3),
}


def fit_diagnostics(problem):
    """``(ratio[N], onesided[N])`` of every particle's fit of degree ``scheme.fit_degree``."""
    sch = problem.scheme
    p = problem.particles
    d = p.dim
    h = smoothing_length(p.vol, sch.beta, d)
    _, nl = neighbors.allocate(p.x, h, problem.domain)
    dom = problem.domain
    box = (jnp.asarray(dom.length), jnp.asarray(dom.periodic)) if dom.any_periodic else (None, None)
    dx = pair_offsets(p.x, nl.idx, nl.mask, *box)
    kern = get_kernel(sch.kernel)
    q = sch.fit_degree
    mdeg = np.asarray(basis.monomial_degrees(q, d))

    def one(dxi, mk, hi):
        w = kern.w_vec(dxi, hi) * mk
        P = basis.evaluate(dxi / hi, q)
        M = jnp.einsum("k,ka,kb->ab", w, P, P)
        # pivot ratios s_j / M_jj of the unguarded factor (mls.cholesky_pivots with rcond 0)
        m = M.shape[0]
        L = jnp.zeros_like(M)
        ratios = []
        for j in range(m):
            s = M[j, j] - jnp.dot(L[j, :j], L[j, :j])
            ratios.append(s / M[j, j])
            ljj = jnp.sqrt(jnp.maximum(s, 1e-300))
            col = (M[j + 1:, j] - L[j + 1:, :j] @ L[j, :j]) / ljj
            L = L.at[j, j].set(ljj).at[j + 1:, j].set(col)
        r = jnp.stack(ratios)
        first = jnp.linalg.norm(jnp.einsum("k,ka->a", w, dxi / hi)) / jnp.sum(w)
        return r, first

    r, first = jax.jit(jax.vmap(one))(dx, nl.mask, h)
    jsafe = jnp.where(nl.mask, nl.idx, 0)
    fill = np.asarray(jnp.sum(kern.w_vec(dx, h[:, None]) * nl.mask * p.vol[jsafe], axis=1))
    r = np.asarray(r)
    top = r.min(axis=1)                                           # the nominal degree survives rcond < top
    lower = r[:, mdeg < q].min(axis=1) if q > 1 else np.ones(len(r))
    return top, lower, np.asarray(first), fill


def wall_rows(problem):
    """Boolean[N]: the particle is in the stencil of a boundary-integral wall point."""
    b = problem.boundary
    b = getattr(b, "walls", b)
    n = problem.particles.n
    if b is None or not hasattr(b, "stencils"):
        for attr in ("inner", "boundary", "first"):
            if hasattr(problem.boundary, attr):
                b = getattr(problem.boundary, attr)
    if b is None or not hasattr(b, "stencils"):
        return np.zeros(n, bool)
    st = b.stencils(problem.particles, b.points(problem.params).x)
    out = np.zeros(n, bool)
    out[np.asarray(st.idx)[np.asarray(st.mask)]] = True
    return out


def main(names):
    rows = {}
    for name in names or LAYOUTS:
        cfg_name, sets, *jitter = LAYOUTS[name]
        cfg = config_mod.load(CONFIG_DIR / f"{cfg_name}.toml", [*sets, "output.plots=false"])
        pb = build_problem(cfg)
        if jitter:
            p = pb.particles
            dxl = float(np.min(np.asarray(p.vol))) ** (1.0 / p.dim)
            shift = np.random.default_rng(0).uniform(-jitter[0], jitter[0], p.x.shape) * dxl
            pb = dataclasses.replace(pb, particles=p.replace(x=p.x + shift))
        fluid = np.asarray(pb.particles.kind) == Kind.FLUID
        top, lower, first, fill = fit_diagnostics(pb)
        wall = wall_rows(pb)
        res = {"fit_degree": pb.scheme.fit_degree, "fluid": int(fluid.sum()), "wall_rows": int((wall & fluid).sum())}
        for cls, sel in (("wall", wall & fluid), ("other", ~wall & fluid)):
            if not sel.any():
                continue
            t = top[sel]
            res[cls] = {"n": int(sel.sum()), "ratio_min": float(t.min()), "ratio_median": float(np.median(t)),
                        "below_0.01": int((t < 0.01).sum()), "0.01_to_0.1": int(((t >= 0.01) & (t < 0.1)).sum()),
                        "lower_levels_below_0.1": int((lower[sel] < 0.1).sum()),
                        "onesided_max": float(first[sel].max()), "onesided_median": float(np.median(first[sel])),
                        "fill_min": float(fill[sel].min()), "fill_max": float(fill[sel].max())}
            band = sel & (top >= 0.01) & (top < 0.1)
            if band.any():
                res[cls]["onesided_of_0.01_to_0.1"] = [float(first[band].min()), float(first[band].max())]
                res[cls]["fill_of_0.01_to_0.1"] = [float(fill[band].min()), float(fill[band].max())]
            ok = sel & (top >= 0.1)
            if ok.any():
                res[cls]["onesided_max_of_ratio_ge_0.1"] = float(first[ok].max())
        rows[name] = res
        print(name, json.dumps(res), flush=True)
    out = Path("experiments/output")
    out.mkdir(parents=True, exist_ok=True)
    (out / "one_sided_fits.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main(sys.argv[1:])
