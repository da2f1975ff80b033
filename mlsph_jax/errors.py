"""Exception types of mlsph-jax.

Every error raised for bad input names the argument (or config key), the value received and
what is allowed, so that a user can fix the call without reading the source.
"""

from __future__ import annotations


class MLSPHError(Exception):
    """Base class of all mlsph-jax errors."""


class InputError(MLSPHError, ValueError):
    """A function argument is invalid (wrong value, shape, type or non-finite data)."""


class ConfigError(MLSPHError, ValueError):
    """A configuration key is unknown, missing, of the wrong type or out of range."""


class SimulationError(MLSPHError, RuntimeError):
    """A simulation went wrong (NaN, inadmissible state, negative density/volume, time step
    underflow or above the CFL limit, unresolved MOOD flags, neighbour overflow).

    Attributes carry where it happened so that callers can report it: ``step``, ``time``,
    ``particle`` (index of the first offending particle, or ``None``) and ``status`` (the
    :class:`mlsph_jax.status.Status` bits, or ``None``).
    """

    def __init__(self, message: str, *, step: int | None = None, time: float | None = None,
                 particle: int | None = None, status=None):
        super().__init__(message)
        self.step = step
        self.time = time
        self.particle = particle
        self.status = status


class NeighborOverflowError(SimulationError):
    """A fixed-capacity neighbour list (or cell) overflowed and could not be regrown (a
    :class:`SimulationError`: a differentiated run cannot regrow, the driver gives up after
    repeated regrowths)."""


class RunInterrupted(MLSPHError):
    """A run was stopped by SIGINT (Ctrl-C) or SIGTERM.  The driver finished the chunk it was
    in and wrote the last good state (snapshot and ``checkpoint.h5``), ``summary.json`` with
    ``status = "interrupted"``, ``timeseries.csv`` and the plots before raising this.

    Attributes: ``result`` (the :class:`~mlsph_jax.simulation.Result` of the part that ran) and
    ``signal`` (the signal number)."""

    def __init__(self, message: str, *, result=None, signal: int | None = None):
        super().__init__(message)
        self.result = result
        self.signal = signal


class DegreeFallbackWarning(UserWarning):
    """A run used a reduced approximation degree at more fluid particles than
    ``output.degree_fallback_warn`` allows (MLS degree fallback, the ``corrected`` -> kernel
    gradient fallback, or exactly-zero fixed-centre derivatives at degree-0 particles; see
    :mod:`mlsph_jax.fallback`).  The message names the fraction, the threshold and the key."""


class LayoutWarning(UserWarning):
    """A particle layout that builds but is known to spoil results (e.g. a lattice whose first row
    lies far from a body's wall over a stretch of it); the message names the keys, the measured
    value and what to change."""


def invalid(argument: str, value, allowed: str) -> InputError:
    """Build the standard bad-argument error: names the argument, the value and what is allowed."""
    return InputError(f"invalid {argument}={value!r}; allowed: {allowed}")
