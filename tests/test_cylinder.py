"""Flow past a cylinder (issue 17; SPEC §12.2 V9): the body-fitted polar layout, the frozen far
field, the boundary-integral body and the ``cylinder`` case."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mlsph_jax.cases.layouts import polar_layout, polar_ring_edges
from mlsph_jax.errors import InputError


@pytest.mark.parametrize("n_theta, r_far, n_extra", [(32, 10.0, 0), (48, 7.5, 4), (120, 40.0, 4)])
def test_polar_layout_volumes_are_the_annular_sectors(n_theta, r_far, n_extra):
    """The volumes of the fluid rings sum to the annulus area pi (r_far^2 - R^2) to round-off, each
    ring's to its own annulus, and every particle lies inside its own sector."""
    R = 0.5
    lay = polar_layout(R, n_theta, r_far, n_extra)
    n_rings = len(lay.edges) - 1 - n_extra
    assert lay.edges[0] == R and math.isclose(lay.edges[n_rings], r_far, rel_tol=1e-14)
    fluid = lay.ring < n_rings
    area = math.pi * (r_far ** 2 - R ** 2)
    assert abs(lay.vol[fluid].sum() - area) <= 1e-13 * area
    rings = np.bincount(lay.ring, weights=lay.vol)
    np.testing.assert_allclose(rings, math.pi * np.diff(lay.edges ** 2), rtol=1e-13)
    r = np.hypot(lay.x[:, 0], lay.x[:, 1])
    assert np.all((r > lay.edges[lay.ring]) & (r < lay.edges[lay.ring + 1]))
    # geometric growth with square cells: dr / (r dtheta) in (1 - dtheta, 1] for every ring
    ratio = np.diff(lay.edges) / (lay.edges[:-1] * 2 * math.pi / n_theta)
    assert np.allclose(ratio, ratio[0], rtol=1e-12) and 1 - 2 * math.pi / n_theta < ratio[0] <= 1 + 1e-12


def test_polar_layout_thesis_count():
    """The thesis' setup (V9): 120 points on the body and 10,800 particles (90 rings)."""
    lay = polar_layout(0.5, 120, 40.0, 4)
    assert len(lay.x) == 10_800 and len(lay.edges) - 1 == 90


@pytest.mark.parametrize("args, key", [((0.5, 4, 10.0), "n_theta=4"), ((0.5, 32, 0.4), "r_far=0.4"),
                                       ((-1.0, 32, 10.0), "radius=-1.0")])
def test_polar_layout_bad_input(args, key):
    with pytest.raises(InputError, match=key):
        polar_ring_edges(*args)
