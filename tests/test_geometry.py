"""Boundary geometry as data (mlsph_jax.geometry; thesis eq. 4.24, SPEC §5.8): quadrature of
perimeters and enclosed areas (divergence theorem), unit normals out of the fluid, shape
gradients against finite differences, and the set-up checks of bad geometry."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.special import ellipe

from mlsph_jax.errors import InputError
from mlsph_jax.geometry import Circle, Ellipse, Polygon, Segment, Spline, check_geometry, curve_params, quadrature
from mlsph_jax.state import Domain, Params


def _pq(curve):
    p = Params(curve_params([curve]))
    return p, quadrature([curve], p)


def _perimeter_area(bp):
    """Perimeter and sum x_b . n_b dGamma_b / d (= +area for normals out of the region)."""
    return float(jnp.sum(bp.dgamma)), float(jnp.sum(jnp.sum(bp.x * bp.normal, axis=-1) * bp.dgamma)) / 2.0


def test_circle_and_ellipse_converge_exponentially():
    r = 0.7
    for n, tol in ((16, 1e-13), (64, 1e-13)):
        per, area = _perimeter_area(_pq(Circle("c", centre=(0.3, -0.2), radius=r, n_points=n))[1])
        assert abs(per - 2 * math.pi * r) < tol and abs(-area - math.pi * r * r) < tol   # body: n into it
    a, b = 1.0, 0.3
    exact_per = 4 * a * ellipe(1 - (b / a) ** 2)
    errs = []
    for n in (16, 32, 64):
        per, area = _perimeter_area(_pq(Ellipse("e", centre=(1.0, 2.0), semi_axes=(a, b), angle=0.4, n_points=n,
                                                fluid="inside"))[1])
        errs.append(abs(per - exact_per))
        assert abs(area - math.pi * a * b) < 1e-13                 # container: n out of it
    # measured 6.6e-4, 1.6e-6, 2.7e-11: the error ratio grows with n (exponential convergence;
    # an algebraic rule of order k would give a constant ratio 2^k)
    assert errs[1] < 1e-5 and errs[2] < 1e-10 and errs[1] / errs[2] > 10 * errs[0] / errs[1]


def test_polygon_and_segment_are_exact():
    sq = Polygon("sq", vertices=((0, 0), (0, 2), (3, 2), (3, 0)), spacing=0.25)   # clockwise on purpose
    p, bp = _pq(sq)
    per, area = _perimeter_area(bp)
    assert sq.n_points == 2 * (8 + 12) and abs(per - 10.0) < 1e-13 and abs(-area - 6.0) < 1e-13
    # normals of a body point into it: the bottom edge (y = 0) has n = +y
    bottom = np.abs(np.asarray(bp.x[:, 1])) < 1e-12
    assert np.allclose(np.asarray(bp.normal)[bottom], [0.0, 1.0])
    seg = Segment("w", start=(0.0, 0.0), end=(2.0, 0.0), n_points=8)             # fluid above (left)
    _, bs = _pq(seg)
    assert np.allclose(np.asarray(bs.normal), [0.0, -1.0]) and abs(float(jnp.sum(bs.dgamma)) - 2.0) < 1e-15
    assert np.allclose(np.asarray(bs.x[:, 0]), (np.arange(8) + 0.5) / 4)


def test_normals_are_unit_and_out_of_the_fluid():
    c = (0.5, -1.0)
    for fluid, sign in (("outside", -1.0), ("inside", 1.0)):
        p, bp = _pq(Circle("c", centre=c, radius=0.5, n_points=37, fluid=fluid))
        radial = (np.asarray(bp.x) - c) / 0.5
        assert np.allclose(np.linalg.norm(np.asarray(bp.normal), axis=1), 1.0, atol=1e-15)
        assert np.allclose(np.asarray(bp.normal), sign * radial, atol=1e-14)
    # a spline body: normals point into the body whichever orientation the knots have
    t = 2 * np.pi * np.arange(12) / 12
    knots = np.stack([np.cos(t), 0.6 * np.sin(t)], axis=1)
    outs = []
    for k in (knots, knots[::-1]):
        _, bp = _pq(Spline("s", knots=tuple(map(tuple, k)), n_points=200))
        inward = np.sum(np.asarray(bp.normal) * -np.asarray(bp.x), axis=1)
        assert np.all(inward > 0)
        per, area = _perimeter_area(bp)
        outs.append(-area)
    assert abs(outs[0] - outs[1]) < 1e-12 and abs(outs[0] - math.pi * 0.6) < 2e-3   # spline ~ the ellipse


def test_rigid_wall_velocity():
    circ = Circle("c", centre=(1.0, 0.0), radius=0.5, n_points=8, velocity=(0.2, 0.0), omega=2.0)
    _, bp = _pq(circ)
    r = np.asarray(bp.x) - [1.0, 0.0]
    assert np.allclose(np.asarray(bp.velocity), np.stack([0.2 - 2.0 * r[:, 1], 2.0 * r[:, 0]], axis=1))


def test_shape_gradients_match_finite_differences():
    circ = Circle("c", centre=(0.0, 0.0), radius=0.5, n_points=24)
    ell = Ellipse("e", centre=(0.0, 0.0), semi_axes=(1.0, 0.4), angle=0.3, n_points=48)
    p0 = Params({**curve_params([circ]), **curve_params([ell])})

    def perimeter(p):
        return jnp.sum(quadrature([circ], p).dgamma)

    def moment(p):   # second moment of the ellipse boundary about the x axis (depends on the angle)
        bp = quadrature([ell], p)
        return jnp.sum(bp.x[:, 1] ** 2 * bp.dgamma)

    perimeter, moment = jax.jit(perimeter), jax.jit(moment)
    for f, key, eps in ((perimeter, "geometry.c.radius", 1e-6), (moment, "geometry.e.angle", 1e-6)):
        g = jax.jit(jax.grad(f))(p0)[key]
        fd = (f(p0.updated({key: p0[key] + eps})) - f(p0.updated({key: p0[key] - eps}))) / (2 * eps)
        assert abs(float(g) - float(fd)) < 1e-8 * max(1.0, abs(float(fd))), (key, g, fd)
    assert abs(float(jax.grad(perimeter)(p0)["geometry.c.radius"]) - 2 * math.pi) < 1e-12
    ga = jax.jit(jax.grad(moment))(p0)["geometry.e.semi_axes"]
    fd = [(moment(p0.updated({"geometry.e.semi_axes": p0["geometry.e.semi_axes"].at[k].add(1e-6)}))
           - moment(p0.updated({"geometry.e.semi_axes": p0["geometry.e.semi_axes"].at[k].add(-1e-6)}))) / 2e-6
          for k in range(2)]
    assert np.allclose(np.asarray(ga), np.asarray(fd), rtol=1e-7)


# --- bad input ------------------------------------------------------------------------------------

def _lattice(lo, hi, dx):
    g = np.arange(lo + dx / 2, hi, dx)
    X, Y = np.meshgrid(g, g, indexing="ij")
    return np.stack([X.ravel(), Y.ravel()], axis=1)


BOX = Domain((-2.0, -2.0), (2.0, 2.0), (False, False))


def _check(curves, x=None, dx=0.1, domain=BOX):
    x = _lattice(-2.0, 2.0, dx) if x is None else x
    p = Params(curve_params(curves))
    check_geometry(curves, p, x, np.full(len(x), dx * dx), domain=domain)


def _fluid_outside(curves, dx=0.1):
    x = _lattice(-2.0, 2.0, dx)
    keep = np.ones(len(x), bool)
    for c in curves:
        keep &= ~_inside(c, x)
    return x[keep]


def _inside(c, x):
    from mlsph_jax.geometry.checks import inside_polygon, outline
    return inside_polygon(x, outline(c, Params(curve_params([c]))))


@pytest.mark.parametrize("curves, fragments", [
    ((Polygon("bow", vertices=((0, 0), (1, 1), (1, 0), (0, 1)), spacing=0.05),), ["geometry.bow", "intersects itself"]),
    ((Spline("eight", knots=((0, 0), (1, 0.5), (1, -0.5), (0, 0.01), (-1, 0.5), (-1, -0.5)), n_points=200),),
     ["geometry.eight", "intersects itself"]),
    ((Circle("a", radius=0.5, n_points=40), Circle("b", centre=(0.6, 0.0), radius=0.5, n_points=40)),
     ["geometry.b", "overlaps geometry.a"]),
    ((Circle("a", radius=1.0, n_points=80), Circle("b", centre=(0.1, 0.0), radius=0.3, n_points=40)),
     ["geometry.b", "overlaps geometry.a"]),
    ((Circle("edge", centre=(1.8, 0.0), radius=0.5, n_points=40),), ["geometry.edge", "domain edge"]),
])
def test_bad_geometry_names_the_curve(curves, fragments):
    with pytest.raises(InputError) as e:
        _check(curves, x=_fluid_outside(curves))
    for f in fragments:
        assert f in str(e.value)


def test_particles_inside_a_body_and_sparse_quadrature_are_refused():
    circ = Circle("cyl", radius=0.5, n_points=40)
    with pytest.raises(InputError, match=r"fluid particle \d+ .* inside the body geometry.cyl"):
        _check((circ,))                                     # the lattice fills the body
    _check((circ,), x=_fluid_outside((circ,)))              # 2 pi 0.5 / 40 = 0.079 < dx = 0.1: fine
    sparse = Circle("cyl", radius=0.5, n_points=20)
    with pytest.raises(InputError, match=r"geometry.cyl.n_points=20: .*n_points >= 32"):
        _check((sparse,), x=_fluid_outside((sparse,)))
    wall = Segment("floor", start=(2.0, -1.0), end=(-2.0, -1.0), n_points=40)   # fluid below: lattice above it
    with pytest.raises(InputError, match="beyond the wall geometry.floor"):
        _check((wall,))
    with pytest.raises(InputError, match=r"geometry.c.radius=-1"):
        Circle("c", radius=-1.0)
    with pytest.raises(InputError, match="duplicate geometry name 'c'"):
        curve_params([Circle("c"), Circle("c")])
    with pytest.raises(InputError, match=r"geometry.p.spacing=0.5: .*spacing <= 0.1"):
        sq = Polygon("p", vertices=((-0.5, -0.5), (0.5, -0.5), (0.5, 0.5), (-0.5, 0.5)), spacing=0.5)
        _check((sq,), x=_fluid_outside((sq,)))
