"""Bodies given by points (issue 17 item 1; decision 103): ``case.body = "polygon"`` or ``"spline"``
with ``case.body_points`` in units of D on the ``cartesian`` layout.  The layout's volumes
partition the fluid around the exact polygon, the body's boundary terms vanish for a fluid at
rest, the force on a square at rest in a hydrostatic atmosphere is Archimedes' buoyancy, a spline
through points of the circle flows like the built-in circle, and bad points are refused naming
the key."""

from __future__ import annotations

import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mlsph_jax import config as config_mod
from mlsph_jax.cases import build_problem
from mlsph_jax.cases.body_layouts import square_lattice
from mlsph_jax.cases.cylinder import free_stream, rear_on_axis
from mlsph_jax.errors import ConfigError, InputError
from mlsph_jax.schema import Key
from mlsph_jax.simulation import run_problem
from mlsph_jax.state import Kind
from mlsph_jax.testing import CONFIG_DIR, stream_particles, uniform_stream_residuals

SQUARE = "[[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]]"
SMALL = ("case.n_theta=32", "case.layout=\"cartesian\"", "case.lattice_ratio=1.5", "output.plots=false",
         "output.progress=false")


def _cfg(*extra):
    return config_mod.load(CONFIG_DIR / "cylinder.toml", [*SMALL, *extra])


def _square(*extra):
    return _cfg("case.body=\"polygon\"", f"case.body_points={SQUARE}", *extra)


def test_point_list_key_checks_every_point():
    """A list key of points (``item_length``): each item must be a list of that many finite numbers;
    the message names the key, the bad item and the allowed form."""
    k = Key(list, [], item_type=float, item_length=2)
    assert k.check("case.body_points", [[0, 1], [2, 3.5]]) == [[0.0, 1.0], [2.0, 3.5]]
    for bad, why in (([[0, 1], [2]], "item 1: expected a list of 2 numbers"), ([1, 2], "item 0"),
                     ([[0, float("nan")]], "finite"), ([[0, "a"]], "expected float")):
        with pytest.raises(ConfigError, match="case.body_points") as e:
            k.check("case.body_points", bad)
        assert why in str(e.value) and "list of [float, float]" in str(e.value)


def test_square_layout_volumes_and_rest_state():
    """The lattice cut around the square: no fluid particle inside it, the fluid volumes sum to
    N_disc h^2 - D^2 to round-off (the body polygon is the square itself, no refinement error), a
    uniform stream without walls and a fluid at rest with the square's boundary terms keep a zero
    right-hand side to round-off, the stream through the no-slip square does not; the rear on the
    wake axis is x = D / 2."""
    cfg = _square("case.r_far=2.0")
    pb = build_problem(cfg)
    p, c = pb.particles, cfg["case"]
    x, vol = np.asarray(p.x), np.asarray(p.vol)
    fluid = np.asarray(p.kind) == int(Kind.FLUID)
    D = 2.0 * c["radius"]
    assert np.all(np.max(np.abs(x[fluid]), axis=1) > 0.5 * D)
    poly = np.asarray(pb.params["geometry.body.vertices"])
    h = math.sqrt(vol[~fluid][0])          # frozen particles hold h^2
    n_disc = len(square_lattice(h, c["r_far"]))
    assert abs(vol[fluid].sum() - (n_disc * h * h - D * D)) <= 1e-12 * n_disc * h * h
    assert rear_on_axis(poly) == 0.5 * D
    r = uniform_stream_residuals(pb, cfg)
    assert r["stream"] <= 2e-11 and r["rest"] <= 2e-11 and r["moving"] > 1e-3, r


def test_faces_on_half_lattice_lines_keep_their_first_row():
    """A square of side D = 12 h (48 points on the body, lattice_ratio 1: h = D / 12) has every face
    exactly h / 2 from a lattice line: the cut-out keeps that row on all four faces alike (the
    row removed by round-off on some faces left a 1.5 h gap there, and that run blew up at the
    front face at t = 3.7)."""
    pb = build_problem(_square("case.n_theta=48", "case.lattice_ratio=1.0", "case.r_far=2.0"))
    x = np.asarray(pb.particles.x)[np.asarray(pb.particles.kind) == int(Kind.FLUID)]
    h = 1.0 / 12.0
    for axis in (0, 1):
        across = np.abs(x[:, 1 - axis]) < 0.5 - h
        near = x[across, axis]
        assert np.isclose(near[near < 0].max(), -0.5 - 0.5 * h, rtol=0, atol=1e-12)
        assert np.isclose(near[near > 0].min(), 0.5 + 0.5 * h, rtol=0, atol=1e-12)


def test_a_lattice_far_from_a_flat_face_warns():
    """The square at 48 points and lattice_ratio 1.176 has its faces 1.40 h from their first rows
    (the run builds, but its wall pressures are wrong: docs/validation.md): a LayoutWarning naming
    the keys and the gap; at lattice_ratio 1 (faces h/2 from a row) none."""
    from mlsph_jax.errors import LayoutWarning

    with pytest.warns(LayoutWarning, match=r"case.n_theta=48 and case.lattice_ratio=1.176: the first lattice row "
                                           r"lies 1.4\d spacings from the body"):
        build_problem(_square("case.n_theta=48", "case.lattice_ratio=1.176", "case.r_far=2.0"))
    with warnings.catch_warnings():
        warnings.simplefilter("error", LayoutWarning)
        build_problem(_square("case.n_theta=48", "case.lattice_ratio=1.0", "case.r_far=2.0"))


def test_force_on_a_square_at_rest_is_the_buoyancy():
    """Archimedes on the square of side D at rest in the isothermal atmosphere p = p_inf exp(-a y)
    (a = rho_inf g / p_inf, body force (0, -g)): the force of the fluid on the body is 2 D p_inf
    sinh(a D / 2) upward.  The midpoint rule is exact on the top and bottom faces (p constant along
    them) and the side faces cancel, so the error is the wall pressure's (the linear MLS
    interpolant of p), O((a h)^2) relative: measured 2.8e-6 at g = 1 and 2.8e-4 at g = 10 (quadratic in
    a); bound (a h)^2 = 6.9e-6 at g = 1 (h = 0.1875 D the lattice spacing)."""
    g = 1.0
    cfg = _square("case.r_far=2.0", f"physics.body_force=[0.0, {-g}]")
    pb = build_problem(cfg)
    p = stream_particles(pb, cfg, 0.0)
    total, pressure = pb.boundary.forces(p, pb.params, pb.scheme)
    p_inf = float(free_stream(cfg, np.zeros((1, 2)), pb.params)[2][0])
    a, D = g / p_inf, 2.0 * cfg["case"]["radius"]
    exact = 2.0 * D * p_inf * math.sinh(0.5 * a * D)
    f = np.asarray(total[0])
    h = 1.5 * 4.0 * D / cfg["case"]["n_theta"]          # lattice_ratio x perimeter / n_theta
    assert abs(f[1] - exact) <= (a * h) ** 2 * exact, (f, exact)
    assert abs(f[0]) <= 1e-12 * exact and np.array_equal(np.asarray(total), np.asarray(pressure))


def test_spline_through_circle_points_flows_like_the_circle():
    """A periodic cubic spline through 16 points of the circle of diameter D (interpolation error
    ~1e-5 D) on the lattice of its own perimeter (h within ~1e-5 of the circle's; both 916
    particles): after a short impulsive start (t = 0.3, Mach 0.2) its drag agrees with the
    circle's to 3e-4 relative, its front and base pressure coefficients (interpolated between
    quadrature points at other angles) to 1e-3 (in units of the dynamic pressure, as every C_p),
    and the flow stays mirror-symmetric, while the 16-gon through the same points (an area 2.6 %
    short of the circle's, a perimeter 0.6 %, so its lattice differs as well) misses by more: the
    check resolves the shape.  Measured (decision 108): C_D 4.13643 (circle), 4.13616 (spline,
    6.4e-5 relative), 4.16768 (16-gon, 7.6e-3); C_p front 2.8113 / 2.8122 / 2.9523, base -0.3221 /
    -0.3227 / -0.4734 (the spline 8.5e-4 / 5.9e-4 from the circle, the 16-gon 0.14 / 0.15).  Before
    decision 108: C_D 4.80632, 4.80604, 4.83779, and C_p base -1.089 (the tolerance was 1e-3 of
    |C_p| then, 3.2e-4 at the base's size now)."""
    t = 2.0 * math.pi * (np.arange(16) + 0.5) / 16
    pts = "[" + ", ".join(f"[{0.5 * math.cos(a)!r}, {0.5 * math.sin(a)!r}]" for a in t) + "]"
    common = ("case.r_far=2.0", "case.mach=0.2", "time.t_end=0.3", "output.snapshots=1", "case.steady_tol=0",
              "time.local_time_stepping=false")
    out = {}
    for name, extra in (("circle", ()), ("spline", ("case.body=\"spline\"", f"case.body_points={pts}")),
                        ("polygon", ("case.body=\"polygon\"", f"case.body_points={pts}"))):
        cfg = _cfg(*common, *extra)
        out[name] = run_problem(build_problem(cfg), cfg, out_dir=None, quiet=True).summary["metrics"]
    cd = out["circle"]["cd"]
    assert abs(out["spline"]["cd"] - cd) <= 3e-4 * cd, out
    for k in ("cp_front", "cp_base"):
        assert abs(out["spline"][k] - out["circle"][k]) <= 1e-3, (k, out)
    assert abs(out["polygon"]["cd"] - cd) > 3e-3 * cd, out
    assert abs(out["spline"]["cl"]) <= 1e-9 * cd, out


def test_shape_derivative_refused_for_points_but_not_the_stream_angle():
    """The lattice is cut once around the points: a derivative with respect to
    geometry.body.vertices is an InputError naming the parameter and the layout; the angle of
    attack turns the stream and stays differentiable."""
    pb = build_problem(_square("case.r_far=2.0", "case.alpha=5.0"))

    def f(key):
        return lambda v: jnp.sum(pb.particles_at(pb.params.updated({key: v})).q)

    with pytest.raises(InputError, match=r"geometry\.body\.vertices"):
        jax.grad(f("geometry.body.vertices"))(pb.params["geometry.body.vertices"])
    assert np.isfinite(float(jax.grad(f("geometry.body.alpha"))(pb.params["geometry.body.alpha"])))


def test_either_sense_of_the_points_gives_the_same_body():
    """The square listed clockwise and counter-clockwise: the same quadrature points (in reverse
    order) with normals into the body, so the same coefficients of the initial state (the
    impulsive start's viscous drag, nonzero) to round-off."""
    cw = "[[-0.5, -0.5], [-0.5, 0.5], [0.5, 0.5], [0.5, -0.5]]"
    co = {}
    for name, pts in (("ccw", SQUARE), ("cw", cw)):
        pb = build_problem(_cfg("case.body=\"polygon\"", f"case.body_points={pts}", "case.r_far=2.0"))
        co[name] = {k: float(v) for k, v in pb.differentiable_metrics(pb.particles, 0.0, pb.params).items()}
    assert co["ccw"]["cd"] > 0.01, co
    for k, v in co["ccw"].items():
        assert abs(co["cw"][k] - v) <= 1e-12 * co["ccw"]["cd"], (k, co)


def test_a_body_thinner_than_the_support_is_refused():
    """A plate D x 0.1 D on a lattice of h = 0.1875 D: particles above and below it would be
    neighbours through it (their fluxes crossing the body), so the set-up refuses it naming the
    points and the resolution; a rectangle D x 0.5 D on the same lattice is accepted (pairs that
    clip its corners go around them), and so is a square; a wedge of 40 degrees is refused with
    the advice to round it (near a corner sharper than 60 degrees the excess does not shrink
    with the spacing)."""
    plate = "[[-0.5, -0.05], [0.5, -0.05], [0.5, 0.05], [-0.5, 0.05]]"
    with pytest.raises(InputError, match=r"case\.body_points=\[\[-0\.5, -0\.05\].* with case\.n_theta=32 and "
                                         r"case\.lattice_ratio=1\.5: particles .* are neighbours through the body .* "
                                         r"allowed: a finer layout"):
        build_problem(_cfg("case.body=\"polygon\"", f"case.body_points={plate}", "case.r_far=2.0"))
    thick = "[[-0.5, -0.25], [0.5, -0.25], [0.5, 0.25], [-0.5, 0.25]]"
    assert build_problem(_cfg("case.body=\"polygon\"", f"case.body_points={thick}", "case.r_far=2.0")).particles.n
    t = math.tan(math.radians(20.0))
    wedge = f"[[-0.6, 0.0], [0.6, {-1.2 * t!r}], [0.6, {1.2 * t!r}]]"
    with pytest.raises(InputError, match=r"corner sharper than 60 degrees .* round it"):
        build_problem(_cfg("case.body=\"polygon\"", f"case.body_points={wedge}", "case.r_far=2.0"))


@pytest.mark.parametrize("overrides, words", [
    (("case.body=\"polygon\"",), ["case.body_points=[]", "0 points", "at least 3"]),
    (("case.body=\"polygon\"", "case.body_points=[[-0.5, -0.5], [0.5, 0.5], [0.5, -0.5], [-0.5, 0.5]]"),
     ["case.body_points=[[-0.5, -0.5], [0.5, 0.5]", "crosses, touches", "simple closed curve"]),
    (("case.body=\"polygon\"", "case.body_points=[[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [0.0, -0.5], [-0.5, 0.5]]"),
     ["case.body_points", "crosses, touches"]),
    (("case.body=\"polygon\"", "case.body_points=[[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [0.9, 0.5], [0.7, 0.5], "
      "[-0.5, 0.5]]"), ["case.body_points", "turns back onto itself"]),
    (("case.body=\"polygon\"", "case.body_points=[[1.0, 1.0], [1.5, 1.0], [1.5, 1.5], [1.0, 1.5]]", "case.r_far=5.0"),
     ["case.body_points", "origin", "not inside the body"]),
    # a simple control polygon whose spline loops (the spline's own curve is tested)
    (("case.body=\"spline\"", "case.body_points=[[0.38, 0.22], [0.01, 0.08], [0.01, 0.2], [-0.08, -0.08], "
      "[0.06, -0.25], [0.2, -0.35]]"), ["case.body_points", "the spline through the points crosses, touches"]),
    (("case.body=\"spline\"", "case.body_points=[[0.5, 0.0], [0.0, 0.5], [0.0, 0.5], [-0.5, 0.0]]"),
     ["case.body_points", "point 1", "appears more than once"]),
    (("case.body=\"polygon\"", "case.body_points=[[0.0, 0.0], [0.5, 0.0], [1.0, 0.0]]"),
     ["case.body_points", "turns back onto itself"]),
    ((f"case.body_points={SQUARE}",), ["case.body_points", "case.body=\"circle\"", "case.body = \"polygon\""]),
    (("case.body=\"polygon\"", f"case.body_points={SQUARE}", "case.layout=\"polar\""),
     ["case.layout=\"polar\"", "case.body=\"polygon\"", "allowed: case.layout = \"cartesian\""]),
    (("case.body=\"spline\"", f"case.body_points={SQUARE}", "case.aspect=2.0"), ["case.aspect=2", "case.aspect = 1"]),
    (("case.body=\"polygon\"", "case.body_points=[[0.0, 1.0], [2.0]]"), ["case.body_points", "item 1"]),
])
def test_bad_point_bodies_name_the_key(overrides, words):
    """Too few points, an outline that crosses, touches (a vertex on another edge) or turns back
    onto itself (a spike; collinear points), a spline that loops although its points do not, a
    repeated point, a body not around its centre (the origin), points for a circle, a polar layout
    or an aspect ratio for a body given by points, a malformed point: ConfigError naming the key,
    its value and what is allowed."""
    over = list(overrides) if any("layout" in o for o in overrides) else ["case.layout=\"cartesian\"", *overrides]
    with pytest.raises(ConfigError) as e:
        config_mod.load(CONFIG_DIR / "cylinder.toml", ["case.n_theta=32", "case.r_far=2.0", *over])
    for w in words:
        assert w in str(e.value), (w, str(e.value))
