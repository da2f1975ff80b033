"""Layouts of the fluid around a body in a stream: the ``cylinder`` case's ``case.layout``
(registry :data:`BODY_LAYOUTS`; docs/architecture.md decision 72; issue 17 item 4).

* ``"polar"`` (default): the body-fitted polar (O-grid) layout of
  :func:`~mlsph_jax.cases.layouts.polar_layout`, carried onto an elliptic body by the conformal
  map of :func:`~mlsph_jax.cases.layouts.elliptic_polar_layout` (decision 65); volumes the
  (mapped) annular-sector areas; the particles follow the body's parameters.
* ``"cartesian"``: a uniform square lattice x = ((i + 1/2) h, (j + 1/2) h) (mirror-symmetric about
  both axes) over the disc |x| < ``r_far``, h = ``case.lattice_ratio`` times the body's quadrature
  spacing (its perimeter / ``case.n_theta``).  Lattice points inside the body or closer than
  :data:`GAP` h to its curve are removed (the cut-out works for any closed curve: it uses the
  curve's polygon of :data:`FINE` x ``n_theta`` vertices, or a polygon body's own vertices, not
  a formula of the circle).  With ``"offset"``, the layouts of a ``"polygon"`` or ``"spline"``
  body (:func:`shape_curve`; decision 103).
* ``"blend"``: the polar rings out to ``case.blend_radius`` (its ring edges end there exactly),
  the same square lattice beyond, with h the particle spacing sqrt(V) of the outermost ring (so
  the ring spacing matches the lattice spacing at the blend radius); lattice points inside the
  outer ring's edge or closer than :data:`GAP` h to a ring particle are removed.
* ``"offset"`` (decision 105): ``case.offset_rows`` rows of particles along the body's offset
  curves, row m on the level set (m + 1/2) h of the distance to the body (its polygon of
  :data:`FINE` x ``n_theta`` vertices, or a polygon body's own vertices), ``round(length / h)``
  particles per row equally spaced by arc length from the row's front crossing of the x axis;
  beyond them the ``cartesian`` lattice of the same h, its points kept where they are at least
  ``offset_rows`` h from the body and :data:`GAP` h from every row particle.  The first row lies
  h/2 from the wall all along any body (straight faces, corners, a spline's curvature), where
  the lattice's cut-out leaves h/2 to 3h/2.  The level sets come from the distance field on a
  grid of h / :data:`OFFSET_GRID` (:func:`offset_rows`; matplotlib's contouring, contourpy), so
  convex corners get arcs and rows closed off in a concave pocket are kept; points of a row
  closer than :data:`GAP` h to each other (where it turns through a kink sharper than 60
  degrees) are merged into their centroid.  Fits every body (circle, ellipse, points).
* ``"graded"`` (decision 90): the polar rings with the ring particles of the near wake replaced by
  a point cloud whose spacing grades smoothly.  Target spacing h_w(x) = D (``wake_spacing`` +
  ``wake_grading`` d / D), d the distance from the wake-axis segment x in [R, ``wake_length`` D],
  y = 0 (:func:`wake_target`); a ring particle (beyond the first :data:`KEEP_RINGS` rings and
  inside the last two fluid rings) is replaced where h_w is below its ring's spacing sqrt(V) = c_p
  r (:func:`_ring_spacing_ratio`).  ``wake_grading`` > c_p (0.126 at n_theta 48) closes that
  region.  The cloud is sampled in the replaced cells with density 1 / h^2 (seeded thinning of a
  fine hexagonal lattice) and relaxed by compressed springs on its Delaunay edges, rest lengths
  proportional to the target spacing at their midpoints, the ring particles fixed (the force
  balance of Persson & Strang's DistMesh, 2004, SIAM Review 46; our own implementation).  Because
  the target is Lipschitz with constant ``wake_grading``, neighbouring spacings differ by ~1 +
  ``wake_grading`` everywhere and the largest gather count (the global row capacity) stays near
  the polar layout's, unlike a uniform strip with a jump at its edge (tag
  ``tried/wake-strip-layout``, decision 86).  Voronoi volumes clipped to the body for the fluid,
  sector areas for the polar frozen rings; circle only; no shape derivatives (as the lattices).

Lattice layouts (cartesian, blend, offset): beyond ``r_far`` the lattice continues as FROZEN far-field particles
(:class:`~mlsph_jax.state.Kind`) out to the support radius of the outermost fluid particle plus
one spacing (as the polar layout's frozen rings).  Volumes are consistent with the layout: the
Voronoi cell of each fluid particle among all particles (:class:`scipy.spatial.Voronoi`),
clipped to the fluid side of the body (cell area minus the area of the body polygon clipped to
the convex cell, Sutherland-Hodgman).  The fluid cells partition the region between the body
and the lattice squares of the lattice points inside ``r_far`` (a staircase of the disc), so
the fluid volumes sum to N_disc h^2 - area(body), N_disc the lattice points with |x| < r_far
(those removed included), to the accuracy of the body polygon (tests/test_body_layouts.py).
Frozen particles get h^2.

Size: a layout's ``count(case, support) -> (estimate, keys)`` (optional; the three built-in ones
have it) gives its particle count (fluid and frozen) from the config alone, before any array is
built, and the config keys that set it; the case hands it to the general guard
``run.max_particles`` (:mod:`mlsph_jax.config.resolve`; a layout without it is held to the limit
after building).
Exact for the polar layout; for the lattices the areas divided by h^2 (within a few per cent,
tests/test_particle_limit.py).

Shape derivatives: the lattice is cut once at set-up, so its particle set and the Voronoi
volumes change discontinuously with the body; the lattice layouts do not follow the body's
parameters, and differentiating with respect to ``geometry.body.{centre, radius, aspect}`` on
them is refused (:class:`~mlsph_jax.errors.InputError` at trace time).  The angle of attack
``geometry.body.alpha`` turns the free stream, not the body, and stays differentiable.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Callable, Mapping
from typing import NamedTuple

import contourpy
import jax
import numpy as np
from matplotlib.path import Path
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import Voronoi, cKDTree

from ..errors import InputError, LayoutWarning
from ..geometry import Polygon, Spline, curve_params
from ..geometry.checks import inside_polygon, self_crossing, spacing_ratio
from ..registry import Registry
from ..schema import show
from ..state import Kind
from .layouts import elliptic_polar_layout, polar_layout, polar_ring_edges

#: Lattice points closer than GAP h to the body's curve (cartesian) or to a ring particle (blend)
#: are removed: no two particles are closer than GAP h (the polar layout's first ring sits h/2
#: from the wall).
GAP = 0.5
#: The body polygon used for the cut-out and the clipping has FINE x n_theta vertices.
FINE = 16
#: :func:`_warn_wall_gap`: the largest mean gap, in lattice spacings, between the wall and its
#: nearest particles over a stretch of the body that the cartesian layout builds without a warning.
WALL_GAP_WARN = 1.2
#: Fewest lattice spacings around the body's perimeter (n_theta / lattice_ratio).
MIN_SPACINGS_AROUND = 20
#: Parameters a lattice layout cannot follow (shape derivatives refused).
SHAPE_FIELDS = ("centre", "radius", "aspect", "vertices", "knots")
#: ``case.body`` values given by points (``case.body_points``), not by a formula; :data:`POINT_LAYOUTS` only.
POINT_BODIES = ("polygon", "spline")
#: The layouts that fit any closed curve (the lattices), hence a body given by points.
POINT_LAYOUTS = ("cartesian", "offset")

#: Layouts around a body (the ``cylinder`` case's ``case.layout``; the kind is a label, since other
#: cases' ``case.layout`` keys name their own, unregistered, layouts).
BODY_LAYOUTS: Registry = Registry("body_layout", protocol=("check", "build"),
                                  doc="particle layouts around a body in a stream (the cylinder's case.layout)")


class BodyLayout(NamedTuple):
    """A layout's result: ``x[N, 2]``, ``vol[N]``, ``kind[N]`` (FLUID or FROZEN), the lattice
    spacing ``h`` (nan for the polar layout), ``positions_at(params) -> (x, vol)`` (jnp) when
    the layout follows the body's parameters, else the set-up particles with shape derivatives
    refused, and ``bound``, the outermost ring edge of the polar layout (nan for the others)."""

    x: np.ndarray
    vol: np.ndarray
    kind: np.ndarray
    h: float
    positions_at: Callable
    bound: float = float("nan")


# --- geometry ---------------------------------------------------------------------------------

def body_polygon(body, params) -> np.ndarray:
    """The closed body curve as a polygon: a :class:`~mlsph_jax.geometry.Polygon`'s own vertices,
    else :data:`FINE` x ``n_points`` points of the curve (counter-clockwise for the built-in
    curves)."""
    if isinstance(body, Polygon):
        return np.asarray(params[body.key("vertices")], float)
    fine = dataclasses.replace(body, n_points=FINE * body.n_points)
    return np.asarray(fine.points(params)[0], float)


def shape_curve(case: Mapping, name: str = "body"):
    """The curve of a ``case.body`` given by points (:data:`POINT_BODIES`; decision 103):
    ``case.body_points`` scaled by D = 2 ``case.radius`` (the points are in units of the reference
    length D, about the body's centre, the origin), a :class:`~mlsph_jax.geometry.Polygon` with
    pieces no longer than its perimeter / ``case.n_theta`` or a periodic cubic
    :class:`~mlsph_jax.geometry.Spline` with ``case.n_theta`` quadrature points."""
    pts = 2.0 * case["radius"] * np.asarray(case["body_points"], float)
    if case["body"] == "polygon":
        perimeter = float(np.sum(np.linalg.norm(np.roll(pts, -1, axis=0) - pts, axis=1)))
        return Polygon(name, vertices=pts, spacing=perimeter / case["n_theta"])
    return Spline(name, knots=pts, n_points=case["n_theta"])


def points_text(points) -> str:
    """``case.body_points`` as written in TOML, shortened to its first three points and the count
    when it has more than eight (messages)."""
    pts = [list(map(float, q)) for q in points]
    if len(pts) <= 8:
        return show(pts)
    return show(pts[:3])[:-1] + f", ... ({len(pts)} points)]"


def shape_problems(case: Mapping) -> list[str]:
    """What is wrong with ``case.body_points`` for a body given by points: fewer than 3 points, a
    point repeated (next to each other or anywhere: a pinch), a curve that is not simple (the
    polygon through the points or the spline's polyline of 4 ``n_theta`` points crosses or touches
    itself, or turns back onto itself: collinear points enclosing no area included), or the body's
    centre, the origin, not inside it (the angles of C_p(theta), the wake axis and the trigger are taken about it)."""
    raw, key = case["body_points"], "case.body_points"
    pts = np.asarray(raw, float).reshape(-1, 2)
    what = f"invalid {key}={points_text(raw)} for case.body={show(case['body'])}"
    if len(pts) < 3:
        return [f"{what}: {len(pts)} points; allowed: at least 3 [x, y] points in units of D = 2 case.radius "
                "about the body's centre (the origin)"]
    size = float(np.max(np.abs(pts))) * 2.0 * case["radius"]
    if not (math.isfinite(size) and 1e-9 * case["r_far"] < size < case["r_far"]):
        return [f"{what}: the body reaches {size:.4g} from the origin, against case.r_far={show(case['r_far'])}; "
                f"allowed: points with 1e-9 case.r_far < max |x|, |y| x D < case.r_far (D = 2 case.radius = "
                f"{2.0 * case['radius']:.4g})"]
    same = np.flatnonzero(np.all(pts[:, None] == pts[None], axis=-1).sum(axis=1) > 1)
    if same.size:
        k = int(same[0])
        return [f"{what}: point {k} {pts[k].tolist()} appears more than once; allowed: distinct points (the "
                "curve closes itself: do not repeat the first point at the end)"]
    poly = shape_outline(case, fine=4)
    k = self_crossing(poly, touching=True)
    if k is not None:
        near = np.round(poly[k[0]] / (2.0 * case["radius"]), 6).tolist()
        return [f"{what}: the {case['body']} through the points crosses, touches or turns back onto itself (near "
                f"{near} in units of D); allowed: points in order around a simple closed curve"]
    if not inside_polygon(np.zeros((1, 2)), poly)[0]:
        return [f"{what}: the origin (the body's centre) is not inside the body; allowed: points about the origin "
                "(shift them so that it lies inside)"]
    return []


def polygon_area(poly: np.ndarray) -> float:
    """Shoelace area (positive for counter-clockwise vertices)."""
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def distance_to_polygon(x: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Distance of each point ``x[N, 2]`` to the closed polygon's edges."""
    a, b = poly, np.roll(poly, -1, axis=0)
    d = b - a
    t = np.clip(np.einsum("nmk,mk->nm", x[:, None] - a[None], d) / np.sum(d * d, axis=1), 0.0, 1.0)
    closest = a[None] + t[..., None] * d[None]
    return np.sqrt(np.min(np.sum((x[:, None] - closest) ** 2, axis=-1), axis=1))


def clip_to_convex(subject: np.ndarray, convex: np.ndarray) -> np.ndarray:
    """Sutherland-Hodgman: the part of polygon ``subject`` inside the convex counter-clockwise
    polygon ``convex`` (``subject`` may be non-convex: the area of the result is exact)."""
    out = subject
    for a, b in zip(convex, np.roll(convex, -1, axis=0), strict=True):
        if len(out) == 0:
            break
        e = b - a
        side = e[0] * (out[:, 1] - a[1]) - e[1] * (out[:, 0] - a[0])      # >= 0: inside
        nxt, s_nxt = np.roll(out, -1, axis=0), np.roll(side, -1)
        keep = side >= 0.0
        cross = (side >= 0.0) != (s_nxt >= 0.0)
        t = side / np.where(cross, side - s_nxt, 1.0)
        hit = out + t[:, None] * (nxt - out)
        pts = np.stack([out, hit], axis=1)                       # per vertex: itself, then a crossing
        use = np.stack([keep, cross], axis=1)
        out = pts[use]
    return out


def square_lattice(h: float, reach: float) -> np.ndarray:
    """Points ((i + 1/2) h, (j + 1/2) h) with |x| < ``reach`` (mirror-symmetric about both axes)."""
    n = int(math.ceil(reach / h))
    c = (np.arange(-n, n) + 0.5) * h
    X, Y = np.meshgrid(c, c, indexing="xy")
    pts = np.stack([X.ravel(), Y.ravel()], axis=1)
    return pts[np.hypot(pts[:, 0], pts[:, 1]) < reach]


def voronoi_volumes(points: np.ndarray, n_fluid: int, body: np.ndarray) -> np.ndarray:
    """Areas of the Voronoi cells of the first ``n_fluid`` of ``points`` (every one must be
    bounded, i.e. surrounded by the others), minus their overlap with the ``body`` polygon."""
    vor = Voronoi(points)
    centre = body.mean(axis=0)
    reach = float(np.max(np.hypot(*(body - centre).T)))
    vol = np.empty(n_fluid)
    for i in range(n_fluid):       # set-up only; a Voronoi region has a variable vertex count
        region = vor.regions[vor.point_region[i]]
        if -1 in region or not region:
            raise InputError(f"invalid lattice layout: the Voronoi cell of fluid particle {i} at "
                             f"x={np.round(points[i], 6).tolist()} is unbounded; allowed: fluid particles "
                             "surrounded by far-field particles")
        cell = vor.vertices[region]
        if polygon_area(cell) < 0.0:
            cell = cell[::-1]
        area = polygon_area(cell)
        # the cell can overlap the body only if it reaches into the body's circumscribed circle
        if inside_polygon(centre[None], cell)[0] or distance_to_polygon(centre[None], cell)[0] < reach:
            cut = clip_to_convex(body, cell)
            area -= abs(polygon_area(cut)) if len(cut) else 0.0
        vol[i] = area
    return vol


# --- the layouts ------------------------------------------------------------------------------

def _body_extent(body, params) -> float:
    poly = np.asarray(body.points(params)[0], float)
    return float(np.max(np.hypot(poly[:, 0], poly[:, 1])))


def _perimeter(body, params) -> float:
    return float(np.sum(np.asarray(body.points(params)[1])))


def _fixed_positions(x, vol, body, layout: str, params):
    """``positions_at`` of a lattice layout: the set-up particles for the set-up shape; a traced
    shape parameter (a shape derivative) or a concrete one that differs from the set-up value (the
    particles would not follow the body) is refused."""
    keys = [k for k in (body.key(f) for f in SHAPE_FIELDS) if k in params]
    setup = {k: np.asarray(params[k], float) for k in keys}

    def positions_at(P):
        moving = [k for k in keys if k in P and (isinstance(P[k], jax.core.Tracer)
                                                 or not np.array_equal(np.asarray(P[k], float), setup[k]))]
        if moving:
            points = any(k.endswith((".vertices", ".knots")) for k in keys)
            allowed = ("no derivative with respect to the points of a polygon or spline body (only the cartesian "
                       "and offset layouts fit them, cut once at set-up); geometry.body.alpha turns the stream and "
                       "stays differentiable" if points
                       else "case.layout=\"polar\" for shape derivatives (geometry.body.alpha turns the stream "
                       "and stays differentiable)")
            raise InputError(f"invalid derivative or change of {', '.join(moving)} with case.layout=\"{layout}\": "
                             "the lattice is cut out around the body once at set-up (its particle set and "
                             "Voronoi volumes change discontinuously with the body), so it cannot follow the "
                             f"shape; allowed: {allowed}")
        return x, vol
    return positions_at


def _lattice_candidates(h: float, r_far: float, support: Callable[[float], float]):
    """The square lattice of spacing ``h`` split at ``r_far``: the fluid candidates (|x| < r_far)
    and the frozen far-field points out to r_far + reach, reach = support(h) + h (a full support
    of frozen particles behind the outermost fluid particle)."""
    reach = support(h) + h
    pts = square_lattice(h, r_far + reach)
    r = np.hypot(pts[:, 0], pts[:, 1])
    return pts[r < r_far], pts[(r >= r_far) & (r < r_far + reach)]


def check_outside(x, kind, body, params, layout: str) -> None:
    """No fluid particle of a layout may lie inside the body (its polygon of :data:`FINE` x
    ``n_points`` vertices): InputError naming ``case.layout``."""
    fluid = np.flatnonzero(np.asarray(kind) == int(Kind.FLUID))
    inside = inside_polygon(np.asarray(x)[fluid], body_polygon(body, params))
    if inside.any():
        i = int(fluid[np.argmax(inside)])
        raise InputError(f"invalid case.layout={layout!r}: fluid particle {i} at x={np.round(x[i], 6).tolist()} is "
                         f"inside the body geometry.{body.name} ({int(inside.sum())} particles); allowed: a layout "
                         "whose fluid particles all lie outside the body")


def _finish(fluid, frozen, h, body, params, what, case_value):
    """The layout of fluid and frozen lattice/ring points with Voronoi volumes clipped to the body."""
    poly = body_polygon(body, params)
    pts = np.concatenate([fluid, frozen])
    vf = voronoi_volumes(pts, len(fluid), poly)
    worst = spacing_ratio(body, params, fluid, vf)
    if worst > 1.0 + 1e-9:
        # sqrt(V) next to the body scales with the lattice spacing (cartesian) or with 1 / n_theta (blend)
        lattice = what in ("cartesian", "offset")
        allowed = (f"case.lattice_ratio >= {case_value * worst:.4g}" if lattice else
                   "a larger case.n_theta or case.layout=\"polar\"")
        key = "case.lattice_ratio" if lattice else "case.n_theta"
        raise InputError(f"invalid {key}={case_value!r} with case.layout={what!r} (case.n_theta={body.n_points}): "
                         f"the body's quadrature pieces are up to {worst:.3g} spacings sqrt(V) of the nearest "
                         f"particle long, too sparse for the particles (geometry.checks.spacing_ratio); allowed: at "
                         f"most 1 spacing, {allowed}")
    vol = np.concatenate([vf, np.full(len(frozen), h * h)])
    kind = np.concatenate([np.full(len(fluid), int(Kind.FLUID)), np.full(len(frozen), int(Kind.FROZEN))])
    return pts, vol, kind


def _around(inner, cand, keep, frozen, h, body, params, case, layout: str) -> BodyLayout:
    """A lattice layout of ``inner`` particles next to the body (the blend's rings, the offset
    rows) and the lattice candidates ``cand[keep]`` at least :data:`GAP` h from them (a point
    exactly GAP h away is kept, not dropped by round-off), the frozen lattice beyond ``r_far``."""
    d, _ = cKDTree(inner).query(cand[keep])
    keep = keep.copy()
    keep[np.flatnonzero(keep)[d < GAP * h * (1.0 - 1e-9)]] = False
    fluid = np.concatenate([inner, cand[keep]])
    x, vol, kind = _finish(fluid, frozen, h, body, params, layout,
                           case["n_theta"] if layout == "blend" else case["lattice_ratio"])
    return BodyLayout(x, vol, kind, h, _fixed_positions(x, vol, body, layout, params))


class Polar:
    """Body-fitted polar rings with geometric growth (decisions 58, 65), frozen rings beyond
    ``r_far``; the layout follows the body's shape parameters."""

    @staticmethod
    def check(case: Mapping, support: Callable[[float], float]) -> list[str]:
        return []

    @staticmethod
    def build(case: Mapping, body, params, support, names) -> BodyLayout:
        n_theta = case["n_theta"]
        lay = polar_layout(case["radius"], n_theta, case["r_far"], far_rings(case, support, names), names=names)
        n_fluid = len(polar_ring_edges(case["radius"], n_theta, case["r_far"], names=names)[0]) - 1
        kind = np.where(lay.ring < n_fluid, int(Kind.FLUID), int(Kind.FROZEN))

        def positions_at(P):
            semi_axes, angle = body._axes(P)
            return elliptic_polar_layout(lay.edges, n_theta, P[body.key("centre")], semi_axes, angle)
        x, vol = (np.asarray(a) for a in positions_at(params))
        return BodyLayout(x, vol, kind, float("nan"), positions_at, float(lay.edges[-1]))

    @staticmethod
    def count(case: Mapping, support: Callable[[float], float]) -> tuple[int, tuple[str, ...]]:
        """n_theta x (fluid rings + frozen rings), exact."""
        names = ("case.radius", "case.n_theta", "case.r_far")
        n_rings = len(polar_ring_edges(case["radius"], case["n_theta"], case["r_far"], names=names)[0]) - 1
        return case["n_theta"] * (n_rings + far_rings(case, support, names)), names


def far_rings(case: Mapping, support: Callable[[float], float], names) -> int:
    """Frozen rings beyond ``r_far`` of the polar layout: the fewest whose widths (the geometric
    sequence continued) cover the support radius of the outermost fluid ring's particles, plus one."""
    edges, q = polar_ring_edges(case["radius"], case["n_theta"], case["r_far"], names=names)
    dtheta = 2.0 * math.pi / case["n_theta"]
    reach = support(math.sqrt(0.5 * (edges[-1] ** 2 - edges[-2] ** 2) * dtheta))
    width, k = 0.0, 0
    while width < reach:
        k += 1
        width += (edges[-1] - edges[-2]) * q ** k
    return k + 1


def shape_outline(case: Mapping, fine: int = FINE) -> np.ndarray:
    """The polygon of a body given by points, from the config alone: a polygon's vertices, a
    spline's ``fine`` x ``n_theta`` points (:func:`body_polygon` with :data:`FINE`)."""
    curve = shape_curve(case)
    if isinstance(curve, Polygon):
        return np.asarray(curve.vertices, float)
    fine_curve = dataclasses.replace(curve, n_points=fine * curve.n_points)
    return np.asarray(fine_curve.points(curve_params([curve]))[0], float)


def body_extent(case: Mapping) -> float:
    """Largest distance of the body's curve from its centre (an ellipse: its semi-major axis; a
    body given by points: from the origin)."""
    if case["body"] in POINT_BODIES:
        return float(np.max(np.hypot(*shape_outline(case).T)))
    return case["radius"] * (math.sqrt(max(case["aspect"], 1.0 / case["aspect"])) if case["body"] == "ellipse"
                             else 1.0)


def body_area_radius(case: Mapping) -> float:
    """The radius of the circle with the body's area (``case.radius`` for the circle and the
    ellipse; from the outline for a body given by points)."""
    if case["body"] in POINT_BODIES:
        return math.sqrt(abs(polygon_area(shape_outline(case))) / math.pi)
    return case["radius"]


def _perimeter_estimate(case: Mapping) -> float:
    """The body's perimeter (Ramanujan's approximation for the ellipse; config checks only)."""
    R = case["radius"]
    if case["body"] in POINT_BODIES:        # as the build measures it: the quadrature's lengths
        curve = shape_curve(case)
        return float(np.sum(np.asarray(curve.points(curve_params([curve]))[1])))
    if case["body"] != "ellipse":
        return 2.0 * math.pi * R
    a, b = R * math.sqrt(case["aspect"]), R / math.sqrt(case["aspect"])
    return math.pi * (3.0 * (a + b) - math.sqrt((3.0 * a + b) * (a + 3.0 * b)))


def lattice_spacing(case: Mapping) -> float:
    """h of the ``cartesian`` layout: ``lattice_ratio`` x perimeter / ``n_theta``."""
    return case["lattice_ratio"] * _perimeter_estimate(case) / case["n_theta"]


def blend_edges(case: Mapping) -> np.ndarray:
    """Ring edges R q^k, k = 0..n, of the ``blend`` layout, ending at ``blend_radius``: as
    :func:`~mlsph_jax.cases.layouts.polar_ring_edges` but with n rounded down (cells at least as
    long radially as they are wide, q >= 1 + 2 pi / n_theta), so that the first ring's particles
    are never smaller than the body's quadrature pieces; at least two rings."""
    R, rb = case["radius"], case["blend_radius"]
    n = max(2, math.floor(math.log(rb / R) / math.log1p(2.0 * math.pi / case["n_theta"]) + 1e-9))
    return R * (rb / R) ** (np.arange(n + 1) / n)


def _ring_scale(case: Mapping) -> float:
    """(a + b) / 2R: the scale of an ellipse's mapped rings against the circle's (1 for a circle)."""
    if case["body"] != "ellipse":
        return 1.0
    return 0.5 * (math.sqrt(case["aspect"]) + 1.0 / math.sqrt(case["aspect"]))


def blend_spacing(case: Mapping) -> float:
    """h of the ``blend`` layout: sqrt(V) of the outermost ring's particles of the circle's rings
    ending at ``blend_radius`` (an ellipse's mapped rings are scaled by (a + b) / 2R)."""
    edges = blend_edges(case)
    return _ring_scale(case) * math.sqrt(0.5 * (edges[-1] ** 2 - edges[-2] ** 2) * 2.0 * math.pi / case["n_theta"])


def _lattice_count(case: Mapping, h: float, r_in: float, support: Callable[[float], float]) -> int:
    """Lattice points of spacing ``h`` in the annulus r_in < r < r_far (fluid) and out to r_far plus
    the frozen reach support(h) + h: the areas divided by h^2."""
    r_out = case["r_far"] + support(h) + h
    return round(math.pi * (r_out ** 2 - r_in ** 2) / (h * h))


def _far_problems(case, h, support) -> list[str]:
    need = body_extent(case) + GAP * h + support(h) + h
    if case["r_far"] <= need:
        return [f"invalid case.r_far={case['r_far']!r} with case.layout={case['layout']!r} (lattice spacing "
                f"{h:.4g}): the far field starts inside the support of the body's wall points (out to r = "
                f"{need:.4g}); allowed: case.r_far > {need:.4g}"]
    return []


def wall_gap(body, params, fluid_x: np.ndarray, h: float) -> np.ndarray:
    """``[Nb]``: the distance from each of the body's quadrature points to the nearest fluid
    particle in lattice spacings h, averaged over the neighbouring eighth of the body's points (a
    stretch of the wall; periodic along the closed curve)."""
    xb = np.asarray(body.points(params)[0], float)
    d = cKDTree(fluid_x).query(xb)[0] / h
    w = max(1, len(d) // 8)
    return np.convolve(np.concatenate([d[-w:], d, d[:w]]), np.ones(w) / w, mode="same")[w:-w]


def _warn_wall_gap(case: Mapping, body, params, fluid_x: np.ndarray, h: float) -> None:
    """:class:`~mlsph_jax.errors.LayoutWarning` when the lattice's first row lies on average more
    than :data:`WALL_GAP_WARN` spacings from the wall over a stretch of the body (:func:`wall_gap`):
    the wall state extrapolates across that gap (docs/validation.md "Bodies given by points": a
    square's faces 1.40 h from their rows gave C_p front 1.82 against 1.20 at h/2; the circle's
    21-spacing lattice, 1.24, a front C_p of 1.93)."""
    gap = wall_gap(body, params, fluid_x, h)
    k = int(np.argmax(gap))
    if gap[k] <= WALL_GAP_WARN:
        return
    where = np.round(np.asarray(body.points(params)[0])[k] / (2.0 * case["radius"]), 3).tolist()
    warnings.warn(LayoutWarning(
        f"case.layout=\"cartesian\" with case.n_theta={case['n_theta']} and case.lattice_ratio="
        f"{show(case['lattice_ratio'])}: the first lattice row lies {gap[k]:.2f} spacings from the body on average "
        f"near {where} (in units of D; above {WALL_GAP_WARN:g}), and the wall pressure extrapolates across that gap "
        "(docs/validation.md, \"Bodies given by points\"); use case.layout=\"offset\" (rows along the body, the first "
        "half a spacing from it everywhere), or choose case.lattice_ratio so that flat faces lie half a spacing from "
        "a lattice row, or a finer lattice (n_theta / lattice_ratio >= 48)"), stacklevel=3)


class Cartesian:
    """A uniform square lattice with the body cut out (module docstring), Voronoi volumes."""

    @staticmethod
    def check(case: Mapping, support: Callable[[float], float]) -> list[str]:
        if case["n_theta"] / case["lattice_ratio"] < MIN_SPACINGS_AROUND:
            return [f"invalid case.lattice_ratio={case['lattice_ratio']!r} with case.n_theta={case['n_theta']}: "
                    f"{case['n_theta'] / case['lattice_ratio']:.3g} lattice spacings around the body, too coarse "
                    f"for it; allowed: case.n_theta / case.lattice_ratio >= {MIN_SPACINGS_AROUND} (lattice_ratio "
                    f"<= {case['n_theta'] / MIN_SPACINGS_AROUND:.4g})"]
        return _far_problems(case, lattice_spacing(case), support)

    @staticmethod
    def build(case: Mapping, body, params, support, names) -> BodyLayout:
        h = case["lattice_ratio"] * _perimeter(body, params) / case["n_theta"]
        cand, frozen = _lattice_candidates(h, case["r_far"], support)
        poly = body_polygon(body, params)
        out = ~inside_polygon(cand, poly)
        near = np.hypot(cand[:, 0], cand[:, 1]) < _body_extent(body, params) + 2.0 * h
        keep = out.copy()
        # (1 - 1e-9): a point exactly GAP h from the curve (a straight face half a spacing from a
        # lattice line, e.g. a square of side 2k h) is kept on every face alike, not by round-off
        keep[near] &= distance_to_polygon(cand[near], poly) >= GAP * h * (1.0 - 1e-9)
        x, vol, kind = _finish(cand[keep], frozen, h, body, params, "cartesian",
                                case["lattice_ratio"])
        _warn_wall_gap(case, body, params, x[kind == int(Kind.FLUID)], h)
        return BodyLayout(x, vol, kind, h, _fixed_positions(x, vol, body, "cartesian", params))

    @staticmethod
    def count(case: Mapping, support: Callable[[float], float]) -> tuple[int, tuple[str, ...]]:
        """The lattice over the disc of r_far plus the frozen reach, less the body's area (an
        equal-area radius for the ellipse)."""
        return (_lattice_count(case, lattice_spacing(case), body_area_radius(case), support),
                ("case.layout", "case.r_far", "case.lattice_ratio", "case.n_theta", "case.radius"))


class Blend:
    """Polar rings out to ``blend_radius``, the square lattice of the outermost ring's spacing
    beyond (module docstring), Voronoi volumes."""

    @staticmethod
    def check(case: Mapping, support: Callable[[float], float]) -> list[str]:
        rb, R, n = case["blend_radius"], case["radius"], case["n_theta"]
        inner = body_extent(case) * (1.0 + 2.0 * math.pi / n) ** 2
        if rb <= inner:
            return [f"invalid case.blend_radius={rb!r} with case.radius={R!r} and case.n_theta={n}: at or inside "
                    f"the body's first two rings (r = {inner:.4g}); allowed: case.blend_radius > {inner:.4g}"]
        h = blend_spacing(case)
        outer = case["r_far"] - 2.0 * h
        if rb >= outer:
            return [f"invalid case.blend_radius={rb!r} with case.r_far={case['r_far']!r}: at or outside the far "
                    f"field less two lattice spacings ({h:.4g} each); allowed: case.blend_radius < {outer:.4g}"]
        return _far_problems(case, h, support)

    @staticmethod
    def build(case: Mapping, body, params, support, names) -> BodyLayout:
        n_theta, edges = case["n_theta"], blend_edges(case)
        semi_axes, angle = body._axes(params)
        x_r, v_r = (np.asarray(a) for a in elliptic_polar_layout(edges, n_theta, params[body.key("centre")],
                                                                  semi_axes, angle))
        h = float(np.sqrt(np.mean(v_r[-n_theta:])))
        cand, frozen = _lattice_candidates(h, case["r_far"], support)
        # the outer edge of the rings (the mapped circle at the last edge) as a polygon
        ring_edge = _mapped_circle(edges[-1], edges[0], FINE * n_theta, params[body.key("centre")],
                                   np.asarray(semi_axes, float), float(angle))
        return _around(x_r, cand, ~inside_polygon(cand, ring_edge), frozen, h, body, params, case, "blend")

    @staticmethod
    def count(case: Mapping, support: Callable[[float], float]) -> tuple[int, tuple[str, ...]]:
        """n_theta x the rings to blend_radius, and the lattice beyond it (plus the frozen reach)."""
        rings = case["n_theta"] * (len(blend_edges(case)) - 1)
        rb = case["blend_radius"] * _ring_scale(case)
        return (rings + _lattice_count(case, blend_spacing(case), rb, support),
                ("case.layout", "case.r_far", "case.blend_radius", "case.n_theta", "case.radius"))


def _mapped_circle(r, r0, n, centre, semi_axes, angle):
    """The circle of radius ``r`` of the polar layout (body radius ``r0``) carried by the Joukowski
    map of :func:`~mlsph_jax.cases.layouts.elliptic_polar_layout`, turned by ``angle`` (the
    identity for a circle)."""
    a, b = semi_axes
    rho = 0.5 * (a + b) / r0 * r
    c2 = 0.25 * (a - b) * (a + b)
    t = 2.0 * math.pi * np.arange(n) / n
    zx, zy = (rho + c2 / rho) * np.cos(t), (rho - c2 / rho) * np.sin(t)
    ca, sa = math.cos(angle), math.sin(angle)
    c = np.asarray(centre, float)
    return np.stack([c[0] + ca * zx - sa * zy, c[1] + sa * zx + ca * zy], axis=1)


BODY_LAYOUTS.register("polar", Polar())
BODY_LAYOUTS.register("cartesian", Cartesian())
BODY_LAYOUTS.register("blend", Blend())


# --- the offset layout: rows along the body's offset curves, the lattice beyond (decision 105) --

#: ``offset``: the distance field whose level sets give the rows is sampled on a square grid of
#: OFFSET_GRID points per lattice spacing (a row point lies within ~(h / OFFSET_GRID)^2 curvature
#: of its offset distance; exact on straight faces).
OFFSET_GRID = 16


def _distance_field(poly: np.ndarray, h: float, reach: float):
    """The signed distance to the closed polygon ``poly`` (negative inside) on a square grid of
    spacing h / :data:`OFFSET_GRID` over the body's bounding box widened by ``reach``, its nodes at
    multiples of the spacing (so that a body symmetric about y = 0 gets a symmetric field): ``(gx,
    gy, Z)``.  The nearest of the edges' dense samples (spacing <= the grid step) picks an edge, and
    the distances to it and to its two neighbours are taken: exact unless two edges that are not
    neighbours are nearly equally near (then off by at most (step / 2)^2 / 2d, ~1e-3 h at the first
    row).  The inside test is matplotlib's (:class:`matplotlib.path.Path`), compiled: the grid has
    ~(16 x extent / h)^2 nodes."""
    step = h / OFFSET_GRID
    lo, hi = poly.min(axis=0) - reach, poly.max(axis=0) + reach
    axes = [step * np.arange(math.floor(lo[k] / step), math.ceil(hi[k] / step) + 1) for k in range(2)]
    X, Y = np.meshgrid(*axes, indexing="xy")
    g = np.stack([X.ravel(), Y.ravel()], axis=1)
    a, b = poly, np.roll(poly, -1, axis=0)
    pieces = np.maximum(1, np.ceil(np.linalg.norm(b - a, axis=1) / step).astype(int))
    edge = np.repeat(np.arange(len(poly)), pieces)
    t = np.concatenate([np.arange(n) / n for n in pieces])
    _, near = cKDTree(a[edge] + t[:, None] * (b - a)[edge]).query(g)
    dist = np.full(len(g), np.inf)
    for shift in (-1, 0, 1):                 # the nearest sample's edge and its two neighbours
        e = (edge[near] + shift) % len(poly)
        d = b[e] - a[e]
        s = np.clip(np.sum((g - a[e]) * d, axis=1) / np.sum(d * d, axis=1), 0.0, 1.0)
        dist = np.minimum(dist, np.hypot(*(g - a[e] - s[:, None] * d).T))
    inside = Path(poly).contains_points(g)
    return axes[0], axes[1], np.where(inside, -dist, dist).reshape(X.shape)


def _loop_from_front(loop: np.ndarray) -> np.ndarray:
    """A closed polyline (first point repeated at the end) turned counter-clockwise and started at
    its front crossing of the x axis (the crossing of least x; a vertex on the axis is a crossing),
    or, when it does not reach the axis, at its point of least x and, among those (a vertical side),
    of least |y|: a loop symmetric about y = 0, or a pair of loops mirroring each other, is then
    sampled symmetrically (arc length from mirrored starts, in either sense, gives mirrored points)."""
    pts = loop[:-1]
    if polygon_area(pts) < 0.0:
        pts = pts[::-1]
    nxt = np.roll(pts, -1, axis=0)
    y, yn = pts[:, 1], nxt[:, 1]
    cross = (y * yn < 0.0) | (y == 0.0)
    if not cross.any():
        tol = 1e-12 * float(np.max(np.abs(pts)))
        left = np.flatnonzero(pts[:, 0] <= pts[:, 0].min() + tol)
        k = int(left[np.argmin(np.abs(y[left]))])
        return np.concatenate([pts[k:], pts[:k + 1]])
    s = np.where(y == 0.0, 0.0, y / np.where(cross & (y != yn), y - yn, 1.0))
    xc = np.where(cross, pts[:, 0] + s * (nxt[:, 0] - pts[:, 0]), np.inf)
    k = int(np.argmin(xc))
    start = np.array([xc[k], 0.0])
    rest = np.concatenate([pts[k + 1:], pts[:k + 1]])
    if y[k] == 0.0:                           # the crossing is the vertex itself: not twice
        rest = rest[:-1]
    return np.concatenate([start[None], rest, start[None]])


def _resample(loop: np.ndarray, h: float) -> np.ndarray:
    """``round(L / h)`` (at least 1) points equally spaced by arc length along the closed polyline
    ``loop`` (first point repeated at the end), the first at its start."""
    seg = np.linalg.norm(np.diff(loop, axis=0), axis=1)
    loop = np.concatenate([loop[:1], loop[1:][seg > 0.0]])     # np.interp needs increasing s
    seg = seg[seg > 0.0]
    s = np.concatenate([[0.0], np.cumsum(seg)])
    n = max(1, round(s[-1] / h))
    q = s[-1] * np.arange(n) / n
    return np.stack([np.interp(q, s, loop[:, 0]), np.interp(q, s, loop[:, 1])], axis=1)


def _merge_crowded(points: np.ndarray, h: float) -> np.ndarray:
    """``points`` with every cluster of points closer than :data:`GAP` h to each other (connected
    components of that relation) replaced by its centroid, repeated until none are: the points of
    one row crowd where it turns through a kink sharper than 60 degrees (the distance to the body
    is 1-Lipschitz, so different rows stay h apart).  A centroid is mirror-equivariant, so a
    layout symmetric about the x axis stays so (dropping one point of a pair would not)."""
    while True:
        pairs = cKDTree(points).query_pairs(GAP * h * (1.0 - 1e-9), output_type="ndarray")
        if len(pairs) == 0:
            return points
        n = len(points)
        graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
        k, label = connected_components(graph, directed=False)
        merged = np.zeros((k, 2))
        np.add.at(merged, label, points)
        points = merged / np.bincount(label, minlength=k)[:, None]


def offset_rows(poly: np.ndarray, h: float, rows: int) -> np.ndarray:
    """The particles of the ``offset`` layout's rows: row m = 0 .. ``rows`` - 1 lies on the level
    set (m + 1/2) h of the distance to the body polygon ``poly`` (each of its closed loops: the
    outer one and any closed off in a concave pocket), ``round(length / h)`` points per loop equally
    spaced by arc length from the loop's front crossing of the x axis (:func:`_loop_from_front`);
    points closer than :data:`GAP` h to each other are merged (:func:`_merge_crowded`)."""
    gx, gy, Z = _distance_field(poly, h, (rows + 1) * h)
    gen = contourpy.contour_generator(gx, gy, Z, line_type="Separate")
    out = []
    for m in range(rows):
        for loop in gen.lines((m + 0.5) * h):
            out.append(_resample(_loop_from_front(np.asarray(loop, float)), h))
    return _merge_crowded(np.concatenate(out), h)


class Offset:
    """``case.offset_rows`` rows along the body's offset curves at (m + 1/2) h, the square lattice of
    spacing h beyond (module docstring), Voronoi volumes: the first row lies h/2 from the wall all
    along any body, a lattice's cut-out leaves h/2 to 3h/2."""

    @staticmethod
    def check(case: Mapping, support: Callable[[float], float]) -> list[str]:
        problems = Cartesian.check(case, support)
        if problems:
            return problems
        h, rows = lattice_spacing(case), case["offset_rows"]
        need = body_extent(case) + (rows + GAP) * h + support(h) + h
        if case["r_far"] <= need:
            most = math.ceil((case["r_far"] - (need - rows * h)) / h) - 1
            fewer = f"case.offset_rows <= {most}" if most >= 1 else "a larger case.r_far"
            return [f"invalid case.offset_rows={rows} with case.r_far={show(case['r_far'])} (lattice spacing "
                    f"{h:.4g}): the rows reach into the support of the far field (out to r = {need:.4g}); allowed: "
                    f"case.r_far > {need:.4g} or {fewer}"]
        return []

    @staticmethod
    def build(case: Mapping, body, params, support, names) -> BodyLayout:
        h = case["lattice_ratio"] * _perimeter(body, params) / case["n_theta"]
        rows, poly = case["offset_rows"], body_polygon(body, params)
        x_r = offset_rows(poly, h, rows)
        cand, frozen = _lattice_candidates(h, case["r_far"], support)
        near = np.hypot(cand[:, 0], cand[:, 1]) < _body_extent(body, params) + (rows + 2.0) * h
        keep = np.ones(len(cand), bool)
        keep[near] = ~inside_polygon(cand[near], poly)
        keep[near] &= distance_to_polygon(cand[near], poly) >= rows * h
        return _around(x_r, cand, keep, frozen, h, body, params, case, "offset")

    #: the rows hold one particle per h^2 as the lattice does: the cartesian layout's count
    count = staticmethod(Cartesian.count)


BODY_LAYOUTS.register("offset", Offset())


# --- the graded wake layout (decision 90) ------------------------------------------------------

#: The graded layout keeps the polar rings 0 .. KEEP_RINGS - 1 next to the body whatever the wake
#: spacing (the wall terms and the body's quadrature see the polar layout there).
KEEP_RINGS = 2
#: Relaxation of the wake cloud: iterations, step (fraction of the bar force) and the bar
#: over-length factor that keeps every bar in compression (so the points spread over the region).
RELAX_STEPS, RELAX_DT, RELAX_FSCALE = 120, 0.2, 1.2
#: Cloud points closer than CLOSE x the target spacing to another particle after the relaxation
#: are dropped.
CLOSE = 0.5
#: The seed of the cloud's initial sampling (the layout is deterministic).
CLOUD_SEED = 0


def _ring_spacing_ratio(q: float, n_theta: int) -> float:
    """sqrt(V) / r_c of a polar ring particle (rings r_k = R q^k, centres r_c = (r_k + r_k+1) / 2):
    sqrt(2 (q - 1) dtheta / (q + 1)), the same on every ring."""
    return math.sqrt(2.0 * (q - 1.0) * (2.0 * math.pi / n_theta) / (q + 1.0))


def wake_target(case: Mapping, x: np.ndarray) -> np.ndarray:
    """The graded layout's wake spacing h_w(x) = D (``wake_spacing`` + ``wake_grading`` d / D), d
    the distance of x from the wake-axis segment from the body's rear (x = R) to x = ``wake_length``
    D, y = 0: linear in the distance, so neighbouring spacings differ by the factor ~1 +
    ``wake_grading`` at most."""
    R = case["radius"]
    D = 2.0 * R
    px = np.clip(x[:, 0], R, case["wake_length"] * D)
    d = np.hypot(x[:, 0] - px, x[:, 1])
    return D * case["wake_spacing"] + case["wake_grading"] * d


def _graded_cells(case: Mapping, names):
    """The polar rings and the mask of the ring particles the wake cloud replaces: those (beyond
    the first :data:`KEEP_RINGS` rings) whose wake spacing is below their ring spacing.
    Returns ``(edges, q, x_polar, vol_polar, ring, ray, removed)`` of the fluid rings."""
    R, n = case["radius"], case["n_theta"]
    lay = polar_layout(R, n, case["r_far"], 0, names=names)
    c_p = _ring_spacing_ratio(float(lay.edges[1] / lay.edges[0]), n)
    r = np.hypot(lay.x[:, 0], lay.x[:, 1])
    n_rings = len(lay.edges) - 1
    removed = (lay.ring >= KEEP_RINGS) & (lay.ring < n_rings - 2) & (wake_target(case, lay.x) < c_p * r)
    ray = np.tile(np.arange(n), len(lay.edges) - 1)
    return lay.edges, float(lay.edges[1] / lay.edges[0]), lay.x, lay.vol, lay.ring, ray, removed


def _in_cells(x, R, q, n_theta, removed_grid) -> np.ndarray:
    """Whether each point lies in a removed polar cell (``removed_grid[ring, ray]``)."""
    r = np.hypot(x[:, 0], x[:, 1])
    k = np.floor(np.log(np.maximum(r, 1e-300) / R) / math.log(q)).astype(int)
    j = np.floor(np.mod(np.arctan2(x[:, 1], x[:, 0]), 2.0 * math.pi) / (2.0 * math.pi / n_theta)).astype(int) % n_theta
    ok = (k >= 0) & (k < removed_grid.shape[0])
    out = np.zeros(len(x), bool)
    out[ok] = removed_grid[k[ok], j[ok]]
    return out


def _cloud_spacing(case, x, c_p):
    """Target spacing of the cloud: the finer of the wake spacing and the rings' spacing at r."""
    return np.minimum(wake_target(case, x), c_p * np.hypot(x[:, 0], x[:, 1]))


def _sample_cloud(case, edges, q, xr, ring, ray, removed) -> tuple[np.ndarray, np.ndarray]:
    """Initial cloud points in the removed cells, density 1 / h^2 (expected count the integral of
    dA / h^2), by thinning a fine hexagonal lattice with a seeded generator; and the removed-cell
    grid."""
    R, n = case["radius"], case["n_theta"]
    c_p = _ring_spacing_ratio(q, n)
    grid = np.zeros((len(edges) - 1, n), bool)
    grid[ring[removed], ray[removed]] = True
    kmax = int(ring[removed].max()) + 1
    reach = float(edges[kmax])
    sub = xr[removed]
    lo, hi = sub.min(axis=0) - 2.0 * c_p * reach, sub.max(axis=0) + 2.0 * c_p * reach
    lo, hi = np.maximum(lo, -reach), np.minimum(hi, reach)
    a = float(_cloud_spacing(case, sub, c_p).min()) / 1.5
    nx, ny = int((hi[0] - lo[0]) / a) + 1, int((hi[1] - lo[1]) / (a * math.sqrt(0.75))) + 1
    ix, iy = np.meshgrid(np.arange(nx), np.arange(ny), indexing="xy")
    cand = np.stack([lo[0] + a * (ix + 0.5 * (iy % 2)), lo[1] + a * math.sqrt(0.75) * iy], axis=-1).reshape(-1, 2)
    cand = cand[_in_cells(cand, R, q, n, grid)]
    p_keep = math.sqrt(0.75) * a * a / _cloud_spacing(case, cand, c_p) ** 2
    rng = np.random.default_rng(CLOUD_SEED)
    return cand[rng.random(len(cand)) < p_keep], grid


def _relax_cloud(case, moving, fixed, q, grid) -> np.ndarray:
    """Spread the cloud points by a bar-force relaxation over the Delaunay triangulation of cloud
    and ring points (a compressed spring on every edge with a cloud end, rest length proportional
    to the target spacing at its midpoint; ring points fixed; a cloud point that would leave the
    removed cells stays where it was)."""
    from scipy.spatial import Delaunay

    R, n = case["radius"], case["n_theta"]
    c_p = _ring_spacing_ratio(q, n)
    nm = len(moving)
    p = np.concatenate([moving, fixed])
    for _ in range(RELAX_STEPS):
        tri = Delaunay(p).simplices
        e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
        e = np.unique(np.sort(e, axis=1), axis=0)
        e = e[(e[:, 0] < nm) | (e[:, 1] < nm)]
        v = p[e[:, 1]] - p[e[:, 0]]
        L = np.hypot(v[:, 0], v[:, 1])
        hb = _cloud_spacing(case, 0.5 * (p[e[:, 0]] + p[e[:, 1]]), c_p)
        L0 = hb * RELAX_FSCALE * math.sqrt(np.sum(L * L) / np.sum(hb * hb))
        f = (np.maximum(L0 - L, 0.0) / L)[:, None] * v
        force = np.zeros_like(p)
        np.add.at(force, e[:, 0], -f)
        np.add.at(force, e[:, 1], f)
        trial = p[:nm] + RELAX_DT * force[:nm]
        ok = _in_cells(trial, R, q, n, grid)
        p[:nm] = np.where(ok[:, None], trial, p[:nm])
    return p[:nm]


class Graded:
    """The polar layout with the ring particles of the wake replaced by a cloud whose spacing grades
    smoothly from ``wake_spacing`` D on the wake axis (decision 90), Voronoi volumes."""

    @staticmethod
    def check(case: Mapping, support: Callable[[float], float]) -> list[str]:
        problems = []
        if case["body"] != "circle":
            problems.append(f"invalid case.body={case['body']!r} with case.layout=\"graded\": the wake cloud is "
                            "placed around a circle's rings; allowed: case.body=\"circle\" (or another layout)")
            return problems
        names = ("case.radius", "case.n_theta", "case.r_far")
        edges, q = polar_ring_edges(case["radius"], case["n_theta"], case["r_far"], names=names)
        c_p = _ring_spacing_ratio(q, case["n_theta"])
        if case["wake_grading"] <= c_p:
            problems.append(f"invalid case.wake_grading={case['wake_grading']!r} with case.n_theta="
                            f"{case['n_theta']}: the wake spacing must grow faster with the distance from the "
                            f"axis than the rings' spacing grows with r ({c_p:.4g}), or the refined region never "
                            f"ends; allowed: {c_p:.4g} < case.wake_grading <= 0.3")
            return problems
        D = 2.0 * case["radius"]
        # the refined region ends where h_w = c_p r, farthest on the axis beyond the segment's end,
        # at x* = (g L - h0) / (g - c_p); it must stay inside the last two fluid rings (which the
        # frozen rings' support reaches)
        g, L, h0 = case["wake_grading"], case["wake_length"] * D, case["wake_spacing"] * D
        x_end = (g * L - h0) / (g - c_p)
        limit = edges[-3]
        if x_end >= limit:
            problems.append(f"invalid case.wake_length={case['wake_length']!r} with case.wake_grading={g!r}, "
                            f"case.wake_spacing={case['wake_spacing']!r} and case.r_far={case['r_far']!r}: the "
                            f"refined wake reaches r = {x_end:.4g}, into the last two fluid rings next to the far "
                            f"field (r >= {limit:.4g}); allowed: a shorter case.wake_length, a larger "
                            "case.wake_grading or case.r_far")
        first = case["radius"] * c_p * (1.0 + q) / 2.0
        if h0 < first:
            problems.append(f"invalid case.wake_spacing={case['wake_spacing']!r}: finer than the first ring's "
                            f"spacing ({first / D:.4g} D), the cloud would be finer than the rings next to the "
                            f"body; allowed: case.wake_spacing >= {first / D:.4g}")
        if not problems and not _graded_cells(case, names)[-1].any():
            problems.append(f"invalid case.wake_spacing={case['wake_spacing']!r} with case.wake_length="
                            f"{case['wake_length']!r} and case.wake_grading={g!r}: no ring particle is coarser "
                            "than the wake spacing there, so the layout would be the polar one; allowed: a "
                            "finer case.wake_spacing or a longer case.wake_length (or case.layout=\"polar\")")
        return problems

    @staticmethod
    def build(case: Mapping, body, params, support, names) -> BodyLayout:
        R, n = case["radius"], case["n_theta"]
        edges, q, xr, vr, ring, ray, removed = _graded_cells(case, names)
        cloud0, grid = _sample_cloud(case, edges, q, xr, ring, ray, removed)
        kept = xr[~removed]
        near = np.hypot(kept[:, 0], kept[:, 1]) < edges[int(ring[removed].max()) + 1] * q ** 2
        cloud = _relax_cloud(case, cloud0, kept[near], q, grid)
        c_p = _ring_spacing_ratio(q, n)
        # drop cloud points too close to another particle (the relaxation leaves a few at the
        # region's edge), the closest first
        hc = _cloud_spacing(case, cloud, c_p)
        keep = cKDTree(kept).query(cloud)[0] >= CLOSE * hc
        for i, j in sorted(cKDTree(cloud).query_pairs(CLOSE * float(hc.max()))):
            if keep[i] and keep[j] and np.hypot(*(cloud[i] - cloud[j])) < CLOSE * min(hc[i], hc[j]):
                keep[j if hc[j] >= hc[i] else i] = False
        fluid = np.concatenate([kept, cloud[keep]])
        n_far = far_rings(case, support, names)
        lay_all = polar_layout(R, n, case["r_far"], n_far, names=names)
        n_fluid_rings = len(edges) - 1
        frozen = lay_all.ring >= n_fluid_rings
        pts = np.concatenate([fluid, lay_all.x[frozen]])
        poly = body_polygon(body, params)
        vf = voronoi_volumes(pts, len(fluid), poly)
        worst = spacing_ratio(body, params, fluid, vf)
        if worst > 1.0 + 1e-9:
            raise InputError(f"invalid case.n_theta={n!r} with case.layout=\"graded\": the body's quadrature pieces "
                             f"are up to {worst:.3g} spacings sqrt(V) of the nearest particle long; allowed: at most "
                             "1 spacing, a larger case.n_theta or case.layout=\"polar\"")
        vol = np.concatenate([vf, lay_all.vol[frozen]])
        kind = np.concatenate([np.full(len(fluid), int(Kind.FLUID)), np.full(int(frozen.sum()), int(Kind.FROZEN))])
        h = 2.0 * R * case["wake_spacing"]
        return BodyLayout(pts, vol, kind, h, _fixed_positions(pts, vol, body, "graded", params))

    @staticmethod
    def count(case: Mapping, support: Callable[[float], float]) -> tuple[int, tuple[str, ...]]:
        """The kept ring particles, the frozen rings and the cloud's expected count (the integral
        of dA / h^2 over the replaced cells, by their sector areas and the spacing at their
        centres: within a few per cent)."""
        names = ("case.radius", "case.n_theta", "case.r_far")
        edges, q, xr, vr, ring, ray, removed = _graded_cells(case, names)
        c_p = _ring_spacing_ratio(q, case["n_theta"])
        cloud = float(np.sum(vr[removed] / _cloud_spacing(case, xr[removed], c_p) ** 2))
        frozen = case["n_theta"] * far_rings(case, support, names)
        return (int((~removed).sum()) + round(cloud) + frozen,
                ("case.layout", "case.r_far", "case.n_theta", "case.radius", "case.wake_spacing",
                 "case.wake_length", "case.wake_grading"))


BODY_LAYOUTS.register("graded", Graded())
