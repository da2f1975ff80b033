"""Set-up checks of boundary geometry (host side; every failure an :class:`InputError` naming
the key and the value), and the point tests shared with the in-run wall-crossing check.

* a closed curve must not intersect itself (``geometry.<name>``);
* curves must not cross or contain each other (segments may touch at their end points, e.g. the
  corners of a box), and closed bodies must lie strictly inside the domain box;
* no fluid particle may be inside a body (outside a container) or beyond a wall segment;
* particles must not be neighbours through a body: the way around it between them
  (:func:`detour_around_polygon`) must stay within their support (a body thinner than the
  support would let fluxes cross it; checked by the cases that build bodies);
* the quadrature must resolve the particles: dGamma_b <= ``max_spacing_ratio`` times the local
  particle spacing V^(1/d) of the fluid particle nearest to x_b (the thesis' cylinder has 120
  wall points for 120 particles on the first ring, ratio 1);
* when a run is set up (:func:`mlsph_jax.run.setup_run`, every run path; the problem's Params,
  not Params given later to a differentiated run's function): walls stay where they were set
  up, so a wall velocity must be finite and tangential to its wall, |u_w . n| <= :data:`WALL_MOTION_RTOL`
  times the largest wall speed (:func:`normal_wall_motion`); a velocity across the wall would move
  it through the particles.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError
from ..state import Kind, Params

#: Largest wall-normal velocity, relative to the largest wall speed, that a run accepts as tangential
WALL_MOTION_RTOL = 1e-9


def normal_wall_motion(velocity, normal):
    """Index of the wall point whose velocity crosses its wall most, and that normal component
    (NaN for a non-finite velocity, which is always refused), or None when every |u_b . n_b| <=
    WALL_MOTION_RTOL max_b |u_b| (tangential motion only: a segment sliding along itself, a circle
    turning about its centre).  Host side; give float64 velocities and normals (float32 round-off
    of a turning circle is ~1e-8 of its speed)."""
    v, n = np.asarray(velocity, float), np.asarray(normal, float)
    if v.size == 0:
        return None
    bad = ~np.all(np.isfinite(v), axis=-1)
    if bad.any():
        return int(np.argmax(bad)), float("nan")
    vn = np.sum(v * n, axis=-1)
    speed = float(np.max(np.linalg.norm(v, axis=-1)))
    b = int(np.argmax(np.abs(vn)))
    if abs(vn[b]) <= WALL_MOTION_RTOL * speed:
        return None
    return b, float(vn[b])


def wall_motion_problem(vn: float) -> str:
    """The phrase of a refused wall velocity (:func:`normal_wall_motion`'s normal component)."""
    if not math.isfinite(vn):
        return "has a non-finite velocity"
    return f"moves across itself (normal velocity {vn:.6g})"


def cross2(a, b):
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def inside_polygon(p, poly, xp=np):
    """Even-odd test: whether each point ``p[N, 2]`` is inside the closed polygon ``poly[M, 2]``
    (``xp``: numpy or jax.numpy)."""
    a, b = poly, xp.roll(poly, -1, axis=0)
    y = p[:, None, 1]
    straddle = (a[None, :, 1] > y) != (b[None, :, 1] > y)
    dy = b[:, 1] - a[:, 1]
    xc = a[None, :, 0] + (y - a[None, :, 1]) * (b[:, 0] - a[:, 0])[None] / xp.where(dy == 0, 1.0, dy)[None]
    hits = straddle & (p[:, None, 0] < xc)
    return (xp.sum(hits, axis=1) % 2) == 1


def beyond_segment(p, a, b, band, xp=np):
    """Whether each point ``p[N, 2]`` lies on the wall side (right of a -> b) of the segment,
    within its span and closer than ``band`` to its line."""
    t = b - a
    length = xp.sqrt(xp.sum(t * t))
    u = xp.sum((p - a) * t, axis=-1) / (length * length)
    depth = -cross2(t, p - a) / length            # > 0: right of a -> b, i.e. beyond the wall
    return (u >= 0) & (u <= 1) & (depth >= 0) & (depth < band)


def _edges(poly, closed):
    a = poly if closed else poly[:-1]
    b = np.roll(poly, -1, axis=0) if closed else poly[1:]
    return a, b


def _orientations(a1, b1, a2, b2):
    """The four orientation products [M1, M2] of the segment pairs (a1, b1), (a2, b2): the sides
    of a2 and b2 seen along segment 1, and of a1 and b1 along segment 2."""
    d1, d2 = b1 - a1, b2 - a2
    return (cross2(d1[:, None], a2[None] - a1[:, None]), cross2(d1[:, None], b2[None] - a1[:, None]),
            cross2(d2[None], a1[:, None] - a2[None]), cross2(d2[None], b1[:, None] - a2[None]))


def _crossings(a1, b1, a2, b2):
    """Proper crossings [M1, M2] of the segments (a1, b1) and (a2, b2) (touching is not one)."""
    o1, o2, o3, o4 = _orientations(a1, b1, a2, b2)
    return (o1 * o2 < 0) & (o3 * o4 < 0)


def detour_around_polygon(poly: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``[K]``: the length of the way from ``a[k]`` to ``b[k]`` around the closed polygon
    ``poly[m, 2]`` where the straight segment passes through it: the segment's proper crossings of
    the edges sorted along it pair up as (in, out) (both ends outside), and each piece inside is
    replaced by the polygon's boundary between its two crossings, the shorter way (an upper bound
    of the shortest path in the fluid); |b - a| for a segment that crosses no edge properly (also
    one that only touches a vertex).  A segment clipping a convex corner gets a detour barely
    longer than itself; one through a plate a detour around its end.  Set-up only (numpy, in
    chunks of ~1e6 pair tests; a Python loop over the few segments that cross)."""
    pa, pb = _edges(poly, True)
    e = pb - pa
    lengths = np.linalg.norm(e, axis=1)
    start = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
    perimeter = float(lengths.sum())
    seg = np.linalg.norm(b - a, axis=1)
    out = seg.copy()
    step = max(1, (1 << 20) // max(len(pa), 1))
    for s in range(0, len(a), step):
        a1, b1 = a[s:s + step], b[s:s + step]
        hit = _crossings(a1, b1, pa, pb)
        for r in np.flatnonzero(hit.any(axis=1)):
            k = np.flatnonzero(hit[r])
            d = b1[r] - a1[r]
            denom = cross2(d[None], e[k])
            w = pa[k] - a1[r]
            t = cross2(w, e[k]) / denom                                   # along the segment
            u = cross2(w, d[None]) / denom                                # along each edge
            order = np.argsort(t)
            t, pos = t[order], (start[k] + u * lengths[k])[order]
            if len(t) % 2:              # a vertex hit left one crossing unpaired: no detour known
                continue
            arc = np.abs(pos[1::2] - pos[0::2])
            inside = np.sum(t[1::2] - t[0::2])
            out[s + r] = seg[s + r] * (1.0 - inside) + np.sum(np.minimum(arc, perimeter - arc))
    return out


def self_crossing(poly: np.ndarray, touching: bool = False) -> tuple[int, int] | None:
    """The first pair of non-adjacent edges (i, j) of the closed polygon ``poly[m, 2]`` that cross
    each other properly, or None for a simple polygon.  ``touching``: also edges that touch or
    overlap (a pinch through a shared point, a vertex on another edge) and adjacent edges that turn
    back onto each other (a spike of zero width), i.e. any polygon that is not simple."""
    a, b = _edges(poly, True)
    m = len(a)
    i, j = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
    apart = (np.abs(i - j) > 1) & (np.abs(i - j) < m - 1)
    hit = _crossings(a, b, a, b) if not touching else _touches(a, b)
    hit &= apart
    if touching:
        d = b - a
        nxt = np.roll(np.arange(m), -1)
        back = (np.abs(cross2(d, d[nxt])) <= 1e-12 * np.sum(d * d, axis=1)) & (np.sum(d * d[nxt], axis=1) < 0)
        hit[np.flatnonzero(back), nxt[back]] = True
    if not hit.any():
        return None
    k = np.argwhere(hit)[0]
    return int(k[0]), int(k[1])


def _touches(a, b):
    """[M, M]: whether the closed segments (a_i, b_i) and (a_j, b_j) share any point."""
    d = b - a
    o1, o2, o3, o4 = _orientations(a, b, a, b)
    scale = 1e-12 * np.max(np.sum(d * d, axis=1))
    z1, z2, z3, z4 = (np.abs(o) <= scale for o in (o1, o2, o3, o4))
    proper = (o1 * o2 < 0) & (o3 * o4 < 0)

    def on(p, q0, q1):     # p on the segment q0 -> q1, given that the three are collinear
        lo, hi = np.minimum(q0, q1), np.maximum(q0, q1)
        return np.all((p >= lo - 1e-12) & (p <= hi + 1e-12), axis=-1)

    A, B = a[:, None], b[:, None]          # segment i
    C, D = a[None], b[None]                # segment j
    return (proper | (z1 & on(C, A, B)) | (z2 & on(D, A, B)) | (z3 & on(A, C, D)) | (z4 & on(B, C, D)))


def outline(curve, params: Params) -> np.ndarray:
    """The polygon used by the checks: a segment's end points, a polygon's vertices, else the
    quadrature points (in order)."""
    if not curve.closed:
        return np.asarray([params[curve.key("start")], params[curve.key("end")]], float)
    if curve.key("vertices") in params:
        return np.asarray(params[curve.key("vertices")], float)
    return np.asarray(curve.points(params)[0], float)


def check_geometry(curves, params: Params, x, vol, kind=None, domain=None, max_spacing_ratio: float = 1.0) -> None:
    """Refuse bad geometry (module docstring); ``x``, ``vol``, ``kind``: the particles (only fluid
    particles are tested), ``domain``: the :class:`~mlsph_jax.state.Domain` (closed bodies must lie
    strictly inside its box)."""
    x, vol = np.asarray(x, float), np.asarray(vol, float)
    fluid = np.ones(len(x), bool) if kind is None else np.asarray(kind) == int(Kind.FLUID)
    xf, vf = x[fluid], vol[fluid]
    outl = [outline(c, params) for c in curves]
    for c, poly in zip(curves, outl, strict=True):
        if c.closed:
            k = self_crossing(poly)
            if k is not None:
                raise InputError(f"invalid geometry.{c.name}: the curve intersects itself (edges {k[0]} and {k[1]} "
                                 f"cross near x={np.round(poly[k[0]], 6).tolist()}); allowed: a simple closed curve")
        if domain is not None and c.closed:
            lo, hi = np.asarray(domain.lower), np.asarray(domain.upper)
            out = np.any((poly <= lo) | (poly >= hi), axis=1)
            if out.any():
                p = poly[np.argmax(out)]
                raise InputError(f"invalid geometry.{c.name}: the body reaches x={np.round(p, 6).tolist()} on or "
                                 f"beyond the domain edge (box {list(domain.lower)} .. {list(domain.upper)}); "
                                 "allowed: closed bodies strictly inside the domain")
    for ia in range(len(curves)):
        for ib in range(ia + 1, len(curves)):
            ca, cb = curves[ia], curves[ib]
            hit = _crossings(*_edges(outl[ia], ca.closed), *_edges(outl[ib], cb.closed))
            nested = ((ca.closed and inside_polygon(outl[ib][:1], outl[ia])[0])
                      or (cb.closed and inside_polygon(outl[ia][:1], outl[ib])[0]))
            if hit.any() or nested:
                raise InputError(f"invalid geometry.{cb.name}: it overlaps geometry.{ca.name}; allowed: curves that "
                                 "neither cross nor contain each other (segments may share end points)")
    for c, poly in zip(curves, outl, strict=True):
        if c.closed:
            inside = inside_polygon(xf, poly)
            bad = inside if c.fluid == "outside" else ~inside
            what = "inside the body" if c.fluid == "outside" else "outside the container"
        else:
            band = np.inf
            bad = beyond_segment(xf, poly[0], poly[1], band)
            what = "beyond the wall"
        if bad.any():
            i = int(np.flatnonzero(fluid)[np.argmax(bad)])
            raise InputError(f"invalid particle layout: fluid particle {i} at x={np.round(x[i], 6).tolist()} is {what} "
                             f"geometry.{c.name} ({int(bad.sum())} particles); allowed: fluid particles on the fluid "
                             "side only")
    _check_spacing(curves, params, xf, vf, max_spacing_ratio)


def spacing_ratio(curve, params, xf, vf) -> float:
    """The largest dGamma_b / V^(1/d) of the fluid particle nearest to x_b over the curve's
    quadrature points (the quadrature resolves the particles when it is <= 1)."""
    d = xf.shape[1]
    xb, dg = (np.asarray(a) for a in curve.points(params)[:2])
    r2 = np.sum((xb[:, None, :] - xf[None]) ** 2, axis=-1)
    return float((dg / vf[np.argmin(r2, axis=1)] ** (1.0 / d)).max())


def _check_spacing(curves, params, xf, vf, ratio_max):
    for c in curves:
        worst = spacing_ratio(c, params, xf, vf)
        if worst > ratio_max * (1 + 1e-9):
            if hasattr(c, "spacing"):
                raise InputError(f"invalid geometry.{c.name}.spacing={c.spacing!r}: quadrature pieces up to "
                                 f"{worst:.3g} particle spacings long; allowed: at most {ratio_max:g} (spacing <= "
                                 f"{c.spacing * ratio_max / worst:.4g})")
            need = int(math.ceil(c.n_points * worst / ratio_max))
            raise InputError(f"invalid geometry.{c.name}.n_points={c.n_points}: quadrature pieces up to {worst:.3g} "
                             f"particle spacings long, too sparse for the particles; allowed: at most {ratio_max:g} "
                             f"spacings (n_points >= {need})")
