"""Reduced approximation degree: what each particle's shape functions and fit actually reproduce.

Three approximations lower their degree per particle, silently for the numbers:

* MLS (``approximation = "mls"``/``"shepard"``; the fixed-centre fit of the reconstruction and
  the viscous gradients): the pivot-ratio fallback of :mod:`mlsph_jax.approximation.mls`
  (decision 2: a degree level whose pivot ratio s_j / M_jj < ``scheme.rcond`` is dropped;
  ``scheme.wall_rcond`` in truncated stencils, decision 77);
* ``corrected``: the Randles-Libersky gradient (exact for linear fields, degree 1) falls back to
  the kernel gradient (degree 0) where the renormalisation matrix is singular;
* fixed-centre derivatives (``scheme.derivative = "fixed_centre"``, and the fit, which is always
  fixed-centre) at a particle of degree 0 are exactly zero: the linear monomials are dropped.

The geometry (:func:`mlsph_jax.rhs.geometry`) carries each particle's active degree as
``Geometry.degree[N, 2]``: column :data:`AREA` the shape functions of the area vectors (-1: the
method has none with a degree, i.e. ``kernel`` and ``sph_ale``), column :data:`FIT` the
reconstruction/viscous fit (-1: no fit).  The step keeps the smallest degree of its three stages
(:func:`mlsph_jax.integrate.ssp_rk3_step`) and the scan carry holds it with the statistics of
:data:`STATS` (:func:`step_fractions`, :func:`update_stats`): no extra fit, no host
synchronisation.  The driver writes the degrees per snapshot (``area_degree``, ``fit_degree``),
the statistics to ``summary.json`` (:func:`summary`) and warns (:class:`DegreeFallbackWarning`)
when a fraction exceeds ``output.degree_fallback_warn``.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .state import Kind

__all__ = ["AREA", "DEFAULT_WARN", "FIT", "STATS", "WARN_KEY", "exceeded", "initial_degrees", "initial_stats",
           "nominal_degrees", "snapshot_fields", "stack", "step_fractions", "summary", "update_stats"]

AREA, FIT = 0, 1
#: Fractions of fluid particles per step: below the nominal degree and with exactly-zero
#: (fixed-centre, degree-0) derivatives, for the area shape functions and for the fit.
STATS = ("area_reduced", "area_zero_gradient", "fit_reduced", "fit_zero_gradient")
#: The config key of the warning threshold and its default.
WARN_KEY = "output.degree_fallback_warn"
DEFAULT_WARN = 0.01


def stack(area, fit, n: int):
    """``degree[N, 2]`` (int32) from the area and fit degrees (``None``: -1, not applicable)."""
    none = jnp.full((n,), -1, jnp.int32)
    cols = [none if c is None else jnp.asarray(c, jnp.int32) for c in (area, fit)]
    return jnp.stack(cols, axis=1)


def initial_degrees(n: int):
    """Per-particle degrees before any step: -1 (not evaluated)."""
    return jnp.full((n, 2), -1, jnp.int32)


def initial_stats():
    """``[max over the steps (4), last step (4)]`` of :data:`STATS`, all zero."""
    return jnp.zeros(2 * len(STATS))


def nominal_degrees(scheme) -> tuple[int | None, int | None]:
    """``(area, fit)``: the degree each would have without fallback (``None``: not applicable).

    An approximation states it with ``nominal_degree(degree)`` (MLS: its basis degree;
    ``corrected``: 1; ``kernel``: ``None``); methods without shape-function areas (``sph_ale``) and
    schemes without a fit have ``None``."""
    area = None
    if getattr(scheme.component("method"), "uses_approximation", False):
        approx = scheme.component("approximation")
        nominal = getattr(approx, "nominal_degree", None)
        area = nominal(scheme.degree) if nominal is not None else None
    return area, (scheme.fit_degree if scheme.needs_fit else None)


def _zero_gradient_possible(scheme) -> tuple[bool, bool]:
    """Whether degree 0 means exactly-zero derivatives, for the areas and for the fit."""
    approx = scheme.component("approximation")
    area = bool(getattr(approx, "has_coeffs", False)) and scheme.derivative == "fixed_centre"
    return area, True


def step_fractions(degree, kind, scheme, count=jnp.sum):
    """Fractions (:data:`STATS`) of the fluid particles for the per-particle ``degree[N, 2]``
    (traceable; -1, not evaluated, counts as neither; ``count(mask)``: the number of particles
    where ``mask`` holds, over every shard of a spatially decomposed run)."""
    fluid = kind == Kind.FLUID
    n = jnp.maximum(count(fluid), 1)
    out = []
    for col, nominal, zero_ok in zip((AREA, FIT), nominal_degrees(scheme), _zero_gradient_possible(scheme),
                                     strict=True):
        d = degree[:, col]
        if nominal is None:
            out += [jnp.zeros(()), jnp.zeros(())]
            continue
        out.append(count(fluid & (d >= 0) & (d < nominal)) / n)
        out.append(count(fluid & (d == 0)) / n if zero_ok else jnp.zeros(()))
    return jnp.stack(out).astype(jnp.float64)


def update_stats(stats, fractions):
    """The carry's statistics after a committed step with ``fractions``."""
    k = len(STATS)
    return jnp.concatenate([jnp.maximum(stats[:k], fractions), fractions]).astype(stats.dtype)


def _what(scheme) -> dict[str, str]:
    approx = scheme.approximation
    rc = (f"scheme.rcond = {scheme.rcond:g}; truncated stencils max(rcond, scheme.wall_rcond) = "
          f"{scheme.wall_fit_rcond:g}")
    area = (f"corrected -> kernel gradient fallback (scheme.approximation = {approx!r})" if approx == "corrected"
            else f"MLS degree fallback of the area shape functions (scheme.approximation = {approx!r}, {rc})")
    return {"area_reduced": area,
            "area_zero_gradient": "exactly zero fixed-centre derivatives at degree-0 particles (scheme.derivative = "
                                  "'fixed_centre')",
            "fit_reduced": f"MLS degree fallback of the reconstruction/viscous fit ({rc})",
            "fit_zero_gradient": "exactly zero gradients of the reconstruction/viscous fit at degree-0 particles"}


def summary(stats, scheme, threshold: float) -> dict:
    """The ``degree_fallback`` entry of ``summary.json``: per approximation in use (``areas``,
    ``fit``) its nominal degree and the largest (over the steps) and final fractions of fluid
    particles below it and with exactly-zero derivatives; the threshold and the items above it."""
    st = np.asarray(stats, dtype=float)
    k = len(STATS)
    top, last = dict(zip(STATS, st[:k].tolist(), strict=True)), dict(zip(STATS, st[k:].tolist(), strict=True))
    area, fit = nominal_degrees(scheme)
    out = {"warn_threshold": float(threshold), "warn_key": WARN_KEY}
    what = _what(scheme)
    for name, prefix, nominal, approx, deriv in (
            ("areas", "area", area, scheme.approximation, scheme.derivative),
            ("fit", "fit", fit, "mls", "fixed_centre")):
        if nominal is None:
            continue
        out[name] = {"approximation": approx, "nominal_degree": int(nominal), "derivative": deriv,
                     "fallback": what[f"{prefix}_reduced"]}
        for s in ("reduced", "zero_gradient"):
            out[name][f"{s}_fraction_max"] = top[f"{prefix}_{s}"]
            out[name][f"{s}_fraction_final"] = last[f"{prefix}_{s}"]
    out["above_threshold"] = [s for s, _ in exceeded(stats, scheme, threshold)]
    return out


def exceeded(stats, scheme, threshold: float) -> list[tuple[str, str]]:
    """``[(stat, message)]`` for every :data:`STATS` entry whose largest fraction exceeds ``threshold``."""
    st = np.asarray(stats, dtype=float)
    k = len(STATS)
    what = _what(scheme)
    out = []
    for i, s in enumerate(STATS):
        if st[i] > threshold:
            out.append((s, f"{what[s]}: a fraction {st[i]:.3g} of the fluid particles in a step ({st[k + i]:.3g} "
                           f"in the last), above {WARN_KEY} = {threshold:g}"))
    return out


def snapshot_fields(degree, scheme) -> dict[str, np.ndarray]:
    """Per-particle datasets of a snapshot: ``area_degree`` and ``fit_degree`` where applicable."""
    d = np.asarray(degree)
    area, fit = nominal_degrees(scheme)
    out = {}
    if area is not None:
        out["area_degree"] = d[:, AREA].astype(np.int32)
    if fit is not None:
        out["fit_degree"] = d[:, FIT].astype(np.int32)
    return out
