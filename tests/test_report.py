"""The run report (issue 16 item 5): conservation changes relative to a meaningful scale and
labelled as drift (closed domain) or boundary-flux change; only errors listed as errors; the
printed wall time is summary.json's."""

from __future__ import annotations

import numpy as np
import pytest

from mlsph_jax import Kind, make_particles
from mlsph_jax.cli import result_paragraph
from mlsph_jax.simulation import _conservation, conserved_totals, split_metrics


def _particles(u, kind=None):
    n = len(u)
    x = np.stack([np.linspace(0, 1, n), np.zeros(n)], axis=1)
    vol = np.full(n, 0.5)
    U = np.column_stack([np.full(n, 2.0), 2.0 * np.asarray(u)])   # rho = 2, rho u
    return make_particles(x, vol, U, kind=kind)


def test_zero_total_momentum_is_scaled_by_the_flow_not_by_round_off():
    """Couette-like: momentum_y is zero by symmetry and changes by 1e-16 (round-off); the old
    report divided it by sum |V rho v| ~ 1e-15 and printed 0.1.  Walls -> boundary-flux label."""
    u = np.zeros((4, 2))
    u[:, 0] = [0.0, 0.25, 0.5, 1.0]
    u[:, 1] = [1e-16, -1e-16, 2e-16, 0.0]
    kind = [Kind.GHOST, Kind.FLUID, Kind.FLUID, Kind.FLUID]
    p0 = _particles(np.zeros((4, 2)), kind)
    p1 = _particles(u, kind)
    t0, t1 = conserved_totals(p0), conserved_totals(p1)
    out, info = _conservation(t0, t1, p0, p1)
    mass = 3 * 0.5 * 2.0
    assert info["scales"]["momentum_y"] == pytest.approx(mass * 1.0)        # M U, U = max |u| = 1
    assert abs(out["momentum_y"]) < 1e-15
    assert out["momentum_x"] == pytest.approx(0.5 * 2.0 * 1.75 / mass)
    assert out["mass"] == 0.0 and info["label"] == "change (boundary fluxes)"


def test_nonzero_initial_totals_are_the_scale_in_a_closed_domain():
    u0 = np.array([[1.0, 0.0], [1.0, 0.0], [1.0, 0.0]])
    u1 = u0 * (1 + 1e-12)
    p0, p1 = _particles(u0), _particles(u1)
    out, info = _conservation(conserved_totals(p0), conserved_totals(p1), p0, p1)
    assert info["label"] == "drift"
    assert info["scales"]["momentum_x"] == pytest.approx(3.0)       # the initial total
    assert out["momentum_x"] == pytest.approx(1e-12, rel=1e-3)
    assert out["momentum_y"] == 0.0


def test_only_errors_are_listed_as_errors():
    metrics = {"ke": 0.2, "ke_exact": 0.21, "ke_rel_error": 0.05, "l2_velocity_error": 0.01, "n_fluid": 100,
               "rho_max": 1.1, "l1_rho": 0.003, "ghia_u_rms_dev": 0.02, "overshoot": 0.01}
    errors, others = split_metrics(metrics)
    assert set(errors) == {"ke_rel_error", "l2_velocity_error", "l1_rho", "ghia_u_rms_dev"}
    assert set(others) == {"ke", "ke_exact", "n_fluid", "rho_max", "overshoot"}
    s = {"n_particles": 10, "t_final": 0.2, "n_steps": 7, "wall_time_s": 2.76, "compile_time_s": 1.0,
         "particle_updates_per_s": 1e5, "metrics": metrics, "conservation": {"mass": 0.0, "momentum_x": 0.34},
         "conservation_info": {"label": "change (boundary fluxes)", "scales": {}}}
    text = result_paragraph("Sod", s, "out/x")
    err_part = text.split("Errors against the reference:")[1].split("Other results:")[0]
    assert " ke =" not in err_part and "n_fluid" not in err_part and "rho_max" not in err_part
    assert "l1_rho = 0.003" in err_part and "ke_rel_error = 0.05" in err_part
    assert "Other results: ke = 0.2" in text
    assert "(2.8 s wall" in text          # summary.json's wall time
    assert "Relative change (boundary fluxes) of the totals" in text and "drift" not in text
