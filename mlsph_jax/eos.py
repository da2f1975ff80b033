"""Equations of state and conservative <-> primitive conversions (SPEC §2, thesis Table 3.1).

Conservative variables per unit volume (thesis eq. 2.6, 3.2, 4.3):

* EOS with an energy equation (``ideal_gas``, ``stiffened_gas``): U = (rho, rho u, rho E),
  nv = d + 2, E = e + |u|^2 / 2.
* barotropic ``tait``: the energy equation decouples (thesis L1150-1152, SPEC §1.5) and is not
  solved: U = (rho, rho u), nv = d + 1.

EOS constants come from the differentiable :class:`~mlsph_jax.state.Params` under the dotted
config keys (``eos.gamma``, ``eos.rho0``, ``eos.c0``, ``eos.p0``, ``eos.pc``).  Invalid states
(rho <= 0, p + pc <= 0) give NaN sound speeds instead of being clamped: the integrator's health
check and MOOD's PAD detector see them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping

import jax.numpy as jnp

from .registry import Registry


@dataclasses.dataclass(frozen=True)
class EOS:
    """An equation of state: ``pressure(rho, e, params)`` and ``sound_speed(rho, p, params)``.

    ``internal_energy(rho, p, params)`` inverts the pressure law (for initial conditions);
    ``admissible(rho, p, params)`` is the physical-admissibility test of a state (used by the
    run's health check and MOOD's PAD detector): rho > 0 always, plus the EOS' own condition;
    ``params_keys`` are the Params keys it reads (for an EOS registered from a user's script the
    ``[eos]`` config keys are derived from them, floats, with ``defaults`` where given);
    ``has_energy`` says whether rho E is solved.
    """

    name: str
    has_energy: bool
    params_keys: tuple[str, ...]
    pressure: Callable = dataclasses.field(compare=False, repr=False)
    sound_speed: Callable = dataclasses.field(compare=False, repr=False)
    internal_energy: Callable = dataclasses.field(compare=False, repr=False)
    admissible: Callable = dataclasses.field(compare=False, repr=False, default=None)
    defaults: Mapping[str, float] = dataclasses.field(compare=False, repr=False, default_factory=dict)

    def __post_init__(self):
        if self.admissible is None:   # default: positive, finite density and a finite pressure
            object.__setattr__(self, "admissible", lambda rho, p, P: (rho > 0) & jnp.isfinite(p))

    def n_vars(self, dim: int) -> int:
        return dim + (2 if self.has_energy else 1)


EOS_REGISTRY: Registry[EOS] = Registry(
    "eos.kind", protocol=("has_energy", "params_keys", "pressure", "sound_speed", "internal_energy", "admissible",
                          "n_vars"),
    doc="equations of state")


def _sqrt_or_nan(a):
    return jnp.sqrt(jnp.where(a > 0, a, jnp.nan))


# --- ideal gas: p = (gamma - 1) rho e, c^2 = gamma p / rho -------------------------------------
EOS_REGISTRY.register("ideal_gas")(EOS(
    "ideal_gas", True, ("eos.gamma",),
    pressure=lambda rho, e, P: (P["eos.gamma"] - 1.0) * rho * e,
    sound_speed=lambda rho, p, P: _sqrt_or_nan(P["eos.gamma"] * p / rho),
    internal_energy=lambda rho, p, P: p / ((P["eos.gamma"] - 1.0) * rho),
    admissible=lambda rho, p, P: (rho > 0) & (p > 0),
))

# --- stiffened gas / Tammann: p = (gamma - 1) rho e - gamma pc, c^2 = gamma (p + pc) / rho ----
EOS_REGISTRY.register("stiffened_gas")(EOS(
    "stiffened_gas", True, ("eos.gamma", "eos.pc"),
    pressure=lambda rho, e, P: (P["eos.gamma"] - 1.0) * rho * e - P["eos.gamma"] * P["eos.pc"],
    sound_speed=lambda rho, p, P: _sqrt_or_nan(P["eos.gamma"] * (p + P["eos.pc"]) / rho),
    internal_energy=lambda rho, p, P: (p + P["eos.gamma"] * P["eos.pc"]) / ((P["eos.gamma"] - 1.0) * rho),
    admissible=lambda rho, p, P: (rho > 0) & (p + P["eos.pc"] > 0),
))


# --- Tait (barotropic): p = rho0 c0^2 / gamma [(rho/rho0)^gamma - 1] + p0 ----------------------
def _power(r, a):
    """r^a for r > 0 (NaN stays NaN) as exp(a log r): ``r ** a`` to round-off (every built-in
    config's fingerprint within its tolerance), but XLA:CPU evaluates a float power element by element
    where exp and log are vectorised, and the derivative a r^a / r reuses the value where that of
    ``**`` is a second power (docs/performance.md, "The Tait power")."""
    return jnp.exp(a * jnp.log(r))


def _tait_p(rho, e, P):
    # in float64 whatever the state's precision: (rho/rho0)^gamma - 1 is a small difference of
    # numbers near 1 (1e-4 at Mach 0.1), which float32 would keep to three digits
    wide = lambda a: jnp.asarray(a, jnp.float64)
    r = jnp.where(rho > 0, wide(rho) / wide(P["eos.rho0"]), jnp.nan)
    p = wide(P["eos.rho0"]) * wide(P["eos.c0"]) ** 2 / wide(P["eos.gamma"]) * (_power(r, wide(P["eos.gamma"])) - 1.0) \
        + wide(P["eos.p0"])
    return p.astype(jnp.result_type(rho))


def _tait_c(rho, p, P):
    r = jnp.where(rho > 0, rho / P["eos.rho0"], jnp.nan)
    return P["eos.c0"] * _power(r, 0.5 * (P["eos.gamma"] - 1.0))


EOS_REGISTRY.register("tait")(EOS(
    "tait", False, ("eos.rho0", "eos.c0", "eos.gamma", "eos.p0"),
    pressure=_tait_p, sound_speed=_tait_c,
    internal_energy=lambda rho, p, P: jnp.zeros_like(rho),
    admissible=lambda rho, p, P: (rho > 0) & jnp.isfinite(p),   # a Tait pressure may be <= 0 (SPEC item 22)
))


def tait_density(p, P):
    """Inverse Tait law rho(p) = rho0 [1 + gamma (p - p0) / (rho0 c0^2)]^(1/gamma) (SPEC §2.1)."""
    g = P["eos.gamma"]
    return P["eos.rho0"] * (1.0 + g * (p - P["eos.p0"]) / (P["eos.rho0"] * P["eos.c0"] ** 2)) ** (1.0 / g)


def get_eos(kind: str) -> EOS:
    return EOS_REGISTRY.get(kind, "eos.kind")


@dataclasses.dataclass(frozen=True)
class Primitive:
    """Primitive fields: density, velocity [.., d], pressure, sound speed, specific internal energy."""

    rho: jnp.ndarray
    vel: jnp.ndarray
    p: jnp.ndarray
    c: jnp.ndarray
    e: jnp.ndarray


def to_primitive(U, eos: EOS, params) -> Primitive:
    """Primitive variables of conservative states ``U[..., nv]``."""
    d = U.shape[-1] - (2 if eos.has_energy else 1)
    rho = U[..., 0]
    vel = U[..., 1:1 + d] / rho[..., None]
    if eos.has_energy:
        e = U[..., 1 + d] / rho - 0.5 * jnp.sum(vel * vel, axis=-1)
    else:
        e = jnp.zeros_like(rho)
    p = eos.pressure(rho, e, params)
    c = eos.sound_speed(rho, p, params)
    return Primitive(rho, vel, p, c, e)


def to_conservative(rho, vel, p, eos: EOS, params):
    """Conservative states ``[..., nv]`` from density, velocity ``[..., d]`` and pressure.

    For Tait the pressure argument is ignored (it follows from rho).
    """
    rho = jnp.asarray(rho)
    mom = rho[..., None] * vel
    if not eos.has_energy:
        return jnp.concatenate([rho[..., None], mom], axis=-1)
    e = eos.internal_energy(rho, p, params)
    E = rho * (e + 0.5 * jnp.sum(vel * vel, axis=-1))
    return jnp.concatenate([rho[..., None], mom, E[..., None]], axis=-1)


def primitive_vector(U, eos: EOS, params):
    """(rho, u, p) packed as ``[..., nv]`` (Tait: (rho, u)); used for primitive reconstruction."""
    pr = to_primitive(U, eos, params)
    parts = [pr.rho[..., None], pr.vel]
    if eos.has_energy:
        parts.append(pr.p[..., None])
    return jnp.concatenate(parts, axis=-1)


def from_primitive_vector(W, eos: EOS, params):
    """Inverse of :func:`primitive_vector`."""
    d = W.shape[-1] - (2 if eos.has_energy else 1)
    p = W[..., 1 + d] if eos.has_energy else None
    return to_conservative(W[..., 0], W[..., 1:1 + d], p, eos, params)


def conservative_components(W, eos: EOS, params):
    """:func:`from_primitive_vector` on a list of component arrays ``W = [rho, u.., (p)]``
    (structure of arrays); returns the list ``[rho, rho u.., (rho E)]``."""
    d = len(W) - (2 if eos.has_energy else 1)
    rho, vel = W[0], W[1:1 + d]
    out = [rho] + [rho * u for u in vel]
    if eos.has_energy:
        ke = vel[0] * vel[0]
        for u in vel[1:]:
            ke = ke + u * u
        out.append(rho * (eos.internal_energy(rho, W[1 + d], params) + 0.5 * ke))
    return out
