"""The ``offset`` layout around a body (``case.layout = "offset"``, decision 105): ``case.offset_rows``
rows along the body's offset curves at distances (m + 1/2) h, the square lattice of spacing h
beyond.  Its first row lies h/2 from the wall along any body, where the cartesian cut-out leaves
h/2 to 3h/2 (a square's faces 1.40 h from their rows spoil the wall pressure: docs/validation.md,
"Bodies given by points").  Checked: the rows' distances, the gap at the wall, the mirror
symmetry, volumes that partition the fluid, no two particles closer than GAP h (also in a
concave notch), a uniform stream and a fluid at rest kept to round-off, and the refusals."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial import cKDTree

from mlsph_jax import config as config_mod
from mlsph_jax.cases import build_problem
from mlsph_jax.cases.body_layouts import (
    BODY_LAYOUTS,
    GAP,
    _merge_crowded,
    body_polygon,
    distance_to_polygon,
    offset_rows,
    polygon_area,
    square_lattice,
    wall_gap,
)
from mlsph_jax.cases.cylinder import _NAMES, _support_radius, body_curve
from mlsph_jax.errors import ConfigError
from mlsph_jax.state import Kind
from mlsph_jax.testing import CONFIG_DIR, uniform_stream_residuals

SQUARE = "[[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]]"
#: The square of docs/validation.md whose faces lie 1.40 h from the cartesian lattice's first rows.
BAD_SQUARE = ("case.body=\"polygon\"", f"case.body_points={SQUARE}", "case.n_theta=48", "case.lattice_ratio=1.176")
#: A square with a notch 0.4 D wide and 0.3 D deep in its top face (concave corners).
NOTCHED = ("case.body=\"polygon\"", "case.body_points=[[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [0.2, 0.5], "
           "[0.2, 0.2], [-0.2, 0.2], [-0.2, 0.5], [-0.5, 0.5]]", "case.n_theta=96", "case.lattice_ratio=1.25")
CIRCLE = ("case.n_theta=32", "case.lattice_ratio=1.5")
#: Symmetric about the x axis and concave: V-notches 0.16 D wide and 0.35 D deep in the top and
#: bottom faces (the first row turns through a kink sharper than 60 degrees in each: merged points).
V_NOTCHED = ("case.body=\"polygon\"", "case.body_points=[[-0.5, -0.5], [-0.08, -0.5], [0.0, -0.15], [0.08, -0.5], "
             "[0.5, -0.5], [0.5, 0.5], [0.08, 0.5], [0.0, 0.15], [-0.08, 0.5], [-0.5, 0.5]]", "case.n_theta=96",
             "case.lattice_ratio=1.125")
#: Symmetric about the x axis with an undercut pocket above and below the axis: rows closed off in
#: the pockets are loops that do not cross the axis, each the other's mirror image.
POCKETS = [[0.5, 0.5], [0.1, 0.5], [0.1, 0.4], [0.3, 0.4], [0.3, 0.1], [-0.3, 0.1], [-0.3, 0.4], [-0.1, 0.4],
           [-0.1, 0.5], [-0.5, 0.5]]
POCKETS = [[x, -y] for x, y in POCKETS[::-1]] + POCKETS


def _cfg(*extra, layout="offset"):
    return config_mod.load(CONFIG_DIR / "cylinder.toml", [f"case.layout=\"{layout}\"", "case.r_far=2.0",
                                                          "output.plots=false", "output.progress=false", *extra])


def _layout(cfg):
    body = body_curve(cfg)
    P = {k: jnp.asarray(v, jnp.float64) for k, v in body.defaults().items()}
    c = cfg["case"]
    lay = BODY_LAYOUTS.get(c["layout"]).build(c, body, P, lambda dx: _support_radius(cfg, dx), _NAMES)
    return lay, body, P


@pytest.mark.parametrize("extra", [BAD_SQUARE, CIRCLE, NOTCHED], ids=["square", "circle", "notched"])
def test_rows_lie_at_their_offsets_and_the_lattice_beyond(extra):
    """Every fluid particle closer than offset_rows h to the body lies on a row, at a distance
    (m + 1/2) h from the body polygon: exactly on straight faces, within the contouring's
    interpolation error elsewhere (measured 4.0e-4 h at the square's corner arcs, 1.9e-4 h on the
    circle, 8.9e-4 h in the notch; bound 2e-3 h), the first row holding about one particle per h of
    the perimeter; no fluid particle is inside the body and no two particles are closer than GAP h
    (the rows are thinned where they crowd into a concave corner)."""
    cfg = _cfg(*extra)
    lay, body, P = _layout(cfg)
    poly = body_polygon(body, P)
    fluid = lay.kind == int(Kind.FLUID)
    d = distance_to_polygon(lay.x[fluid], poly) / lay.h
    rows = cfg["case"]["offset_rows"]
    on_rows = d < rows - 1e-9
    assert np.all(np.abs(d[on_rows] - (np.floor(d[on_rows]) + 0.5)) <= 2e-3), np.sort(d[on_rows])[:5]
    assert np.sum(np.abs(d - 0.5) <= 2e-3) >= 0.9 * _perimeter(poly) / lay.h
    nn, _ = cKDTree(lay.x).query(lay.x, k=2)
    assert nn[:, 1].min() >= GAP * lay.h * (1.0 - 1e-9)
    from mlsph_jax.geometry.checks import inside_polygon
    assert not inside_polygon(lay.x[fluid], poly).any()


def _perimeter(poly):
    return float(np.sum(np.linalg.norm(np.roll(poly, -1, axis=0) - poly, axis=1)))


def test_first_row_half_a_spacing_from_every_face_where_the_lattice_left_1_4():
    """The square of side D at h = D / 10.2 (n_theta 48, lattice_ratio 1.176): the cartesian cut-out
    leaves its faces 1.40 h from the first rows (wall_gap, averaged over an eighth of the body;
    the set-up warns), the offset layout 0.5 h at the faces' quadrature points' feet: the nearest
    particle of every quadrature point lies between h/2 (straight in front) and sqrt(1/4 + 1/4) h
    (half a row spacing aside), so the averaged gap is below 0.71 everywhere (measured 0.54-0.58)."""
    from mlsph_jax.errors import LayoutWarning

    with pytest.warns(LayoutWarning):
        cart, body, P = _layout(_cfg(*BAD_SQUARE, layout="cartesian"))
    off, _, _ = _layout(_cfg(*BAD_SQUARE))
    assert off.h == cart.h
    g_cart = wall_gap(body, P, cart.x[cart.kind == int(Kind.FLUID)], cart.h)
    g_off = wall_gap(body, P, off.x[off.kind == int(Kind.FLUID)], off.h)
    assert g_cart.max() > 1.35 and 0.5 - 1e-9 <= g_off.min() and g_off.max() <= math.sqrt(0.5) + 1e-9


@pytest.mark.parametrize("extra", [BAD_SQUARE, CIRCLE, V_NOTCHED], ids=["square", "circle", "v_notched"])
def test_offset_layout_is_mirror_symmetric_and_partitions_the_fluid(extra):
    """A body symmetric about the x axis gets a layout symmetric about it (the rows start at their
    front crossing of the axis; the distance field's grid is centred on the axis; crowded points
    are merged into centroids, not dropped one of a pair) to round-off, so a symmetric flow stays
    symmetric (measured 3.4e-13 h on the V-notched body, whose rows are merged at the notches'
    kinks; dropping the later point of each pair left two particles 0.22 h from their mirror
    images); the fluid volumes (Voronoi cells clipped to the body) sum to N_disc h^2 less the
    body polygon's area, as on the cartesian layout, each between 0.5 and 2.5 h^2 (measured 0.93-1.12
    h^2 around the square, 0.78-1.16 around the circle, 0.79-2.28 around the V-notched body, whose
    largest cells sit where its rows merge at the notches' tips)."""
    cfg = _cfg(*extra)
    lay, body, P = _layout(cfg)
    fluid = lay.kind == int(Kind.FLUID)
    xf = lay.x[fluid]
    d, _ = cKDTree(xf).query(xf * np.array([1.0, -1.0]))
    assert d.max() <= 1e-11 * lay.h
    n_disc = len(square_lattice(lay.h, cfg["case"]["r_far"]))
    area = polygon_area(body_polygon(body, P))
    assert abs(lay.vol[fluid].sum() - (n_disc * lay.h ** 2 - area)) <= 1e-12 * n_disc * lay.h ** 2
    assert lay.vol.min() > 0.5 * lay.h ** 2 and lay.vol[fluid].max() < 2.5 * lay.h ** 2


def test_rows_closed_off_in_pockets_are_mirror_images():
    """Rows that do not reach the x axis (closed off in an undercut pocket) start at their point
    of least x and, on a vertical side, of least |y|: the loops in the upper and lower pockets are
    sampled at mirrored points (the first point of least x in the contour's order started the
    lower pocket's loop at y = -0.2419 and the upper one's at y = +0.2588: 13 particles 0.47 h
    from their mirror images)."""
    h = 0.09
    poly = np.asarray(POCKETS, float)
    rows = offset_rows(poly, h, 3)
    d, _ = cKDTree(rows).query(rows * np.array([1.0, -1.0]))
    assert d.max() <= 1e-11 * h
    pocket = (np.abs(rows[:, 1]) > 0.2) & (np.abs(rows[:, 1]) < 0.35) & (np.abs(rows[:, 0]) < 0.25)
    assert pocket.sum() >= 8            # the rows in the pockets exist (8 per pocket at 1.5 h)


def test_crowded_points_merge_into_their_centroid():
    """Points closer than GAP h to each other (chains of them too) become one point at their
    centroid, repeated until none are; isolated points are kept as they are; the result of
    mirrored points is the mirrored result."""
    h = 1.0
    pts = np.array([[0.0, 1.0], [0.3, 1.0], [0.6, 1.0], [5.0, 0.0], [0.0, -1.0], [0.3, -1.0], [0.6, -1.0]])
    out = _merge_crowded(pts, h)
    assert sorted(map(tuple, np.round(out, 12))) == [(0.3, -1.0), (0.3, 1.0), (5.0, 0.0)]
    # a centroid landing next to another point merges again
    out = _merge_crowded(np.array([[0.0, 0.0], [0.4, 0.0], [0.55, 0.0]]), h)
    assert np.allclose(out, [[0.95 / 3, 0.0]])


def test_uniform_stream_and_rest_on_the_offset_layout():
    """On the offset layout around the square: a uniform free stream without walls and a fluid at
    rest with the square's boundary terms have a zero right-hand side to round-off (bound 2e-11 of
    max |q|, as on the other layouts; measured 3.4e-13 and 2.8e-13), the stream through the no-slip
    square does not (the check can fail); the frozen far field gets no update."""
    cfg = _cfg(*BAD_SQUARE)
    r = uniform_stream_residuals(build_problem(cfg), cfg)
    assert r["stream"] <= 2e-11 and r["rest"] <= 2e-11 and r["moving"] > 1e-3, r
    assert r["n_frozen"] > 0 and not r["frozen_updated"], r


@pytest.mark.parametrize("overrides, words", [
    (("case.offset_rows=2",), ["case.offset_rows=2", "case.layout=\"polar\"", "\"offset\" only"]),
    (("case.layout=\"cartesian\"", "case.offset_rows=2"), ["case.offset_rows=2", "\"offset\" only"]),
    (("case.layout=\"offset\"", "case.offset_rows=0"), ["case.offset_rows=0", "allowed: int >= 1"]),
    (("case.layout=\"offset\"", "case.offset_rows=12", "case.lattice_ratio=1.5"),
     ["case.offset_rows=12", "far field", "allowed: case.r_far > 2.93 or case.offset_rows <= 5"]),
    (("case.layout=\"offset\"", "case.lattice_ratio=2.0"), ["case.lattice_ratio=2", "too coarse"]),
    (("case.body=\"polygon\"", f"case.body_points={SQUARE}", "case.layout=\"blend\""),
     ["case.layout=\"blend\"", "allowed: case.layout = \"cartesian\"", "or \"offset\""]),
])
def test_bad_offset_layouts_name_the_key(overrides, words):
    """The rows key without the layout that uses it, zero rows, rows reaching the far field, a
    lattice too coarse for the body, a body given by points on a polar-based layout: ConfigError
    naming the key, its value and what is allowed."""
    with pytest.raises(ConfigError) as e:
        config_mod.load(CONFIG_DIR / "cylinder.toml", ["case.n_theta=32", "case.r_far=2.0", *overrides])
    for w in words:
        assert w in str(e.value), (w, str(e.value))
