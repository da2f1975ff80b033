"""Boundary geometry as data: quadrature points on walls and bodies (thesis §4.3, eq. 4.24;
SPEC §5.8).

A boundary is a :class:`~mlsph_jax.geometry.curves.BoundaryPoints` pytree of quadrature points
``x[Nb, d]``, lengths ``dgamma[Nb]``, unit normals ``normal[Nb, d]`` pointing out of the fluid
(into the wall or body) and wall velocities ``velocity[Nb, d]``, built from parametric curves
(:mod:`.curves`: straight segments, circles, ellipses, polygons, closed splines).  The curve
parameters (centre, radius, semi-axes, angle of attack, vertices, wall velocity, rotation rate)
are entries ``geometry.<name>.<field>`` of :class:`~mlsph_jax.state.Params`, so the quadrature
is a jnp function of them and forces on bodies are differentiable with respect to their shape.
:mod:`.checks` refuses bad geometry at setup (self-intersecting curves, overlapping bodies,
bodies across the domain edge, particles inside bodies, quadrature too sparse for the particles).
"""

from .checks import check_geometry
from .curves import (
    CURVES,
    BoundaryPoints,
    Circle,
    Ellipse,
    Polygon,
    Segment,
    Spline,
    StreamEllipse,
    curve_params,
    quadrature,
)

__all__ = ["CURVES", "BoundaryPoints", "Circle", "Ellipse", "Polygon", "Segment", "Spline", "StreamEllipse",
           "check_geometry",
           "curve_params", "quadrature"]
