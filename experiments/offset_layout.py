"""The ``offset`` layout against the ``cartesian`` cut-out around a body (docs/validation.md, "Bodies
given by points"; decision 105).

Builds both layouts of the ``cylinder`` case for the same body and lattice spacing and prints, for
each, the particle count, the set-up time (layout only), the wall gap (:func:`wall_gap`: distance
from the body's quadrature points to the nearest particle in spacings h, averaged over an eighth
of the body; min / mean / max), the fluid volumes' range in h^2 and the mirror-symmetry defect of
the layout; draws both near the body.  Writes ``experiments/output/offset_layout.json`` and the
figure (``--figure``).  Not a test; the runs on these layouts are ``mlsph run`` commands in
docs/validation.md.

Usage::

    python experiments/offset_layout.py --figure docs/figures/offset_layout_square.png
    python experiments/offset_layout.py --set case.body=spline 'case.body_points=[[...]]' ...
"""

from __future__ import annotations

import argparse
import json
import pathlib
import time

import jax.numpy as jnp
import numpy as np
from scipy.spatial import cKDTree

from mlsph_jax import config
from mlsph_jax.cases.body_layouts import BODY_LAYOUTS, body_polygon, wall_gap
from mlsph_jax.cases.cylinder import _NAMES, _support_radius, body_curve
from mlsph_jax.plotting import subplots
from mlsph_jax.state import Kind
from mlsph_jax.testing import CONFIG_DIR

#: The square of docs/validation.md whose faces lie 1.40 h from the cartesian lattice's rows.
SQUARE = ("case.body=\"polygon\"", "case.body_points=[[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]]",
          "case.n_theta=48", "case.lattice_ratio=1.176", "case.r_far=5.0")


def layout(cfg):
    body = body_curve(cfg)
    P = {k: jnp.asarray(v, jnp.float64) for k, v in body.defaults().items()}
    c = cfg["case"]
    t0 = time.perf_counter()
    lay = BODY_LAYOUTS.get(c["layout"]).build(c, body, P, lambda dx: _support_radius(cfg, dx), _NAMES)
    return lay, body, P, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--set", nargs="*", default=list(SQUARE), help="cylinder config overrides (default: the square)")
    ap.add_argument("--figure", type=pathlib.Path, default=None, help="write the figure here")
    ap.add_argument("--out", type=pathlib.Path, default=pathlib.Path("experiments/output/offset_layout.json"))
    args = ap.parse_args()
    results, drawn = {}, {}
    for name in ("cartesian", "offset"):
        cfg = config.load(CONFIG_DIR / "cylinder.toml", [*args.set, f"case.layout=\"{name}\""])
        lay, body, P, seconds = layout(cfg)
        fluid = lay.kind == int(Kind.FLUID)
        gap = wall_gap(body, P, lay.x[fluid], lay.h)
        mirror, _ = cKDTree(lay.x).query(lay.x * np.array([1.0, -1.0]))
        v = lay.vol[fluid] / lay.h ** 2
        results[name] = {"particles": int(len(lay.x)), "fluid": int(fluid.sum()), "h": lay.h, "setup_s": seconds,
                         "wall_gap_min": float(gap.min()), "wall_gap_mean": float(gap.mean()),
                         "wall_gap_max": float(gap.max()), "volume_min_h2": float(v.min()),
                         "volume_max_h2": float(v.max()), "mirror_defect_h": float(mirror.max() / lay.h)}
        r = results[name]
        print(f"{name:9s}  {r['particles']:6d} particles  h = {lay.h:.5g}  set-up {seconds:5.2f} s  wall gap "
              f"{r['wall_gap_min']:.3f} / {r['wall_gap_mean']:.3f} / {r['wall_gap_max']:.3f} h (min / mean / max)  "
              f"volumes {r['volume_min_h2']:.2f}-{r['volume_max_h2']:.2f} h^2  mirror defect "
              f"{r['mirror_defect_h']:.1e} h")
        drawn[name] = (lay.x[fluid], body_polygon(body, P), lay.h)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"set": args.set, "layouts": results}, indent=2))
    print(f"wrote {args.out}")
    if args.figure is not None:
        fig, axes = subplots(1, 2, figsize=(11, 5.2))
        for ax, (name, (x, poly, h)) in zip(axes, drawn.items(), strict=True):
            reach = float(np.max(np.abs(poly))) + 5.0 * h
            near = np.max(np.abs(x), axis=1) < reach
            ax.fill(*poly.T, color="0.8", edgecolor="k")
            ax.plot(*x[near].T, ".", ms=3)
            r = results[name]
            ax.set_title(f"{name}: wall gap {r['wall_gap_mean']:.2f} h mean, {r['wall_gap_max']:.2f} h max")
            ax.set_aspect("equal")
            ax.set_xlim(-reach, reach)
            ax.set_ylim(-reach, reach)
        fig.tight_layout()
        args.figure.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(args.figure, dpi=110)
        print(f"wrote {args.figure}")


if __name__ == "__main__":
    main()
