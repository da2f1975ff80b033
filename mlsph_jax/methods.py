"""Particle methods: the rule that turns shape functions into pair area vectors A_ij
(registry ``scheme.method``).

A method is an object with

* ``default_beta``: the smoothing-length factor h_i = beta V_i^(1/d) used when ``scheme.beta = 0``;
* ``areas(dx, h, vol, idx, mask, jsafe, rev, scheme) -> (A, values, coeffs[, degree])``: the area
  vectors ``A[N, K, d]`` (antisymmetric, A_ji = -A_ij), the method's own interpolation weights
  ``values[N, K]`` (N_j(x_i), or ``None`` when the method has none), when the area build
  already produced them, the fixed-centre fit coefficients reused by the reconstruction
  (``None`` otherwise) and, optionally, the per-particle degree of its shape functions after
  fallback (``ShapeOperators.degree``; :mod:`mlsph_jax.fallback`).  A method whose areas use
  ``scheme.approximation`` says so with ``uses_approximation = True``.

Built in:

* ``mlsph_ale``: A_ij = V_i grad N_j(x_i) - V_j grad N_i(x_j) with the shape functions of
  ``scheme.approximation`` (MLS by default; thesis eq. 4.36, 5.77);
* ``sph_ale``: A_ij = 2 V_i V_j grad_i W(x_i - x_j, h_ij), h_ij = (h_i + h_j)/2 (thesis eq. 3.5-3.7).
"""

from __future__ import annotations

import dataclasses

from . import approximation as apx
from .kernels import get_kernel
from .registry import Registry
from .stencil import reverse_gather

METHODS: Registry = Registry("scheme.method", protocol=("default_beta", "areas"),
                             doc="particle methods: the area-vector rule")


@dataclasses.dataclass(frozen=True)
class MLSPHALE:
    """MLSPH-ALE: MLS area vectors A_ij = V_i grad N_ji - V_j grad N_ij (thesis eq. 4.36, 5.77)."""

    default_beta: float = 1.5
    uses_approximation: bool = True

    def areas(self, dx, h, vol, idx, mask, jsafe, rev, scheme):
        aspec = scheme.area_spec()
        ops = apx.build_from_offsets(dx, h, vol, idx, mask, aspec)
        G = ops.gradients                              # grad N_j(x_i) = grad N_ji
        G_rev = reverse_gather(G, jsafe, rev)          # grad N_i(x_j) = grad N_ij
        A = vol[:, None, None] * G - vol[jsafe][..., None] * G_rev
        return A, ops.values, (ops.coeffs if aspec.with_coeffs else None), ops.degree


@dataclasses.dataclass(frozen=True)
class SPHALE:
    """SPH-ALE: kernel area vectors A_ij = 2 V_i V_j grad_i W(x_i - x_j, h_ij) (thesis eq. 3.5, 5.84)."""

    default_beta: float = 2.0

    def areas(self, dx, h, vol, idx, mask, jsafe, rev, scheme):
        hij = 0.5 * (h[:, None] + h[jsafe])
        gradW = get_kernel(scheme.kernel).grad(-dx, hij)        # grad_i W(x_i - x_j, h_ij)
        A = 2.0 * vol[:, None, None] * vol[jsafe][..., None] * gradW
        return A, None, None


METHODS.register("mlsph_ale", MLSPHALE())
METHODS.register("sph_ale", SPHALE())


def default_beta(method: str) -> float:
    """Smoothing-length factor of ``method`` used when ``scheme.beta = 0``."""
    return float(METHODS.get(method, "scheme.method").default_beta)
