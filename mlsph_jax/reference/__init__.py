"""Host-side (numpy/scipy) reference solutions used by case metrics, plots and tests.

* :mod:`mlsph_jax.reference.riemann` — exact 1-D Riemann solvers for the ideal gas, the
  stiffened (Tammann) gas and the barotropic Tait EOS (Toro 2009 ch. 4; Ivings et al. 1998).
"""

from __future__ import annotations

from .riemann import EOS_KINDS, ExactRiemann, StarState, sample, star_state

__all__ = ["EOS_KINDS", "ExactRiemann", "StarState", "sample", "star_state"]
