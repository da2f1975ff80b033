"""Reduced approximation degree is reported, never silent (issue 16 item 8, last defect).

The layout: a periodic box holding a square lattice (20 x 10 particles, y < 0.5) and, far from
it, a line of 40 small particles at y = 0.75 whose stencils hold only that line.  On a line a 2D
linear (let alone quadratic) fit is impossible (y - y_i = 0 on the whole stencil), so every line
particle must fall back to degree 0, and the ``corrected`` renormalisation matrix is singular
there (its y row is zero).  The expected degree of every particle is computed here
independently, in numpy, from the pivot criterion of docs/architecture.md decision 2 (the ratio
of each monomial's Schur complement to its own weighted norm, in the basis order, against
``scheme.rcond``); the state is uniform and at rest, so the run does not change the layout.
"""

from __future__ import annotations

import json
import warnings

import h5py
import numpy as np
import pytest

from mlsph_jax import approximation as apx
from mlsph_jax.approximation import basis
from mlsph_jax.checkpoint import read_checkpoint
from mlsph_jax.cli import main
from mlsph_jax.eos import get_eos, to_conservative
from mlsph_jax.errors import DegreeFallbackWarning, InputError
from mlsph_jax.integrate import static_geometry
from mlsph_jax.run import setup_run
from mlsph_jax.scheme import Scheme
from mlsph_jax.simulation import Problem, Simulation
from mlsph_jax.state import Domain, Params, make_particles
from mlsph_jax.testing import TAIT

N_LATTICE, N_LINE = 200, 40
BOX = Domain((0.0, 0.0), (1.0, 1.0), (True, True))
PARAMS = Params(TAIT)


def layout():
    """Positions and volumes: the lattice (spacing 0.05) and the line (spacing 0.025, volume
    0.025^2, so its support 2 h = 0.075 reaches only the line; the lattice's, 0.15, never reaches it)."""
    g = (np.arange(20) + 0.5) * 0.05
    xl = np.stack(np.meshgrid(g, g[:10], indexing="ij"), -1).reshape(-1, 2)
    xs = np.stack([(np.arange(N_LINE) + 0.5) * 0.025, np.full(N_LINE, 0.75)], -1)
    vol = np.concatenate([np.full(N_LATTICE, 0.05**2), np.full(N_LINE, 0.025**2)])
    return np.concatenate([xl, xs]), vol


def problem(frame="eulerian", t_end=2e-3, **scheme):
    x, vol = layout()
    n = len(x)
    U = to_conservative(np.ones(n), np.zeros((n, 2)), np.zeros(n), get_eos("tait"), PARAMS)
    sc = Scheme(eos="tait", frame=frame, beta=1.5, **scheme)
    p = make_particles(x, vol, U, ppd=np.full(n, sc.reconstruction_degree))
    return Problem("line_and_lattice", p, PARAMS, sc, BOX, t_end)


def _cubic(q):
    return np.where(q <= 1, 1 - 1.5 * q**2 + 0.75 * q**3, 0.25 * np.clip(2 - q, 0, None) ** 3)


def expected_degrees(degree: int, rcond: float, beta: float = 1.5):
    """Active MLS degree of every particle from the pivot criterion (numpy, brute-force stencils).

    Returns the degrees and the smallest distance |log(ratio / rcond)| of a deciding pivot (a
    layout must not sit on the threshold)."""
    x, vol = layout()
    h = beta * np.sqrt(vol)
    e = basis.exponents(degree, 2)                  # the basis order (x^2 before xy before y^2)
    level = e.sum(1)
    out, margin = [], np.inf
    for i in range(len(x)):
        y = x - x[i]
        y -= np.round(y)                            # minimum image in the unit box
        w = _cubic(np.linalg.norm(y, axis=1) / h[i])
        P = np.prod((y / h[i])[:, None, :] ** e[None], axis=-1)
        M = (P * w[:, None]).T @ P
        deg = degree
        for j in range(len(e)):
            s = M[j, j] - M[j, :j] @ np.linalg.solve(M[:j, :j], M[:j, j]) if j else M[0, 0]
            ratio = s / M[j, j] if M[j, j] > 0 else 0.0
            if ratio > 0:
                margin = min(margin, abs(np.log(ratio / rcond)))
            if ratio < rcond:
                deg = int(level[j]) - 1
                break
        out.append(deg)
    return np.asarray(out), margin


def expected_corrected():
    """1 where the renormalisation matrix sum_j V_j grad W_ij (x_j - x_i)^T is regular, 0 where it
    is singular (every stencil on the line: its y row is exactly zero)."""
    x, vol = layout()
    on_line = np.arange(len(x)) >= N_LATTICE
    return np.where(on_line, 0, 1)


@pytest.fixture(scope="module")
def pivots():
    deg, margin = expected_degrees(2, 1e-2)
    assert margin > 0.05, "a pivot ratio sits on scheme.rcond: the layout does not decide the degree"
    line = np.arange(len(deg)) >= N_LATTICE
    assert np.all(deg[line] == 0)                   # the layout's answer: no linear fit on a line
    x, _ = layout()
    inner = ~line & (x[:, 1] > 0.15) & (x[:, 1] < 0.35)
    assert np.all(deg[inner] == 2)                  # a full lattice stencil keeps the quadratic fit
    return deg


def test_geometry_carries_the_degree_of_every_particle(pivots):
    """Geometry.degree holds the area and fit degrees (no extra fit: they come from the builds)."""
    pb = problem()
    s = setup_run(pb)
    g = static_geometry(pb.particles, s.nl, pb.scheme, pb.domain)
    np.testing.assert_array_equal(np.asarray(g.degree[:, 0]), pivots)
    np.testing.assert_array_equal(np.asarray(g.degree[:, 1]), pivots)     # the fit reuses the area build
    # a cubic fit (reconstruction_degree 3) is a build of its own, with its own fallback
    pb3 = problem(reconstruction_degree=3)
    g3 = static_geometry(pb3.particles, s.nl, pb3.scheme, pb3.domain)
    np.testing.assert_array_equal(np.asarray(g3.degree[:, 0]), pivots)
    np.testing.assert_array_equal(np.asarray(g3.degree[:, 1]), expected_degrees(3, 1e-2)[0])


def test_run_reports_the_fraction_in_summary_and_fields(tmp_path, pivots):
    pb = problem()
    sim = Simulation(pb, chunk=4)
    with pytest.warns(DegreeFallbackWarning, match=r"output\.degree_fallback_warn = 0\.01"):
        res = sim.run(tmp_path, snapshots=2, progress=False, plots=False)
    frac, zero = np.mean(pivots < 2), np.mean(pivots == 0)       # every particle is fluid
    s = json.loads((tmp_path / "summary.json").read_text())["degree_fallback"]
    assert s == res.summary["degree_fallback"]
    for part in ("areas", "fit"):
        assert s[part]["nominal_degree"] == 2
        assert s[part]["reduced_fraction_max"] == pytest.approx(frac, abs=1e-15)
        assert s[part]["reduced_fraction_final"] == pytest.approx(frac, abs=1e-15)
    assert s["areas"]["zero_gradient_fraction_max"] == 0.0       # full derivative: no zero gradients
    assert s["fit"]["zero_gradient_fraction_max"] == pytest.approx(zero, abs=1e-15)
    assert s["warn_threshold"] == 0.01 and s["warn_key"] == "output.degree_fallback_warn"
    assert set(s["above_threshold"]) == {"area_reduced", "fit_reduced", "fit_zero_gradient"}
    with h5py.File(tmp_path / "fields.h5") as f:
        snaps = sorted(f["snapshots"])
        assert len(snaps) == 3
        for name in snaps:                          # Eulerian: the degrees of the one geometry, t = 0 included
            np.testing.assert_array_equal(f[f"snapshots/{name}/area_degree"][()], pivots)
            np.testing.assert_array_equal(f[f"snapshots/{name}/fit_degree"][()], pivots)
    assert 'Name="area_degree"' in (tmp_path / "fields.xmf").read_text()
    ck = read_checkpoint(tmp_path)                  # a restart continues the statistics
    np.testing.assert_array_equal(ck.degree[:, 0], pivots)
    np.testing.assert_allclose(ck.fallback, [frac, 0, frac, zero] * 2, rtol=0, atol=1e-15)


def test_warning_fires_above_the_threshold_and_not_below(pivots):
    frac = float(np.mean(pivots < 2))
    zero = float(np.mean(pivots == 0))
    pb = problem()
    sim = Simulation(pb, chunk=4)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        sim.run(None, snapshots=1, progress=False, degree_fallback_warn=frac * 1.001)
    assert not [w for w in caught if issubclass(w.category, DegreeFallbackWarning)]
    with pytest.warns(DegreeFallbackWarning) as rec:
        sim.run(None, snapshots=1, progress=False, degree_fallback_warn=frac * 0.999)
    msgs = [str(w.message) for w in rec if issubclass(w.category, DegreeFallbackWarning)]
    # area and fit below degree 2, and the fit's zero gradients: the line particles, all at degree 0
    assert zero == frac and len(msgs) == 3
    assert all(f"a fraction {frac:.3g} " in m and f"output.degree_fallback_warn = {frac * 0.999:g}" in m for m in msgs)
    with pytest.raises(InputError, match="degree_fallback_warn"):
        sim.run(None, snapshots=1, progress=False, degree_fallback_warn=1.5)


def test_moving_particles_carry_the_degree_through_the_scan(tmp_path, pivots):
    """Lagrangian frame (geometry rebuilt every stage, degrees carried out of the chunk) on the
    same layout at rest (linear areas, first order): the same fractions; the initial snapshot has
    -1 (no step yet)."""
    linear, _ = expected_degrees(1, 1e-2)
    assert np.all(linear[N_LATTICE:] == 0) and np.all(linear[:N_LATTICE] == 1)
    pb = problem(frame="lagrangian", degree=1, reconstruction_degree=0)
    with pytest.warns(DegreeFallbackWarning):
        res = Simulation(pb, chunk=4).run(tmp_path, snapshots=1, progress=False, plots=False)
    s = res.summary["degree_fallback"]
    assert s["areas"]["reduced_fraction_max"] == pytest.approx(np.mean(linear < 1), abs=1e-15)
    assert "fit" not in s                           # first order without viscosity: no fit
    with h5py.File(tmp_path / "fields.h5") as f:
        assert np.all(f["snapshots/00000/area_degree"][()] == -1) and "fit_degree" not in f["snapshots/00000"]
        np.testing.assert_array_equal(f["snapshots/00001/area_degree"][()], linear)


def test_corrected_kernel_gradient_fallback_is_counted():
    pb = problem(approximation="corrected", reconstruction_degree=0)
    s = setup_run(pb)
    g = static_geometry(pb.particles, s.nl, pb.scheme, pb.domain)
    expected = expected_corrected()
    np.testing.assert_array_equal(np.asarray(g.degree[:, 0]), expected)
    with pytest.warns(DegreeFallbackWarning, match="corrected -> kernel gradient"):
        res = Simulation(pb, chunk=4).run(None, snapshots=1, progress=False)
    a = res.summary["degree_fallback"]["areas"]
    assert a["nominal_degree"] == 1
    assert a["reduced_fraction_max"] == pytest.approx(N_LINE / (N_LATTICE + N_LINE), abs=1e-15)


def test_fixed_centre_zero_gradients_are_counted(pivots):
    """At degree-0 particles the fixed-centre derivative is exactly zero: the reported fraction is
    the fraction of particles whose gradient rows are all exactly zero."""
    pb = problem(derivative="fixed_centre", reconstruction_degree=0)
    s = setup_run(pb)
    p = pb.particles
    h = apx.smoothing_length(p.vol, 1.5, 2)
    ops = apx.build(p.x, h, p.vol, s.nl.idx, s.nl.mask, pb.scheme.area_spec(), np.ones(2), np.array([True, True]))
    zero = np.all(np.asarray(ops.gradients) == 0.0, axis=(1, 2))
    np.testing.assert_array_equal(zero, pivots == 0)
    with pytest.warns(DegreeFallbackWarning) as rec:
        res = Simulation(pb, chunk=4).run(None, snapshots=1, progress=False)
    msgs = sorted(str(w.message).split(" (")[0] for w in rec)
    assert msgs == ["MLS degree fallback of the area shape functions",
                    "exactly zero fixed-centre derivatives at degree-0 particles"]
    a = res.summary["degree_fallback"]["areas"]
    assert a["zero_gradient_fraction_max"] == pytest.approx(zero.mean(), abs=1e-15) and zero.mean() > 0


def test_cli_prints_one_line_per_warning(tmp_path, capsys):
    """``mlsph run`` with scheme.rcond above every pivot ratio of the 1D lattice (>= 0.2 but < 0.9):
    every particle falls back; one ``mlsph: warning:`` line names the fraction, threshold and key."""
    code = main(["run", "sod_ideal_gas", "--out", str(tmp_path / "o"), "--quiet", "--set", "case.n=40",
                 "time.t_end=0.002", "output.snapshots=1", "output.plots=false", "scheme.rcond=0.9"])
    assert code == 0
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.startswith("mlsph: warning: MLS degree fallback of the area")]
    assert len(lines) == 1 and "output.degree_fallback_warn = 0.01" in lines[0] and "a fraction 1 " in lines[0]
    s = json.loads((tmp_path / "o/summary.json").read_text())["degree_fallback"]
    assert s["areas"]["reduced_fraction_max"] == 1.0
