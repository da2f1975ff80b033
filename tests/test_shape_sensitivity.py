"""Elliptic bodies and shape sensitivity of the ``cylinder`` case (issue 17 items 1 and 8;
docs/architecture.md decision 65): the conformally mapped layout, the ellipse that reproduces the
circle, the mirror symmetry at zero incidence and reverse-mode shape derivatives against central
finite differences."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from mlsph_jax import config as config_mod
from mlsph_jax.cases import build_problem
from mlsph_jax.cases.layouts import elliptic_polar_layout, polar_layout
from mlsph_jax.errors import ConfigError, InputError
from mlsph_jax.geometry import StreamEllipse
from mlsph_jax.testing import CONFIG_DIR

ALPHA, ASPECT = "geometry.body.alpha", "geometry.body.aspect"
SMALL = ("case.n_theta=32", "case.r_far=3.0", "case.mach=0.2", "output.plots=false", "output.progress=false",
         "time.local_time_stepping=false")


def _problem(*overrides):
    cfg = config_mod.load(CONFIG_DIR / "cylinder.toml", [*SMALL, *overrides])
    return cfg, build_problem(cfg)


# --- the mapped layout ----------------------------------------------------------------------

def _ellipse_frame(x, centre, angle):
    """Coordinates of x along / across the a-axis of an ellipse turned by ``angle``."""
    d = np.asarray(x) - np.asarray(centre)
    ca, sa = math.cos(angle), math.sin(angle)
    return d[:, 0] * ca + d[:, 1] * sa, -d[:, 0] * sa + d[:, 1] * ca


@pytest.mark.parametrize("a, b, angle, centre", [(0.5 * math.sqrt(2), 0.5 / math.sqrt(2), -0.3, (0.2, -0.1)),
                                                 (0.3, 0.9, 0.7, (0.0, 0.0)), (1.5, 0.5, 0.0, (1.0, 2.0))])
def test_mapped_layout_stays_outside_the_body_and_its_volumes_are_the_cell_areas(a, b, angle, centre):
    """Every particle lies outside the ellipse; each volume is the area of its mapped cell (the
    cell's boundary, images of the four polar edges at 4000 points each, by the shoelace formula, to
    1e-8); the volumes sum to the area between the body and the outer mapped ring, pi (rho^2 -
    c^4 / rho^2) - pi a b, to round-off."""
    lay = polar_layout(0.5, 32, 4.0, 3)
    x, vol = (np.asarray(v) for v in elliptic_polar_layout(lay.edges, 32, centre, (a, b), angle))
    u, v = _ellipse_frame(x, centre, angle)
    assert np.min((u / a) ** 2 + (v / b) ** 2) > 1.0 + 1e-3
    assert np.all(vol > 0)
    rho0, c2 = 0.5 * (a + b), 0.25 * (a * a - b * b)
    rho_out = rho0 / 0.5 * lay.edges[-1]
    area = math.pi * (rho_out ** 2 - c2 ** 2 / rho_out ** 2) - math.pi * a * b
    assert abs(vol.sum() - area) <= 1e-12 * area
    # cells of ring 0 and of ring 5 at three angles: the image of the cell's boundary
    s, dth = rho0 / 0.5, 2 * math.pi / 32
    for k, j in ((0, 0), (0, 7), (5, 20)):
        r1, r2 = s * lay.edges[k], s * lay.edges[k + 1]
        t1, t2 = j * dth, (j + 1) * dth
        m = 4000
        w = np.linspace(0, 1, m, endpoint=False)
        zeta = np.concatenate([(r1 + (r2 - r1) * w) * np.exp(1j * t1), r2 * np.exp(1j * (t1 + (t2 - t1) * w)),
                               (r2 - (r2 - r1) * w) * np.exp(1j * t2), r1 * np.exp(1j * (t2 - (t2 - t1) * w))])
        z = zeta + c2 / zeta
        cell = 0.5 * abs(np.sum(z.real * np.roll(z.imag, -1) - np.roll(z.real, -1) * z.imag))
        assert abs(vol[k * 32 + j] - cell) <= 1e-8 * cell, (k, j, vol[k * 32 + j], cell)


def test_mapped_layout_of_the_circle_is_the_polar_layout_bit_for_bit():
    lay = polar_layout(0.5, 48, 6.0, 4)
    x, vol = elliptic_polar_layout(lay.edges, 48, jnp.zeros(2), jnp.asarray([0.5, 0.5]), jnp.asarray(0.0))
    assert np.array_equal(np.asarray(x), lay.x) and np.array_equal(np.asarray(vol), lay.vol)


@pytest.mark.slow   # 22-27 s of compilation; the circle's own numbers are held by its fingerprint
def test_ellipse_of_aspect_one_is_the_circle_bit_for_bit():
    """case.body = ellipse with aspect 1 and alpha 0 gives the circle's particles, wall quadrature
    and right-hand side bit for bit (sqrt(1) = 1, sin(-0) = -0: every operation exact)."""
    from mlsph_jax.rhs import geometry, rhs
    from mlsph_jax.run import setup_run

    _, pc = _problem()
    _, pe = _problem("case.body=\"ellipse\"")
    for f in ("x", "vol", "q", "kind"):
        assert np.array_equal(np.asarray(getattr(pc.particles, f)), np.asarray(getattr(pe.particles, f))), f
    bc, be = pc.boundary.points(pc.params), pe.boundary.points(pe.params)
    for f in ("x", "dgamma", "normal", "velocity"):
        assert np.array_equal(np.asarray(getattr(bc, f)), np.asarray(getattr(be, f))), f
    out = []
    for pb in (pc, pe):
        nl = setup_run(pb).nl

        def rate(p, P, nl=nl, pb=pb):
            return rhs(p, P, geometry(p.x, p.vol, nl, pb.scheme, pb.domain), pb.scheme, pb.boundary)[2]

        out.append(np.asarray(jax.jit(rate)(pb.particles_at(pb.params), pb.params)))
    assert np.array_equal(out[0], out[1]) and np.abs(out[0]).max() > 0


# --- bad input ------------------------------------------------------------------------------

@pytest.mark.parametrize("field, value", [("aspect", 0.0), ("aspect", -2.0), ("aspect", float("nan")),
                                          ("alpha", float("nan")), ("alpha", float("inf")), ("radius", 0.0),
                                          ("incidence", "wing")])
def test_stream_ellipse_bad_input_names_the_key(field, value):
    with pytest.raises(InputError, match=rf"geometry\.body\.{field}=") as e:
        StreamEllipse("body", **{field: value})
    assert "allowed" in str(e.value)


@pytest.mark.parametrize("overrides, words", [
    (("case.body=\"ellipse\"", "case.aspect=0.0"), ["case.aspect", "0"]),
    (("case.body=\"ellipse\"", "case.alpha=nan"), ["case.alpha", "nan"]),
    (("case.body=\"ellipse\"", "case.alpha=120.0"), ["case.alpha", "120"]),
    (("case.aspect=2.0",), ["case.aspect=2", "case.body=\"circle\"", "allowed: case.body = \"ellipse\""]),
    (("case.body=\"square\"",), ["case.body", "square", "circle", "ellipse"]),
])
def test_bad_ellipse_configs_name_the_key(overrides, words):
    with pytest.raises(ConfigError) as e:
        config_mod.load(CONFIG_DIR / "cylinder.toml", list(overrides))
    for w in words:
        assert w in str(e.value), (w, str(e.value))


# --- derivatives ----------------------------------------------------------------------------

def _euler_coefficients(pb, steps: int = 1):
    """``f(theta) -> (C_D, C_L)`` of the state ``steps`` (0 or 1) forward-Euler steps (dt 2e-3)
    after the impulsive start, on the layout for the shape ``theta`` = {alpha, aspect} (the
    neighbour list of the problem's own layout)."""
    from mlsph_jax.differentiable import with_param
    from mlsph_jax.rhs import geometry, rhs
    from mlsph_jax.run import setup_run

    nl = setup_run(pb).nl

    def f(theta):
        P = pb.params
        for k, v in theta.items():
            P = with_param(P, k, v)
        p = pb.particles_at(P)
        if steps:
            g = geometry(p.x, p.vol, nl, pb.scheme, pb.domain)
            _, _, dq = rhs(p, P, g, pb.scheme, pb.boundary)
            p = p.replace(q=p.q + 2e-3 * dq)
        co = pb.differentiable_metrics(p, 0.0, P)
        return jnp.stack([co["cd"], co["cl"]])

    return f


def _fd(fj, th, k):
    h = 1e-5 * float(th[k])
    return (np.asarray(fj({**th, k: th[k] + h})) - np.asarray(fj({**th, k: th[k] - h}))) / (2 * h)


@pytest.mark.parametrize("steps", [0, pytest.param(1, marks=pytest.mark.slow)])
def test_zero_incidence_symmetry_and_shape_derivatives_match_fd(steps):
    """Physics and derivatives of the force coefficients of the impulsively started stream
    (``steps`` = 0: the body's wall state, Rusanov wall pressure and constrained viscous fit on the
    free stream; 1 (slow, ~40 s of compilation): after one forward-Euler step of the whole
    right-hand side, the MLS geometry included).  The layout and wall quadrature move with the
    aspect, the stream with alpha; forward-mode autodiff (``jax.jvp``, one compilation for every
    direction and the values).  For the ellipse A = 2 at alpha = 0 the flow is mirror-symmetric,
    so C_L = 0 and d C_D / d alpha = 0 (to round-off) while d C_L / d alpha != 0 (incidence makes
    lift); at alpha = 6 deg the derivatives w.r.t. alpha and aspect match central finite
    differences to 1e-6.  Reverse mode: the slow tests below."""
    _, pb = _problem("case.body=\"ellipse\"", "case.aspect=2.0")
    f = _euler_coefficients(pb, steps)
    both = jax.jit(lambda th, k: jax.jvp(f, (th,), (k,)))      # (value, derivative): one compilation
    unit = {k: {q: jnp.asarray(float(q == k)) for q in (ALPHA, ASPECT)} for k in (ALPHA, ASPECT)}
    fj = lambda th: both(th, unit[ALPHA])[0]  # noqa: E731
    jvp = lambda th, k: both(th, k)[1]  # noqa: E731
    th0 = {ALPHA: jnp.asarray(0.0), ASPECT: jnp.asarray(2.0)}
    (cd, cl), (dcd, dcl) = both(th0, unit[ALPHA])
    assert abs(float(cl)) <= 1e-12 * abs(float(cd))
    assert abs(float(dcd)) <= 1e-10 * abs(float(cd))
    assert abs(float(dcl)) > 1e-2 * abs(float(cd))
    th = {ALPHA: jnp.asarray(math.radians(6.0)), ASPECT: jnp.asarray(2.0)}
    for k in (ALPHA, ASPECT):
        fd, ad = _fd(fj, th, k), np.asarray(jvp(th, unit[k]))
        assert np.max(np.abs(ad - fd)) <= 1e-6 * np.max(np.abs(fd)), (k, ad, fd)
        assert np.all(np.abs(fd) > 0)


@pytest.mark.slow
def test_one_step_reverse_mode_shape_jacobian_matches_fd():
    """The same one-step coefficients by reverse mode (``jax.jacrev``): the Jacobian w.r.t.
    (alpha, aspect) at alpha = 6 deg matches central FD to 1e-6 (~60 s, mostly compilation)."""
    _, pb = _problem("case.body=\"ellipse\"", "case.aspect=2.0")
    f = _euler_coefficients(pb)
    th = {ALPHA: jnp.asarray(math.radians(6.0)), ASPECT: jnp.asarray(2.0)}
    J, fj = jax.jit(jax.jacrev(f))(th), jax.jit(f)
    for k in (ALPHA, ASPECT):
        fd = _fd(fj, th, k)
        assert np.max(np.abs(np.asarray(J[k]) - fd)) <= 1e-6 * np.max(np.abs(fd)), (k, J[k], fd)


@pytest.mark.slow
def test_whole_run_shape_gradient_matches_fd():
    """Reverse mode through a whole differentiated run (make_simulate, 40 global steps from the
    impulsive start, checkpoint "step"): d C_D(t_end) / d (alpha, aspect) of the ellipse A = 2 at
    alpha = 5 deg against central FD on the same compiled run, to 1e-4 relative (the issue's
    target); the objective goes through `mlsph_jax.sensitivity.sensitivity` (problem.particles_at)."""
    from mlsph_jax.sensitivity import sensitivity

    _, pb = _problem("case.body=\"ellipse\"", "case.aspect=2.0", "case.alpha=5.0")
    res = sensitivity(pb, [ALPHA, ASPECT], "cd", check_fd=True, n_steps=40, t_end=0.24, cfl=0.6,
                      checkpoint="step", record_every=40)
    for k in (ALPHA, ASPECT):
        e = res["gradients"][k]
        assert e["verdict"] == "agree", e
        assert abs(e["gradient"]) > 0
