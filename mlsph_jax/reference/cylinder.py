"""Flow past a circular cylinder: reference coefficients (SPEC §12.2 V9-V10, thesis Tables 4.1
and 4.2; issue 17 targets).

Steady Re = 40 (thesis Table 4.1, SPEC V9; the angle convention follows the values: ``cp_front``
is the front stagnation point, theta = pi with the stream along +x, ``cp_base`` the rear point):

=====================================  ======  =========  =======
method                                 C_D     cp_front   cp_base
=====================================  ======  =========  =======
thesis (MLSPH-ALE)                     1.570   1.195      -0.505
Ramírez et al. 2017 (3rd-order FV)     1.568   1.180      -0.512
Chassaing et al. 2013                  1.565   1.205      -0.516
Niu et al. 2003 (LBM)                  1.574   1.147      -0.555
He & Doolen 1997 (LBM)                 1.499   1.133      -0.487
=====================================  ======  =========  =======

:data:`RE40_TARGETS` are the issue-17 targets built on them (C_D 1.56 +- 3 %, cp_front 1.18 +- 4 %,
cp_base -0.51 +- 8 %, L_w / D 2.3 +- 10 %).

Provenance: the table is the thesis' Table 4.1 (``/work/shared/sources/001_0f99307690fff66b.txt``,
§4.5.2, as condensed in SPEC V9).  ``data/cylinder_literature_values.csv`` is an unchanged copy of
the project's reference set ``/work/shared/reference/cylinder_literature_values.csv`` (C_D = 1.565
and L_w / D = 2.31 at Re = 40 from Wu & Shu 2009, Re = 100 values, Williamson 1989 Strouhal
numbers; its ``provenance_quality`` column says how well each number is traced).

Heat transfer (an isothermal cylinder in cross-flow, decision 102): no traceable value is in the
reference set, so :func:`nusselt_churchill_bernstein` and :func:`nusselt_hilpert` give the mean
Nusselt number of two classic correlations of experiments (scatter ~20 %): Churchill & Bernstein
(1977, J. Heat Transfer 99:300-306) and Hilpert (1933, Forsch. Geb. Ingenieurwes. 4:215; constants
as tabulated by Incropera & DeWitt, Fundamentals of Heat and Mass Transfer, Table 7.2).
"""

from __future__ import annotations

import csv
from pathlib import Path

#: Thesis Table 4.1 (Re = 40): method -> (C_D, cp_front, cp_base).
TABLE_4_1 = {
    "thesis (MLSPH-ALE)": (1.570, 1.195, -0.505),
    "Ramirez et al. 2017": (1.568, 1.180, -0.512),
    "Chassaing et al. 2013": (1.565, 1.205, -0.516),
    "Niu et al. 2003": (1.574, 1.147, -0.555),
    "He & Doolen 1997": (1.499, 1.133, -0.487),
}

#: Issue-17 targets at Re = 40: metric -> (value, relative tolerance).
RE40_TARGETS = {"cd": (1.56, 0.03), "cp_front": (1.18, 0.04), "cp_base": (-0.51, 0.08),
                "recirculation_length": (2.3, 0.10)}

_DATA = Path(__file__).parent / "data" / "cylinder_literature_values.csv"


def literature_values() -> list[dict]:
    """Rows of ``data/cylinder_literature_values.csv`` (strings, as published in the reference set)."""
    with open(_DATA, newline="") as f:
        return list(csv.DictReader(f))


def nusselt_churchill_bernstein(re: float, pr: float) -> float:
    """Nu = 0.3 + 0.62 Re^1/2 Pr^1/3 / [1 + (0.4 / Pr)^2/3]^1/4 [1 + (Re / 282000)^5/8]^4/5
    (Churchill & Bernstein 1977; stated for Re Pr > 0.2)."""
    return (0.3 + 0.62 * re ** 0.5 * pr ** (1.0 / 3.0) / (1.0 + (0.4 / pr) ** (2.0 / 3.0)) ** 0.25
            * (1.0 + (re / 282000.0) ** 0.625) ** 0.8)


def nusselt_hilpert(re: float, pr: float) -> float:
    """Nu = C Re^m Pr^1/3, (C, m) = (0.911, 0.385) for 4 <= Re < 40 and (0.683, 0.466) for
    40 <= Re < 4000 (Hilpert 1933 as tabulated by Incropera & DeWitt)."""
    if not 4.0 <= re < 4000.0:
        raise ValueError(f"invalid re={re!r}: Hilpert's constants cover 4 <= Re < 4000")
    c, m = (0.911, 0.385) if re < 40.0 else (0.683, 0.466)
    return c * re ** m * pr ** (1.0 / 3.0)
