"""Particle layouts: a disc for the 2-D blast explosion (SPEC §12.1 V3) and a body-fitted polar
layout around a circular body (SPEC §12.2 V9, :func:`polar_layout`).

Thesis §3.7.2 ("2D Blast Explosion", Fig. 3.5) runs the cylindrical Tait shock tube on a disc of
radius ``R = 0.1`` m with three initial particle layouts, to show that the scheme keeps the radial
symmetry whatever the particle arrangement:

* ``"rings"`` — :func:`rings`: concentric rings of particles (the thesis' "radial distribution",
  ~90,000 particles);
* ``"delaunay"`` — :func:`delaunay_barycentres`: particles at the barycentres of the triangles of a
  Delaunay triangulation of the disc (~75,000 particles);
* ``"perturbed"`` — :func:`perturbed_barycentres`: the Delaunay barycentres with a random
  displacement (the thesis' "Random distribution", ~75,000 particles).

The thesis does not give the meshes, only the particle counts; the constructions below are our
own.  Every function returns ``(x, vol)``: positions ``x[N, 2]`` and particle volumes ``vol[N]``
(float64 numpy arrays, host-side set-up code), with ``vol`` a partition of the disc (rings: exactly
``pi R^2``; triangle barycentres: the inscribed polygon, ``pi R^2 (1 - O(dx^2/R^2))``).

Particle counts (``N dx^2 / (pi R^2)``, measured for ``R = 0.1``; see the report in the tests):

* rings: ``N = sum_k round(2 pi (k + 1/2)) ~= pi n_r^2`` with ``n_r = round(R/dx)`` rings, i.e.
  ratio 1.00;
* Delaunay / perturbed: the vertex lattice spacing is :data:`DELAUNAY_SPACING` ``* dx``, chosen so
  that one triangle covers about ``dx^2``: ratio ~1.00 (within 2 % for ``dx <= R/25``).

So ``N ~= pi R^2 / dx^2`` for all layouts: the thesis counts correspond to ``dx ~= 5.9e-4`` m
(rings, ~90,000) and ``dx ~= 6.5e-4`` m (Delaunay, ~75,000) for ``R = 0.1`` m.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from scipy.spatial import Delaunay

from ..errors import invalid

__all__ = ["DELAUNAY_SPACING", "LAYOUTS", "PolarLayout", "delaunay_barycentres", "disc_layout",
           "perturbed_barycentres", "polar_layout", "polar_ring_edges", "rings"]

#: Vertex spacing ``h / dx`` of the Delaunay layouts.  An equilateral triangle of side ``h`` has
#: area ``sqrt(3)/4 h^2``; ``h = (4/sqrt(3))^(1/2) dx`` makes it ``dx^2`` (one particle per
#: ``dx^2`` as for the rings).
DELAUNAY_SPACING = math.sqrt(4.0 / math.sqrt(3.0))

#: Random displacement of the Delaunay vertices, as a fraction of the lattice spacing ``h``.
_VERTEX_JITTER = 0.15
#: Lattice vertices closer than this fraction of ``h`` to the circle are dropped (the boundary
#: vertices on ``r = R`` take their place), which keeps the boundary triangles well shaped.
_BOUNDARY_BAND = 0.6


def _check_disc(radius, dx) -> tuple[float, float]:
    try:
        r = float(radius)
    except (TypeError, ValueError):
        raise invalid("radius", radius, "a finite disc radius > 0") from None
    if not (math.isfinite(r) and r > 0.0):
        raise invalid("radius", radius, "a finite disc radius > 0")
    try:
        h = float(dx)
    except (TypeError, ValueError):
        raise invalid("dx", dx, f"a finite particle spacing with 0 < dx < radius={r!r}") from None
    if not (math.isfinite(h) and 0.0 < h < r):
        raise invalid("dx", dx, f"a finite particle spacing with 0 < dx < radius={r!r}")
    return r, h


def _check_seed(seed) -> int:
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise invalid("seed", seed, "an integer >= 0")
    return int(seed)


def rings(radius: float, dx: float) -> tuple[np.ndarray, np.ndarray]:
    """Concentric rings of particles filling a disc (thesis §3.7.2, "radial distribution").

    The disc is cut into ``n_r = round(radius/dx)`` annuli of width ``dr = radius/n_r``; ring
    ``k`` sits at ``r_k = (k + 1/2) dr`` and carries ``n_k = max(1, round(2 pi r_k / dr))``
    particles equally spaced in angle, every other ring rotated by half an angular step.  Each
    particle gets the annulus area divided by ``n_k``, so the volumes sum to ``pi radius^2``
    (to rounding).  ``N = sum_k n_k ~= pi n_r^2``.

    Returns ``(x[N, 2], vol[N])``.
    """
    radius, dx = _check_disc(radius, dx)
    n_r = max(1, round(radius / dx))
    dr = radius / n_r
    k = np.arange(n_r)
    r_k = (k + 0.5) * dr
    n_k = ring_sizes(k)
    # annulus k: pi ((k+1)^2 - k^2) dr^2 = pi (2k+1) dr^2
    annulus = np.pi * (2.0 * k + 1.0) * dr * dr
    ring = np.repeat(k, n_k)
    start = np.concatenate([[0], np.cumsum(n_k)[:-1]])
    j = np.arange(ring.size) - start[ring]
    theta = 2.0 * np.pi * (j + 0.5 * (ring % 2)) / n_k[ring]
    x = np.stack([r_k[ring] * np.cos(theta), r_k[ring] * np.sin(theta)], axis=1)
    vol = (annulus / n_k)[ring]
    return x, vol


def ring_sizes(k) -> np.ndarray:
    """Particles on ring ``k`` (array) of the :func:`rings` layout: max(1, round(2 pi (k + 1/2)))."""
    return np.maximum(1, np.rint(2.0 * np.pi * (np.asarray(k) + 0.5)).astype(np.int64))


def _disc_vertices(radius: float, dx: float, seed: int) -> np.ndarray:
    """Jittered hexagonal lattice clipped to the disc, plus equally spaced vertices on ``r = R``."""
    h = DELAUNAY_SPACING * dx
    dy = 0.5 * math.sqrt(3.0) * h
    ni = int(math.ceil(radius / h)) + 1
    nj = int(math.ceil(radius / dy)) + 1
    i, j = np.meshgrid(np.arange(-ni, ni + 1), np.arange(-nj, nj + 1), indexing="ij")
    i, j = i.ravel(), j.ravel()
    lattice = np.stack([(i + 0.5 * (j % 2)) * h, j * dy], axis=1)
    rng = np.random.default_rng([seed, 0x5E1])
    a = _VERTEX_JITTER * h * np.sqrt(rng.random(len(lattice)))
    phi = 2.0 * np.pi * rng.random(len(lattice))
    lattice += np.stack([a * np.cos(phi), a * np.sin(phi)], axis=1)
    lattice = lattice[np.hypot(lattice[:, 0], lattice[:, 1]) < radius - _BOUNDARY_BAND * h]
    n_b = max(8, round(2.0 * np.pi * radius / h))
    phi_b = 2.0 * np.pi * np.arange(n_b) / n_b
    boundary = radius * np.stack([np.cos(phi_b), np.sin(phi_b)], axis=1)
    return np.concatenate([lattice, boundary])


def delaunay_barycentres(radius: float, dx: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Particles at the barycentres of a Delaunay triangulation of the disc (thesis §3.7.2).

    Vertices: a hexagonal lattice of spacing ``h =`` :data:`DELAUNAY_SPACING` ``* dx`` (one
    triangle per ``dx^2``), each vertex displaced uniformly within ``0.15 h`` (``seed``) so that
    the mesh is unstructured, lattice vertices within ``0.6 h`` of the circle dropped, and
    ``round(2 pi R / h)`` equally spaced vertices on the circle ``r = R``.  The vertices are
    triangulated with :class:`scipy.spatial.Delaunay`; each triangle gives one particle at its
    barycentre with volume equal to its area.  The volumes sum to the area of the inscribed
    polygon, ``pi R^2 (1 - O(h^2/R^2))``; ``N ~= pi R^2 / dx^2``.  Deterministic given ``seed``.

    Returns ``(x[N, 2], vol[N])``.
    """
    radius, dx = _check_disc(radius, dx)
    seed = _check_seed(seed)
    pts = _disc_vertices(radius, dx, seed)
    tri = pts[Delaunay(pts).simplices]  # [T, 3, 2]
    e1 = tri[:, 1] - tri[:, 0]
    e2 = tri[:, 2] - tri[:, 0]
    vol = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    x = tri.mean(axis=1)
    keep = vol > 1e-12 * dx * dx  # qhull never returns flat triangles here; guard anyway
    x, vol = x[keep], vol[keep]
    order = np.lexsort((x[:, 0], x[:, 1]))  # deterministic, cache-friendly ordering
    return x[order], vol[order]


def perturbed_barycentres(radius: float, dx: float, amplitude: float = 0.2,
                          seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Delaunay barycentres randomly displaced (thesis §3.7.2, "Random distribution").

    Starts from :func:`delaunay_barycentres` ``(radius, dx, seed)`` and moves particle ``i`` by a
    vector drawn uniformly in the disc of radius ``amplitude * sqrt(vol_i)``; the volumes are kept.
    A displacement that would leave the disc is redrawn (after a few attempts the particle stays
    at its barycentre), so all particles satisfy ``|x| < radius``.  Deterministic given ``seed``.

    Returns ``(x[N, 2], vol[N])``.
    """
    radius, dx = _check_disc(radius, dx)
    seed = _check_seed(seed)
    allowed = "a finite number with 0 <= amplitude <= 0.5"
    try:
        amp = float(amplitude)
    except (TypeError, ValueError):
        raise invalid("amplitude", amplitude, allowed) from None
    if not (math.isfinite(amp) and 0.0 <= amp <= 0.5):
        raise invalid("amplitude", amplitude, allowed)
    x0, vol = delaunay_barycentres(radius, dx, seed)
    rng = np.random.default_rng([seed, 0xB1A57])
    x = x0.copy()
    todo = np.arange(len(x0))
    for _ in range(20):
        a = amp * np.sqrt(vol[todo]) * np.sqrt(rng.random(todo.size))
        phi = 2.0 * np.pi * rng.random(todo.size)
        trial = x0[todo] + np.stack([a * np.cos(phi), a * np.sin(phi)], axis=1)
        inside = np.hypot(trial[:, 0], trial[:, 1]) < radius
        x[todo[inside]] = trial[inside]
        todo = todo[~inside]
        if todo.size == 0:
            break
    return x, vol


#: Layout name -> builder, as selected by the ``case.layout`` config key.
LAYOUTS = {"rings": rings, "delaunay": delaunay_barycentres, "perturbed": perturbed_barycentres}


def disc_layout(name: str, radius: float, dx: float, seed: int = 0,
                amplitude: float = 0.2) -> tuple[np.ndarray, np.ndarray]:
    """Layout ``name`` (``case.layout``: one of :data:`LAYOUTS`) of a disc; returns ``(x, vol)``.

    ``seed`` is used by the Delaunay layouts, ``amplitude`` by ``"perturbed"`` only.
    """
    if not isinstance(name, str) or name not in LAYOUTS:
        raise invalid("case.layout", name, ", ".join(sorted(LAYOUTS)))
    if name == "rings":
        _check_seed(seed)
        return rings(radius, dx)
    if name == "delaunay":
        return delaunay_barycentres(radius, dx, seed=seed)
    return perturbed_barycentres(radius, dx, amplitude=amplitude, seed=seed)


# --------------------------------------------------------------------------------------------
# body-fitted polar layout (flow past a cylinder, SPEC §12.2 V9)
# --------------------------------------------------------------------------------------------

def polar_ring_edges(radius: float, n_theta: int, r_far: float, *, names=("radius", "n_theta", "r_far")):
    """Ring edges ``r_k = radius q^k``, k = 0..n_rings, with ``r_{n_rings} = r_far`` exactly.

    Geometric radial growth with cells as long as they are wide: a cell of the ring at r spans
    dr = r dtheta radially for dtheta = 2 pi / n_theta, so ``n_rings = ceil(ln(r_far / radius) /
    ln(1 + dtheta))`` and ``q = (r_far / radius)^(1 / n_rings)`` (slightly below 1 + dtheta).
    ``names``: the config keys named by the errors.  Returns ``(edges[n_rings + 1], q)``.
    """
    kr, kn, kf = names
    if not (isinstance(radius, int | float) and math.isfinite(radius) and radius > 0):
        raise invalid(kr, radius, "a finite radius > 0")
    if isinstance(n_theta, bool) or not isinstance(n_theta, int | np.integer) or n_theta < 8:
        raise invalid(kn, n_theta, "an integer >= 8 (points around the body)")
    if not (isinstance(r_far, int | float) and math.isfinite(r_far) and r_far > radius):
        raise invalid(kf, r_far, f"a finite outer radius > {kr}={radius!r}")
    dtheta = 2.0 * math.pi / int(n_theta)
    n_rings = max(1, math.ceil(math.log(r_far / radius) / math.log1p(dtheta) - 1e-9))
    q = (r_far / radius) ** (1.0 / n_rings)
    return radius * q ** np.arange(n_rings + 1), q


class PolarLayout(NamedTuple):
    """:func:`polar_layout`'s result: ``x[N, 2]``, ``vol[N]``, ``ring[N]`` (particle i's ring, 0
    next to the body) and the ring ``edges[R + 1]``."""

    x: np.ndarray
    vol: np.ndarray
    ring: np.ndarray
    edges: np.ndarray


def polar_layout(radius: float, n_theta: int, r_far: float, n_extra: int = 0, centre=(0.0, 0.0),
                 *, names=("radius", "n_theta", "r_far")) -> PolarLayout:
    """Body-fitted polar (O-grid) layout of the annulus ``radius < r < r_far`` around ``centre``.

    :func:`polar_ring_edges` gives the rings; ``n_extra`` more rings continue the same geometric
    sequence beyond ``r_far`` (the far-field rings).  Ring k holds ``n_theta`` particles at the
    centres of its annular sectors, ``r = (r_k + r_{k+1}) / 2``, ``theta_j = (j + 1/2) dtheta``
    (the angles of the :class:`~mlsph_jax.geometry.Circle` quadrature points, so every wall point
    has a particle straight above it), and each particle's volume is its sector's area
    ``(r_{k+1}^2 - r_k^2) dtheta / 2``: the volumes of the first ``n_rings`` rings sum to
    ``pi (r_far^2 - radius^2)`` to round-off.  Thesis setup (V9): 120 points around the body,
    10,800 particles = 120 x 90 rings.  Returns a :class:`PolarLayout`.
    """
    edges, q = polar_ring_edges(radius, n_theta, r_far, names=names)
    if isinstance(n_extra, bool) or not isinstance(n_extra, int | np.integer) or n_extra < 0:
        raise invalid("n_extra", n_extra, "an integer >= 0 (far-field rings)")
    n_theta = int(n_theta)
    edges = np.concatenate([edges, edges[-1] * q ** np.arange(1, int(n_extra) + 1)])
    n_r = len(edges) - 1
    dtheta = 2.0 * math.pi / n_theta
    theta = (np.arange(n_theta) + 0.5) * dtheta
    rc = 0.5 * (edges[1:] + edges[:-1])
    area = 0.5 * (edges[1:] ** 2 - edges[:-1] ** 2) * dtheta
    ring = np.repeat(np.arange(n_r), n_theta)
    th = np.tile(theta, n_r)
    c = np.asarray(centre, float)
    x = np.stack([c[0] + rc[ring] * np.cos(th), c[1] + rc[ring] * np.sin(th)], axis=1)
    return PolarLayout(x, area[ring], ring, edges)


def elliptic_polar_layout(edges, n_theta: int, centre, semi_axes, angle):
    """The polar layout of :func:`polar_layout` (ring ``edges`` about a circle of radius
    ``edges[0]``) carried by a conformal map onto the region outside the ellipse with
    ``semi_axes`` (a, b) turned by ``angle`` about ``centre``: ``(x[N, 2], vol[N])`` as jnp
    functions of the shape (docs/architecture.md decision 65).

    In the plane zeta = rho e^{i theta} the layout is the polar one scaled by s = rho_0 /
    edges[0], rho_0 = (a + b) / 2; the Joukowski map z = zeta + c^2 / zeta, c^2 = (a^2 - b^2) / 4,
    takes the circle rho_0 to the ellipse x = a cos theta, y = b sin theta (so every particle of
    ray j stays above the quadrature point t_j = theta_j of the :class:`~mlsph_jax.geometry.Ellipse`)
    and the rings to confocal ellipses; z is then turned by ``angle`` and shifted by ``centre``.
    Conformal: the square polar cells stay square (the rings' grading and aspect are kept; the
    cells shrink by |dz/dzeta| = |1 - c^2 / zeta^2| >= 2 min(a, b) / (a + b) at the body).  It is
    one-to-one outside |zeta| = |c| < rho_0, so no particle enters the body.

    Volumes: the exact areas of the mapped annular sectors, int |dz/dzeta|^2 dA over rho_1 < rho <
    rho_2, theta_1 < theta < theta_2, i.e. (rho_2^2 - rho_1^2) dtheta / 2 - c^2 (sin 2 theta_2 -
    sin 2 theta_1) ln(rho_2 / rho_1) + c^4 (rho_1^-2 - rho_2^-2) dtheta / 2; they sum to the area
    between the body and the outer mapped ring, pi (rho_out^2 - c^4 / rho_out^2) - pi a b.

    For a = b = edges[0], angle 0 and centre 0 every operation is exact (s = 1, c^2 = 0, cos 0 =
    1, sin 0 = 0) and the result is :func:`polar_layout`'s bit for bit.  The angles' cosines and
    sines are host constants (the angles are not parameters)."""
    import jax.numpy as jnp

    edges = np.asarray(edges, float)
    n_theta = int(n_theta)
    n_r = len(edges) - 1
    dtheta = 2.0 * math.pi / n_theta
    theta = (np.arange(n_theta) + 0.5) * dtheta
    ring = np.repeat(np.arange(n_r), n_theta)
    th = np.tile(theta, n_r)
    lo, hi = np.tile(theta - 0.5 * dtheta, n_r), np.tile(theta + 0.5 * dtheta, n_r)
    ab = jnp.asarray(semi_axes)
    rho0 = 0.5 * (ab[0] + ab[1])
    c2 = 0.25 * (ab[0] - ab[1]) * (ab[0] + ab[1])
    s = rho0 / edges[0]
    e = s * jnp.asarray(edges)
    rc = 0.5 * (e[1:] + e[:-1])[ring]
    zx = (rc + c2 / rc) * np.cos(th)
    zy = (rc - c2 / rc) * np.sin(th)
    ca, sa = jnp.cos(angle), jnp.sin(angle)
    c = jnp.asarray(centre)
    x = jnp.stack([c[0] + (ca * zx - sa * zy), c[1] + (sa * zx + ca * zy)], axis=1)
    r1, r2 = e[:-1][ring], e[1:][ring]
    vol = (0.5 * (r2 ** 2 - r1 ** 2) * dtheta
           - c2 * (np.sin(2.0 * hi) - np.sin(2.0 * lo)) * jnp.log(r2 / r1)
           + 0.5 * c2 * c2 * (1.0 / r1 ** 2 - 1.0 / r2 ** 2) * dtheta)
    return x, vol
