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
