"""Parametric wall curves in 2D and their boundary quadrature (thesis eq. 4.24; SPEC §5.8).

Every curve turns its parameters (entries ``geometry.<name>.<field>`` of
:class:`~mlsph_jax.state.Params`) into quadrature points by jnp operations, so that anything
computed from the points (boundary fluxes, forces, C_D) is differentiable with respect to the
shape:

* :class:`Segment` — a straight wall from ``start`` to ``end``, the fluid on its left; midpoint
  rule on ``n_points`` equal pieces (exact for the length and for linear integrands).
* :class:`Circle`, :class:`Ellipse`, :class:`StreamEllipse` (an ellipse given by its equal-area
  radius, aspect ratio and angle of attack) — closed smooth curves x(t) = c + R(angle) (a cos t, b sin t);
  the trapezoidal rule at t_k = 2 pi (k + 1/2) / n with dGamma_k = \\|x'(t_k)\\| 2 pi / n, which
  converges exponentially for the perimeter, the enclosed area and any smooth integrand.
* :class:`Polygon` — closed polygon through ``vertices``; each edge cut into pieces no longer
  than ``spacing`` (counts fixed at construction), midpoint rule (exact perimeter and area).
* :class:`Spline` — closed periodic cubic spline through ``knots`` (uniform parameter), the
  trapezoidal rule in the parameter.

Normals point **out of the fluid** (SPEC §5.8): for a closed curve with ``fluid = "outside"``
(a body in a stream) they point into the body, with ``fluid = "inside"`` (a container) out of
the enclosed region; a segment's normal is its right-hand normal (the fluid is on the left of
start -> end).  Closed curves may be given in either orientation.

Wall velocity at a point: ``velocity + omega x (x - centre)`` (a rigid motion; the rotation
centre of a polygon or spline is the mean of its vertices); segments translate only.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import InputError
from ..registry import Registry

#: Curve kinds (registry ``geometry.kind``): classes whose instances give ``defaults()``,
#: ``points(params)`` and the static ``n_points``.
CURVES: Registry = Registry("geometry.kind", protocol=("points", "defaults"), doc="wall and body curves")

FLUID_SIDES = ("outside", "inside")
#: How a :class:`StreamEllipse` realises its angle of attack.
INCIDENCES = ("body", "stream")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class BoundaryPoints:
    """Boundary quadrature (a pytree): points ``x[Nb, d]``, lengths ``dgamma[Nb]``, unit normals
    ``normal[Nb, d]`` out of the fluid, wall velocities ``velocity[Nb, d]`` and the index of the
    curve each point belongs to, ``curve[Nb]``."""

    x: jax.Array
    dgamma: jax.Array
    normal: jax.Array
    velocity: jax.Array
    curve: jax.Array

    @property
    def n(self) -> int:
        return self.x.shape[0]


def _check_name(name):
    if not isinstance(name, str) or not name or not name.replace("_", "a").isalnum():
        raise InputError(f"invalid geometry name {name!r}; allowed: a non-empty string of letters, digits and '_'")


def _check_count(key: str, n, minimum: int):
    if not isinstance(n, int) or isinstance(n, bool) or n < minimum:
        raise InputError(f"invalid {key}={n!r}; allowed: an int >= {minimum}")


def _vec(key: str, v, shape) -> tuple:
    a = np.asarray(v, float)
    if a.shape != shape or not np.all(np.isfinite(a)):
        raise InputError(f"invalid {key}={v!r}; allowed: finite numbers of shape {shape}")
    return tuple(a.ravel().tolist()) if a.ndim == 1 else tuple(map(tuple, a.tolist()))


def _rot90(v):
    """(v_y, -v_x): the right-hand normal of a direction v (outward for a counter-clockwise curve)."""
    return jnp.stack([v[..., 1], -v[..., 0]], axis=-1)


def _rigid_velocity(x, velocity, omega, centre):
    r = x - centre
    return velocity + omega * jnp.stack([-r[:, 1], r[:, 0]], axis=-1)


def _signed_area(p):
    """Shoelace area of the closed polygon p[m, 2] (> 0 counter-clockwise)."""
    q = jnp.roll(p, -1, axis=0)
    return 0.5 * jnp.sum(p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1])


@dataclasses.dataclass(frozen=True)
class _Curve:
    name: str

    def key(self, field: str) -> str:
        return f"geometry.{self.name}.{field}"

    def _closed_side(self):
        if self.fluid not in FLUID_SIDES:
            raise InputError(f"invalid {self.key('fluid')}={self.fluid!r}; allowed: "
                             f"{', '.join(map(repr, FLUID_SIDES))}")

    def _finish(self, x, tangent, dgamma, outward_sign, params, centre):
        """Closed curve: normals out of the fluid from the tangent of a curve whose orientation
        sign is ``outward_sign`` (+1 counter-clockwise)."""
        t = tangent / jnp.linalg.norm(tangent, axis=-1, keepdims=True)
        n_out = _rot90(t) * outward_sign            # out of the enclosed region
        normal = n_out if self.fluid == "inside" else -n_out
        vel = _rigid_velocity(x, params[self.key("velocity")], params[self.key("omega")], centre)
        return x, dgamma, normal, vel


@dataclasses.dataclass(frozen=True)
class _Closed(_Curve):
    """A closed curve: which side the fluid is on, and its rigid motion."""

    fluid: str = "outside"
    velocity: tuple = (0.0, 0.0)
    omega: float = 0.0
    closed = True

    def _common(self, count: bool = True):
        _check_name(self.name)
        self._closed_side()
        if count:
            _check_count(self.key("n_points"), self.n_points, 3)
        object.__setattr__(self, "velocity", _vec(self.key("velocity"), self.velocity, (2,)))

    def _motion(self) -> dict:
        return {self.key("velocity"): self.velocity, self.key("omega"): float(self.omega)}


@dataclasses.dataclass(frozen=True)
class Segment(_Curve):
    """Straight wall from ``start`` to ``end`` with ``n_points`` quadrature points; the fluid is on
    the left of start -> end; ``velocity``: wall velocity (e.g. a sliding plate)."""

    start: tuple = (0.0, 0.0)
    end: tuple = (1.0, 0.0)
    n_points: int = 10
    velocity: tuple = (0.0, 0.0)
    closed = False

    def __post_init__(self):
        _check_name(self.name)
        _check_count(self.key("n_points"), self.n_points, 1)
        object.__setattr__(self, "start", _vec(self.key("start"), self.start, (2,)))
        object.__setattr__(self, "end", _vec(self.key("end"), self.end, (2,)))
        object.__setattr__(self, "velocity", _vec(self.key("velocity"), self.velocity, (2,)))
        if self.start == self.end:
            raise InputError(f"invalid {self.key('end')}={list(self.end)}: equal to {self.key('start')}; "
                             "allowed: a segment of non-zero length")

    def defaults(self) -> dict:
        return {self.key("start"): self.start, self.key("end"): self.end, self.key("velocity"): self.velocity}

    def points(self, params):
        a, b = params[self.key("start")], params[self.key("end")]
        n = self.n_points
        u = (jnp.arange(n) + 0.5) / n
        x = a + u[:, None] * (b - a)
        length = jnp.linalg.norm(b - a)
        normal = jnp.broadcast_to(_rot90((b - a) / length), (n, 2))
        vel = jnp.broadcast_to(params[self.key("velocity")], (n, 2))
        return x, jnp.full(n, length / n), normal, vel


@dataclasses.dataclass(frozen=True)
class Ellipse(_Closed):
    """Ellipse with ``centre``, ``semi_axes`` (a, b) and ``angle`` (radians, counter-clockwise from
    +x to the a-axis; an angle of attack alpha in a stream along +x is ``angle = -alpha``)."""

    centre: tuple = (0.0, 0.0)
    semi_axes: tuple = (1.0, 0.5)
    angle: float = 0.0
    n_points: int = 64

    def __post_init__(self):
        self._common()
        object.__setattr__(self, "centre", _vec(self.key("centre"), self.centre, (2,)))
        self._check_shape()

    def _check_shape(self):
        ax = _vec(self.key("semi_axes"), self.semi_axes, (2,))
        if min(ax) <= 0:
            raise InputError(f"invalid {self.key('semi_axes')}={list(ax)}; allowed: two lengths > 0")
        object.__setattr__(self, "semi_axes", ax)

    def defaults(self) -> dict:
        return {self.key("centre"): self.centre, self.key("semi_axes"): self.semi_axes,
                self.key("angle"): float(self.angle), **self._motion()}

    def _axes(self, params):
        return params[self.key("semi_axes")], params[self.key("angle")]

    def points(self, params):
        c = params[self.key("centre")]
        ab, ang = self._axes(params)
        n = self.n_points
        t = 2.0 * math.pi * (jnp.arange(n) + 0.5) / n
        ca, sa = jnp.cos(ang), jnp.sin(ang)
        local = jnp.stack([ab[0] * jnp.cos(t), ab[1] * jnp.sin(t)], axis=-1)
        dlocal = jnp.stack([-ab[0] * jnp.sin(t), ab[1] * jnp.cos(t)], axis=-1)
        rot = lambda v: jnp.stack([ca * v[:, 0] - sa * v[:, 1], sa * v[:, 0] + ca * v[:, 1]], axis=-1)  # noqa: E731
        x, dx = c + rot(local), rot(dlocal)
        dgamma = jnp.linalg.norm(dx, axis=-1) * (2.0 * math.pi / n)
        return self._finish(x, dx, dgamma, 1.0, params, c)


@dataclasses.dataclass(frozen=True)
class Circle(Ellipse):
    """Circle of ``radius`` about ``centre`` (the ellipse with a = b = radius)."""

    radius: float = 0.5

    def _check_shape(self):
        if not (isinstance(self.radius, int | float) and math.isfinite(self.radius) and self.radius > 0):
            raise InputError(f"invalid {self.key('radius')}={self.radius!r}; allowed: a length > 0")

    def defaults(self) -> dict:
        return {self.key("centre"): self.centre, self.key("radius"): float(self.radius), **self._motion()}

    def _axes(self, params):
        r = params[self.key("radius")]
        return jnp.stack([r, r]), jnp.zeros_like(r)


@dataclasses.dataclass(frozen=True)
class StreamEllipse(Ellipse):
    """Ellipse of a body in a stream along +x, parametrised for shape studies: the equal-area
    ``radius`` R (area pi R^2), the ``aspect`` ratio A = a/b of the semi-axes along and across
    its chord, so a = R sqrt(A), b = R / sqrt(A), and the angle of attack ``alpha`` (radians,
    nose up).  ``incidence``: ``"body"`` turns the a-axis by -alpha (clockwise, so the leading
    edge at -x rises); ``"stream"`` keeps the a-axis along +x and leaves alpha to the user of the
    curve, who turns the free stream to the direction (cos alpha, sin alpha) instead (the same
    flow seen in a frame turned by alpha; the ``cylinder`` case does so, decision 65).  A = 1,
    alpha = 0 is the :class:`Circle` of radius R, bit for bit (sqrt(1) = 1, sin(-0) = -0)."""

    radius: float = 0.5
    aspect: float = 1.0
    alpha: float = 0.0
    incidence: str = "body"

    def _check_shape(self):
        if self.incidence not in INCIDENCES:
            raise InputError(f"invalid {self.key('incidence')}={self.incidence!r}; allowed: "
                             f"{', '.join(map(repr, INCIDENCES))}")
        for field, lo in (("radius", 0.0), ("aspect", 0.0), ("alpha", None)):
            v = getattr(self, field)
            ok = isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
            if not ok or (lo is not None and v <= lo):
                what = "a finite angle in radians" if lo is None else "a finite number > 0"
                raise InputError(f"invalid {self.key(field)}={v!r}; allowed: {what}")

    def defaults(self) -> dict:
        return {self.key("centre"): self.centre, self.key("radius"): float(self.radius),
                self.key("aspect"): float(self.aspect), self.key("alpha"): float(self.alpha), **self._motion()}

    def _axes(self, params):
        r, s = params[self.key("radius")], jnp.sqrt(params[self.key("aspect")])
        alpha = params[self.key("alpha")]
        return jnp.stack([r * s, r / s]), (-alpha if self.incidence == "body" else jnp.zeros_like(alpha))


@dataclasses.dataclass(frozen=True)
class Polygon(_Closed):
    """Closed polygon through ``vertices`` (either orientation); edges cut into pieces no longer
    than ``spacing`` (the counts are fixed by the initial vertices)."""

    vertices: tuple = ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0))
    spacing: float = 0.1

    def __post_init__(self):
        self._common(count=False)
        v = np.asarray(self.vertices, float)
        if v.ndim != 2 or v.shape[0] < 3 or v.shape[1] != 2 or not np.all(np.isfinite(v)):
            raise InputError(f"invalid {self.key('vertices')}={self.vertices!r}; allowed: at least 3 finite "
                             "(x, y) vertices")
        object.__setattr__(self, "vertices", tuple(map(tuple, v.tolist())))
        if not (isinstance(self.spacing, int | float) and self.spacing > 0):
            raise InputError(f"invalid {self.key('spacing')}={self.spacing!r}; allowed: a length > 0")
        lengths = np.linalg.norm(np.roll(v, -1, axis=0) - v, axis=1)
        if np.any(lengths == 0):
            raise InputError(f"invalid {self.key('vertices')}: vertex {int(np.argmin(lengths))} repeats the next "
                             "one; allowed: distinct consecutive vertices")
        object.__setattr__(self, "_per_edge", tuple(int(max(1, math.ceil(s / self.spacing - 1e-9)))
                                                    for s in lengths))

    @property
    def n_points(self) -> int:
        return sum(self._per_edge)

    def defaults(self) -> dict:
        return {self.key("vertices"): self.vertices, **self._motion()}

    def points(self, params):
        v = params[self.key("vertices")]
        e = np.repeat(np.arange(len(self._per_edge)), self._per_edge)
        u = np.concatenate([(np.arange(k) + 0.5) / k for k in self._per_edge])
        cnt = np.repeat(np.asarray(self._per_edge, float), self._per_edge)
        a, b = v[e], jnp.roll(v, -1, axis=0)[e]
        x = a + jnp.asarray(u)[:, None] * (b - a)
        dgamma = jnp.linalg.norm(b - a, axis=-1) / cnt
        return self._finish(x, b - a, dgamma, jnp.sign(_signed_area(v)), params, jnp.mean(v, axis=0))


@dataclasses.dataclass(frozen=True)
class Spline(_Closed):
    """Closed periodic cubic spline through the points ``knots`` (uniform parameter), ``n_points``
    quadrature points equally spaced in the parameter."""

    knots: tuple = ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))
    n_points: int = 64

    def __post_init__(self):
        self._common()
        p = np.asarray(self.knots, float)
        if p.ndim != 2 or p.shape[0] < 3 or p.shape[1] != 2 or not np.all(np.isfinite(p)):
            raise InputError(f"invalid {self.key('knots')}={self.knots!r}; allowed: at least 3 finite (x, y) "
                             "points")
        object.__setattr__(self, "knots", tuple(map(tuple, p.tolist())))

    def defaults(self) -> dict:
        return {self.key("knots"): self.knots, **self._motion()}

    def points(self, params):
        P = params[self.key("knots")]
        m, n = P.shape[0], self.n_points
        # periodic second derivatives: M_{i-1} + 4 M_i + M_{i+1} = 6 (P_{i+1} - 2 P_i + P_{i-1})
        eye = np.eye(m)
        A = 4.0 * eye + np.roll(eye, 1, axis=1) + np.roll(eye, -1, axis=1)
        M = jnp.linalg.solve(jnp.asarray(A), 6.0 * (jnp.roll(P, -1, axis=0) - 2.0 * P + jnp.roll(P, 1, axis=0)))
        s = m * (np.arange(n) + 0.5) / n
        i = np.floor(s).astype(int)
        u = jnp.asarray(s - i)[:, None]
        j = (i + 1) % m
        x = ((1 - u) * P[i] + u * P[j] + ((1 - u) ** 3 - (1 - u)) * M[i] / 6.0 + (u ** 3 - u) * M[j] / 6.0)
        dx = P[j] - P[i] + (1.0 - 3.0 * (1 - u) ** 2) * M[i] / 6.0 + (3.0 * u ** 2 - 1.0) * M[j] / 6.0
        dgamma = jnp.linalg.norm(dx, axis=-1) * (m / n)
        return self._finish(x, dx, dgamma, jnp.sign(_signed_area(P)), params, jnp.mean(P, axis=0))


for _name, _cls in (("segment", Segment), ("circle", Circle), ("ellipse", Ellipse),
                    ("stream_ellipse", StreamEllipse), ("polygon", Polygon), ("spline", Spline)):
    CURVES.register(_name, _cls)


def curve_params(curves) -> dict:
    """The ``geometry.<name>.<field>`` defaults of all ``curves`` (to merge into the Params);
    duplicate names are an :class:`InputError`."""
    out, seen = {}, set()
    for c in curves:
        if c.name in seen:
            raise InputError(f"duplicate geometry name {c.name!r}; allowed: one curve per name")
        seen.add(c.name)
        out.update({k: jnp.asarray(v, jnp.float64) for k, v in c.defaults().items()})
    return out


def quadrature(curves, params) -> BoundaryPoints:
    """All curves' quadrature points as one :class:`BoundaryPoints` (jnp; differentiable in the
    ``geometry.*`` parameters)."""
    if not curves:
        raise InputError("invalid curves=(); allowed: at least one curve")
    parts = [c.points(params) for c in curves]
    cid = np.concatenate([np.full(c.n_points, k, np.int32) for k, c in enumerate(curves)])
    cat = lambda i: jnp.concatenate([p[i] for p in parts], axis=0)  # noqa: E731
    return BoundaryPoints(cat(0), cat(1), cat(2), cat(3), jnp.asarray(cid))
