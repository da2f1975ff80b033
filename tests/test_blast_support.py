"""Tests of the 2-D blast explosion support code (SPEC §12.1 V3, thesis §3.7.2).

* :mod:`mlsph_jax.cases.layouts` — ring / Delaunay-barycentre / perturbed particle layouts of a
  disc: volumes partition the disc, particles inside, counts ~ pi R^2 / dx^2, determinism,
  spacing, input errors.
* :mod:`mlsph_jax.reference.radial` — the 1-D radial finite-volume reference: planar limit vs
  the exact Tait Riemann solution, grid convergence, mass conservation, geometric spreading.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from mlsph_jax.cases.layouts import (
    DELAUNAY_SPACING,
    LAYOUTS,
    delaunay_barycentres,
    disc_layout,
    perturbed_barycentres,
    rings,
)
from mlsph_jax.errors import InputError
from mlsph_jax.reference.radial import RadialSolution, radial_tait_reference
from mlsph_jax.reference.riemann import ExactRiemann

R = 0.1
AREA = math.pi * R * R
TAIT = {"kind": "tait", "rho0": 1000.0, "c0": 1466.0, "gamma": 7.0, "p0": 0.0}
# rho_in, rho_out, r_interface, radius, t_end, rho0, c0, gamma (thesis §3.7.2 / SPEC V3)
BLAST = (1100.0, 1000.0, 0.05, R, 1e-5, 1000.0, 1466.0, 7.0)


# --- layouts ------------------------------------------------------------------------------

@pytest.mark.parametrize("name", sorted(LAYOUTS))
@pytest.mark.parametrize("dx", [4e-3, 2e-3])
def test_layout_partitions_disc(name, dx):
    x, vol = disc_layout(name, R, dx)
    assert x.shape == (len(vol), 2) and x.dtype == np.float64 and vol.dtype == np.float64
    assert np.all(np.isfinite(x)) and np.all(vol > 0.0)
    assert np.all(np.hypot(x[:, 0], x[:, 1]) < R)
    if name == "rings":
        assert vol.sum() == pytest.approx(AREA, rel=1e-12)
    else:
        assert vol.sum() == pytest.approx(AREA, rel=0.02)
        assert vol.sum() < AREA  # inscribed polygon
    # documented counts: N dx^2 / (pi R^2) ~ 1
    ratio = len(vol) * dx * dx / AREA
    assert 0.95 < ratio < 1.03, ratio
    # no clustered particles
    d, _ = cKDTree(x).query(x, k=2)
    assert d[:, 1].min() > 0.2 * dx
    # volumes comparable to dx^2 (one particle per dx^2)
    assert 0.3 * dx * dx < vol.min() and vol.max() < 3.0 * dx * dx


def test_rings_structure():
    dx = 4e-3
    x, vol = rings(R, dx)
    n_r = round(R / dx)
    n_k = [max(1, round(2 * math.pi * (k + 0.5))) for k in range(n_r)]
    assert len(x) == sum(n_k)
    radii = np.hypot(x[:, 0], x[:, 1])
    dr = R / n_r
    assert np.allclose(np.sort(np.unique(np.round(radii / dr - 0.5, 9))), np.arange(n_r))
    # equal volumes within a ring, rings in order
    start = 0
    for k, nk in enumerate(n_k):
        ring_vol = vol[start:start + nk]
        assert np.allclose(ring_vol, math.pi * (2 * k + 1) * dr * dr / nk, rtol=1e-13)
        assert np.allclose(radii[start:start + nk], (k + 0.5) * dr, rtol=1e-12)
        start += nk
    # alternate rings offset by half an angular step
    th1 = np.arctan2(x[3:3 + n_k[1], 1], x[3:3 + n_k[1], 0]) % (2 * np.pi)
    assert np.min(th1) == pytest.approx(np.pi / n_k[1])


def test_delaunay_spacing_constant():
    # an equilateral triangle of side DELAUNAY_SPACING * dx has area dx^2
    assert math.sqrt(3.0) / 4.0 * DELAUNAY_SPACING**2 == pytest.approx(1.0, rel=1e-14)


@pytest.mark.parametrize("fn", [delaunay_barycentres, perturbed_barycentres])
def test_layout_determinism(fn):
    a = fn(R, 4e-3, seed=3)
    b = fn(R, 4e-3, seed=3)
    c = fn(R, 4e-3, seed=4)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert a[0].shape != c[0].shape or not np.array_equal(a[0], c[0])


def test_perturbed_displacement():
    dx, amp = 2e-3, 0.2
    x0, v0 = delaunay_barycentres(R, dx, seed=1)
    x, v = perturbed_barycentres(R, dx, amplitude=amp, seed=1)
    np.testing.assert_array_equal(v, v0)  # volumes kept
    d = np.hypot(*(x - x0).T)
    assert np.all(d <= amp * np.sqrt(v0) * (1 + 1e-12))
    assert np.mean(d > 0) > 0.99  # (almost) every particle moved
    assert np.mean(d) > 0.3 * amp * np.sqrt(v0).mean()  # uniform in the disc: mean 2/3 of max
    assert np.all(np.hypot(x[:, 0], x[:, 1]) < R)
    x_zero, _ = perturbed_barycentres(R, dx, amplitude=0.0, seed=1)
    np.testing.assert_array_equal(x_zero, x0)


def test_thesis_resolution_counts():
    """Counts scale as pi R^2 / dx^2 (report in the module docstring)."""
    dx = 1e-3
    n_rings = len(rings(R, dx)[1])
    n_del = len(delaunay_barycentres(R, dx)[1])
    assert n_rings == pytest.approx(AREA / dx**2, rel=0.01)
    assert n_del == pytest.approx(AREA / dx**2, rel=0.02)


@pytest.mark.parametrize("bad", ["hexagon", "Rings", None, 3])
def test_layout_unknown_name(bad):
    with pytest.raises(InputError) as err:
        disc_layout(bad, R, 4e-3)
    msg = str(err.value)
    assert "case.layout" in msg and repr(bad) in msg
    for name in LAYOUTS:
        assert name in msg


@pytest.mark.parametrize("name", sorted(LAYOUTS))
@pytest.mark.parametrize("radius, dx, arg", [(0.0, 1e-3, "radius"), (-1.0, 1e-3, "radius"),
                                             (float("nan"), 1e-3, "radius"), (R, 0.0, "dx"),
                                             (R, -1e-3, "dx"), (R, R, "dx"), (R, 0.2, "dx"),
                                             (R, float("inf"), "dx"), ("a", 1e-3, "radius")])
def test_layout_bad_values(name, radius, dx, arg):
    with pytest.raises(InputError, match=rf"\b{arg}="):
        disc_layout(name, radius, dx)


def test_layout_bad_seed_and_amplitude():
    with pytest.raises(InputError, match="seed="):
        disc_layout("delaunay", R, 4e-3, seed=-1)
    with pytest.raises(InputError, match="seed="):
        disc_layout("perturbed", R, 4e-3, seed=1.5)
    with pytest.raises(InputError, match="amplitude="):
        disc_layout("perturbed", R, 4e-3, amplitude=-0.1)
    with pytest.raises(InputError, match="amplitude="):
        disc_layout("perturbed", R, 4e-3, amplitude=0.9)


# --- radial finite-volume reference ---------------------------------------------------------

def test_radial_planar_matches_exact_riemann():
    ref = radial_tait_reference(*BLAST, alpha=0, n=4000)
    assert isinstance(ref, RadialSolution) and ref.t == pytest.approx(1e-5)
    exact = ExactRiemann((1100.0, 0.0), (1000.0, 0.0), TAIT, x0=0.05)
    ex = exact(ref.r, 1e-5)
    err_rho = np.mean(np.abs(ref.rho - ex["rho"])) / 100.0
    assert err_rho < 0.01
    assert np.mean(np.abs(ref.u - ex["u"])) / np.max(np.abs(ex["u"])) < 0.02
    # interpolation API
    q = ref(np.array([0.0, 0.02, 0.05, 0.09]))
    assert set(q) >= {"rho", "u", "p"}
    assert q["rho"][0] == pytest.approx(1100.0) and q["rho"][-1] == pytest.approx(1000.0)


def _l1(a: RadialSolution, b: RadialSolution) -> float:
    """Mean |rho_a - rho_b| on the grid of ``b`` (the finer one)."""
    return float(np.mean(np.abs(a(b.r)["rho"] - b.rho)))


def test_radial_convergence():
    r250, r1000, r4000 = (radial_tait_reference(*BLAST, alpha=1, n=n) for n in (250, 1000, 4000))
    d_fine = _l1(r1000, r4000)
    d_coarse = _l1(r250, r1000)
    assert d_fine < 0.5 * d_coarse, (d_fine, d_coarse)


@pytest.mark.parametrize("alpha", [1, 2])
def test_radial_mass_conservation(alpha):
    ref = radial_tait_reference(*BLAST, alpha=alpha, n=4000)
    if alpha == 1:
        dr = ref.r[1] - ref.r[0]
        m0 = math.pi * (0.05**2 * 1100.0 + (R**2 - 0.05**2) * 1000.0)
        assert ref.initial_mass == pytest.approx(m0, rel=1e-13)
        assert np.sum(ref.rho * 2 * np.pi * ref.r * dr) == pytest.approx(m0, rel=1e-10)
    assert ref.mass == pytest.approx(ref.initial_mass, rel=1e-10)
    # the outgoing shock has not reached r = R: the far field is untouched
    assert ref.rho[-1] == pytest.approx(1000.0, rel=1e-12)


@pytest.mark.parametrize("alpha", [0, 1, 2])
def test_radial_rest_state_is_exact(alpha):
    ref = radial_tait_reference(1050.0, 1050.0, 0.05, R, 1e-6, 1000.0, 1466.0, 7.0, alpha=alpha,
                                n=200)
    assert np.max(np.abs(ref.u)) < 1e-12
    assert np.allclose(ref.rho, 1050.0, rtol=1e-14)


def test_radial_geometric_spreading():
    planar, cyl, sph = (radial_tait_reference(*BLAST, alpha=a, n=4000) for a in (0, 1, 2))
    exact = ExactRiemann((1100.0, 0.0), (1000.0, 0.0), TAIT, x0=0.05)
    shocked = planar.r > 0.05
    peak = [s.rho[shocked].max() for s in (planar, cyl, sph)]
    assert peak[0] == pytest.approx(exact.star.rho_r, rel=2e-3)
    assert peak[0] > peak[1] > peak[2] > 1000.0
    # the shock travels outwards, at about the same place in all geometries
    front = [s.r[np.nonzero(s.rho > 1000.5)[0].max()] for s in (planar, cyl, sph)]
    assert np.ptp(front) < 2e-3 and 0.06 < front[0] < 0.07
    # the rarefaction has not reached the centre yet at t = 1e-5 s
    assert cyl.rho[0] == pytest.approx(1100.0, rel=1e-10)


def test_radial_focusing_at_centre_stays_finite():
    # later time: the inward rarefaction has reflected at r = 0 (shock still inside the disc)
    ref = radial_tait_reference(1100.0, 1000.0, 0.05, R, 3e-5, 1000.0, 1466.0, 7.0, alpha=1,
                                n=1000)
    assert np.all(np.isfinite(ref.rho)) and np.all(np.isfinite(ref.u))
    assert 0.0 < ref.rho.min() and ref.rho.max() < 1100.0
    assert ref.rho[0] < 1000.0  # expansion focused at the centre
    assert abs(ref.u[0]) < 0.1 * np.max(np.abs(ref.u))  # u -> 0 at the axis
    assert ref.mass == pytest.approx(ref.initial_mass, rel=1e-10)


def test_radial_cache_and_readonly():
    a = radial_tait_reference(*BLAST, alpha=1, n=250)
    b = radial_tait_reference(*BLAST, alpha=1, n=250)
    assert a is b
    with pytest.raises(ValueError):
        a.rho[0] = 0.0


@pytest.mark.parametrize("kwargs, arg", [({"alpha": 3}, "alpha"), ({"n": 2}, "n"),
                                         ({"cfl": 0.0}, "cfl"), ({"cfl": 1.5}, "cfl"),
                                         ({"limiter": "superbee"}, "limiter"),
                                         ({"flux": "roe"}, "flux")])
def test_radial_bad_arguments(kwargs, arg):
    with pytest.raises(InputError, match=rf"\b{arg}="):
        radial_tait_reference(*BLAST, **kwargs)


def test_radial_bad_geometry():
    with pytest.raises(InputError, match="r_interface="):
        radial_tait_reference(1100.0, 1000.0, 0.2, R, 1e-5, 1000.0, 1466.0, 7.0)
    with pytest.raises(InputError, match="t_end="):
        radial_tait_reference(1100.0, 1000.0, 0.05, R, -1.0, 1000.0, 1466.0, 7.0)
    with pytest.raises(InputError, match="rho_in="):
        radial_tait_reference(-1.0, 1000.0, 0.05, R, 1e-5, 1000.0, 1466.0, 7.0)
