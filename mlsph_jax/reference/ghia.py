"""Ghia, Ghia & Shin (1982) lid-driven cavity centre-line velocities (Re = 100, 400, 1000).

U. Ghia, K. N. Ghia, C. T. Shin, "High-Re solutions for incompressible flow using the
Navier-Stokes equations and a multigrid method", J. Comput. Phys. 48(3):387-411 (1982),
Table I (u/U_lid along the vertical centre line x = 0.5) and Table II (v/U_lid along the
horizontal centre line y = 0.5), 17 points each, walls included.

Provenance: ``data/ghia1982_centerlines.csv`` holds the numbers of the project's reference set
(``/work/shared/reference/ghia1982_{u_vertical,v_horizontal}_centerline.csv``, README §1) with
every value's text unchanged, the two tables stacked (column ``line`` = ``u`` or ``v``).  Those
were taken from pypr/pysph ``pysph/examples/ghia_cavity_data.py`` (commit c9de9e94) and
cross-checked point by point against four other public copies (PetIBM, jax-sph, deal.II
step-57, and a circulating table); the copies disagree only at v(Re=400, x=0.5) (0.05186 used)
and v(Re=1000, x=0.9063) (-0.51550 used).

Flagged misprint (:data:`MISPRINTS`): v(Re=400, x=0.9063) = -0.23827, kept as published but
inconsistent with its neighbours (-0.44993 at x=0.8594, -0.22847 at x=0.9453); SPEC Appendix
A and the reference README recommend leaving it out of error norms, which
:func:`centerline` does unless ``include_misprint=True``.
"""

from __future__ import annotations

import csv
import functools
from pathlib import Path

import numpy as np

from ..errors import InputError

DATA_FILE = Path(__file__).resolve().parent / "data" / "ghia1982_centerlines.csv"

#: Reynolds numbers tabulated here.
REYNOLDS = (100, 400, 1000)

#: (component, Re, coordinate) of published values known to be misprinted.
MISPRINTS = frozenset({("v", 400, 0.9063)})


@functools.cache
def _table() -> dict[str, tuple[np.ndarray, dict[int, np.ndarray]]]:
    rows: dict[str, list[list[str]]] = {"u": [], "v": []}
    with DATA_FILE.open(newline="") as f:
        reader = csv.reader(line for line in f if not line.startswith("#"))
        header = next(reader)
        if header != ["line", "coord", "Re100", "Re400", "Re1000"]:
            raise InputError(f"unexpected header {header} in {DATA_FILE}")
        for r in reader:
            rows[r[0]].append(r[1:])
    out = {}
    for comp, rs in rows.items():
        a = np.asarray(rs, dtype=float)
        out[comp] = (a[:, 0], {re: a[:, 1 + k] for k, re in enumerate(REYNOLDS)})
    return out


def table_reynolds(re: float, tol: float = 1e-6) -> int | None:
    """The tabulated Reynolds number equal to ``re`` (relative ``tol``), or None."""
    for r in REYNOLDS:
        if abs(re - r) <= tol * r:
            return r
    return None


def centerline(component: str, re: float, *, include_walls: bool = True,
               include_misprint: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Ghia's centre-line profile: ``component = "u"``: ``(y, u/U_lid)`` along x = 0.5;
    ``"v"``: ``(x, v/U_lid)`` along y = 0.5.  ``include_walls=False`` drops the two wall points
    (coordinates 0 and 1, where the values are the boundary conditions); the flagged misprint is
    dropped unless ``include_misprint``."""
    if component not in ("u", "v"):
        raise InputError(f"invalid component={component!r}; allowed: 'u' (along x = 0.5) or 'v' (along y = 0.5)")
    r = table_reynolds(re)
    if r is None:
        raise InputError(f"invalid re={re!r}: no Ghia et al. (1982) data; allowed: one of "
                         f"{', '.join(map(str, REYNOLDS))}")
    coord, vals = _table()[component]
    val = vals[r]
    keep = np.ones(coord.size, bool)
    if not include_walls:
        keep &= (coord > 0.0) & (coord < 1.0)
    if not include_misprint:
        for comp, rr, c in MISPRINTS:
            if comp == component and rr == r:
                keep &= ~np.isclose(coord, c, rtol=0, atol=1e-9)
    return coord[keep].copy(), val[keep].copy()
