"""mlsph-jax: differentiable meshless finite-volume particle methods in JAX.

Importing the package enables float64 in JAX (``jax_enable_x64``): Tait water pressures reach
1e8-5e9 Pa while the differences that drive the flow are small, and quadratic MLS moment
matrices are poorly conditioned in float32 (SPEC §5.9).  Set the environment variable
``MLSPH_JAX_FLOAT32=1`` before import to keep JAX's float32 default (GPU throughput studies).
"""

from __future__ import annotations

import os as _os

import jax as _jax

if _os.environ.get("MLSPH_JAX_FLOAT32", "0") != "1":
    _jax.config.update("jax_enable_x64", True)

__version__ = "0.1.0"

from . import wall_integral as _wall_integral  # noqa: E402,F401  (registers the boundary_integral wall treatment)
from .errors import (  # noqa: E402
    ConfigError,
    InputError,
    MLSPHError,
    NeighborOverflowError,
    RunInterrupted,
    SimulationError,
)
from .point_cloud import ShapeFunctions, shape_functions  # noqa: E402
from .state import Domain, Kind, Params, Particles, make_particles  # noqa: E402

__all__ = [
    "__version__",
    "ConfigError",
    "Domain",
    "InputError",
    "Kind",
    "MLSPHError",
    "NeighborOverflowError",
    "Params",
    "Particles",
    "RunInterrupted",
    "ShapeFunctions",
    "SimulationError",
    "make_particles",
    "shape_functions",
]

