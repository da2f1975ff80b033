"""Particle layouts filling a disc, for the 2-D blast explosion (SPEC §12.1 V3).

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

import numpy as np
from scipy.spatial import Delaunay

from ..errors import invalid

__all__ = ["DELAUNAY_SPACING", "LAYOUTS", "delaunay_barycentres", "disc_layout",
           "perturbed_barycentres", "rings"]

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
    n_k = np.maximum(1, np.rint(2.0 * np.pi * (k + 0.5)).astype(np.int64))
    # annulus k: pi ((k+1)^2 - k^2) dr^2 = pi (2k+1) dr^2
    annulus = np.pi * (2.0 * k + 1.0) * dr * dr
    ring = np.repeat(k, n_k)
    start = np.concatenate([[0], np.cumsum(n_k)[:-1]])
    j = np.arange(ring.size) - start[ring]
    theta = 2.0 * np.pi * (j + 0.5 * (ring % 2)) / n_k[ring]
    x = np.stack([r_k[ring] * np.cos(theta), r_k[ring] * np.sin(theta)], axis=1)
    vol = (annulus / n_k)[ring]
    return x, vol


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
