"""Far-field treatments of the FROZEN outer particles (thesis §4.5.2, "free-stream values are
imposed at the outer boundary", method unspecified; SPEC §5.8, §8.5; issue 17 item 3).

A far field is a few rings (or, in 1D, a few particles) of :attr:`~mlsph_jax.state.Kind.FROZEN`
particles beyond the fluid: the integrator never updates them, they act as neighbours of the
fluid (in its fluxes, reconstruction and gradients), and the far-field treatment decides what
state they hold.  Registry ``case.far_field`` (:data:`FAR_FIELDS`), protocol ``setup(particles,
eos, reference) -> object or None``; the object's ``apply(particles, params)`` is called before
every Runge-Kutta stage and after each step, like a wall treatment's.

``frozen``
    The frozen particles keep the free-stream state they start with, bit for bit (SPEC §5.8
    [REC]).  Simple and exact for a uniform stream, but a fixed state: an outgoing wave or the
    wake meets a boundary that holds the free-stream pressure and velocity, and part of it is
    reflected.

``characteristic``
    The classical Riemann-invariant far field of finite-volume codes (e.g. Blazek,
    *Computational Fluid Dynamics: Principles and Applications*, §8.5; Jameson & Baker 1983),
    applied to the frozen particles as the ghost cells of a mesh code: each frozen particle f
    takes the state whose one-dimensional characteristics along the outward normal n_f come
    from where they start.  With the interior state i (the nearest fluid particle, found once
    at set-up: far fields belong to Eulerian runs) and the free stream inf at x_f,

        R+ = u_i . n + 2 c_i / (gamma - 1)      (outgoing: from the interior)
        R- = u_inf . n - 2 c_inf / (gamma - 1) (incoming: from the free stream)
        u_n = (R+ + R-) / 2,   c = (gamma - 1) (R+ - R-) / 4,

    and the tangential velocity and the entropy from the interior where the flow leaves
    (u_n >= 0) and from the free stream where it enters; at supersonic normal speed every
    characteristic comes from one side (outflow: the interior state, inflow: the free stream).
    The invariants u +- 2c / (gamma - 1) are exact for the isentropic flow of every registered
    EOS: ideal gas and stiffened gas (entropy s = (p + pc) / rho^gamma, pc = 0 for the ideal
    gas, c^2 = gamma (p + pc) / rho) and Tait (barotropic, c = c0 (rho / rho0)^((gamma-1)/2), so
    int c drho / rho = 2 c / (gamma - 1) as well).  A uniform free stream is kept exactly (the
    interior state equals the free stream there, and so does the characteristic state); an
    outgoing simple wave leaves with its incoming invariant R- unchanged, so it is not reflected
    to first order (``tests/test_far_field.py`` measures the reflection of an acoustic pulse).

``inflow_outflow``
    A velocity inlet and pressure outlet (the boundaries of channel-type domains): where the free
    stream enters (u_inf . n < 0) its velocity and density with the interior's pressure, where it
    leaves the interior's velocity and density with the free stream's pressure.  It pins the
    pressure level, but the outlet reflects acoustic waves (p' = 0 there).

Measurements of all three on the cylinder and on a 1D acoustic pulse: docs/validation.md,
"Far-field options"; docs/architecture.md decision 68.

The outward normal of a frozen particle is the unit vector from its interior particle to it
(radial on the cylinder's polar rings, +-x at the ends of a tube).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from .eos import get_eos, to_conservative, to_primitive
from .errors import InputError
from .registry import Registry
from .state import Kind, Particles

#: Far-field treatments (config key ``case.far_field`` of the cases with a far field).
FAR_FIELDS: Registry = Registry("case.far_field", protocol=("setup",),
                                doc="states of the frozen far-field particles")

#: EOS whose isentropic invariants are u +- 2 c / (gamma - 1) (module docstring).
_INVARIANT_EOS = ("ideal_gas", "stiffened_gas", "tait")


def _pc(eos: str, params):
    """The stiffened gas' pressure constant (0 for the ideal gas)."""
    return params["eos.pc"] if eos == "stiffened_gas" else 0.0


def _entropy(rho, p, eos: str, params):
    """s = (p + pc) / rho^gamma (ideal gas: pc = 0); unused for Tait (barotropic)."""
    return (p + _pc(eos, params)) / rho ** params["eos.gamma"]


def _state_from(c, s, eos: str, params):
    """``(rho, p)`` of sound speed ``c`` and entropy ``s`` (Tait: of sound speed alone)."""
    g = params["eos.gamma"]
    if eos == "tait":
        rho = params["eos.rho0"] * (c / params["eos.c0"]) ** (2.0 / (g - 1.0))
        return rho, None
    rho = (c * c / (g * s)) ** (1.0 / (g - 1.0))
    return rho, rho * c * c / g - _pc(eos, params)


def inflow_outflow_state(inner, outer, normal, eos: str, params):
    """``(rho, vel, p)`` of the velocity-inlet / pressure-outlet far field (module docstring):
    where the free stream enters (u_inf . n < 0) its velocity and density with the interior's
    pressure; where it leaves, the interior's velocity and density with the free stream's
    pressure (Tait: density is pressure, so the inlet takes the interior's, the outlet the free
    stream's)."""
    rho_i, u_i, p_i, _ = inner
    rho_o, u_o, p_o, _ = outer
    inflow = jnp.sum(u_o * normal, axis=-1) < 0.0
    vel = jnp.where(inflow[:, None], u_o, u_i)
    if eos == "tait":
        return jnp.where(inflow, rho_i, rho_o), vel, None
    return jnp.where(inflow, rho_o, rho_i), vel, jnp.where(inflow, p_i, p_o)


def characteristic_state(inner, outer, normal, eos: str, params):
    """``(rho, vel, p)`` of the Riemann-invariant far-field state (module docstring) from the
    interior primitives ``inner`` and the free-stream primitives ``outer`` (each ``(rho, vel, p,
    c)``, vel ``[F, d]``) along the outward unit ``normal[F, d]`` (p is None for Tait)."""
    g = params["eos.gamma"]
    rho_i, u_i, p_i, c_i = inner
    rho_o, u_o, p_o, c_o = outer
    un_i = jnp.sum(u_i * normal, axis=-1)
    un_o = jnp.sum(u_o * normal, axis=-1)
    k = 2.0 / (g - 1.0)
    r_plus = jnp.where(un_o <= -c_o, un_o + k * c_o, un_i + k * c_i)     # supersonic inflow: all from outside
    r_minus = jnp.where(un_i >= c_i, un_i - k * c_i, un_o - k * c_o)     # supersonic outflow: all from inside
    un = 0.5 * (r_plus + r_minus)
    c = 0.25 * (g - 1.0) * (r_plus - r_minus)
    out = un >= 0.0
    tangential = jnp.where(out[:, None], u_i - un_i[:, None] * normal, u_o - un_o[:, None] * normal)
    vel = tangential + un[:, None] * normal
    if eos == "tait":
        rho, p = _state_from(c, None, eos, params)
        return rho, vel, p
    s = jnp.where(out, _entropy(rho_i, p_i, eos, params), _entropy(rho_o, p_o, eos, params))
    rho, p = _state_from(c, s, eos, params)
    return rho, vel, p


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class CharacteristicFarField:
    """The ``characteristic`` far field (module docstring): frozen particle ``frozen[f]`` takes
    the Riemann-invariant state of its interior particle ``source[f]`` and the free stream
    ``reference(x, params) -> (rho, vel[.., d], p)`` along ``normal[f]``."""

    frozen: jax.Array      # [F] int
    source: jax.Array      # [F] int
    normal: jax.Array      # [F, d]
    eos: str = dataclasses.field(metadata=dict(static=True))
    reference: Callable = dataclasses.field(metadata=dict(static=True))
    #: the state of the frozen particles: :func:`characteristic_state` or :func:`inflow_outflow_state`
    state: Callable = dataclasses.field(metadata=dict(static=True), default=characteristic_state)

    def apply(self, p: Particles, params) -> Particles:
        """The frozen particles' conserved states ``q = V U`` set to the characteristic state
        of the current interior (positions and volumes untouched).  The invariants compare the
        interior with the free stream at the interior particle, and the free stream's own change
        from there to the frozen particle is added (primitive variables): a non-uniform free
        stream, such as the hydrostatic atmosphere under a body force, is then kept exactly."""
        eos = get_eos(self.eos)
        inner = to_primitive(p.q[self.source] / p.vol[self.source][:, None], eos, params)
        ref_s, ref_f = (self._reference(p.x[idx], params, eos) for idx in (self.source, self.frozen))
        normal = self.normal.astype(p.q.dtype)   # float32 runs: the set-up normals are float64
        rho, vel, pres = self.state((inner.rho, inner.vel, inner.p, inner.c), ref_s, normal, self.eos, params)
        rho, vel = rho + ref_f[0] - ref_s[0], vel + ref_f[1] - ref_s[1]
        pres = None if pres is None else pres + ref_f[2] - ref_s[2]
        U = to_conservative(rho, vel, pres, eos, params)
        return p.replace(q=p.q.at[self.frozen].set((p.vol[self.frozen][:, None] * U).astype(p.q.dtype)))

    def _reference(self, x, params, eos):
        """``(rho, vel, p, c)`` of the free stream at ``x``."""
        rho, vel, pres = (None if a is None else jnp.asarray(a, x.dtype) for a in self.reference(x, params))
        if not eos.has_energy:
            pres = eos.pressure(rho, jnp.zeros_like(rho), params)
        return rho, vel, pres, eos.sound_speed(rho, pres, params)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class WithFarField:
    """A wall treatment ``walls`` (e.g. the cylinder's boundary-integral body) and a far field
    ``far`` in one boundary object: :meth:`apply` applies both, every other attribute (the wall
    terms, forces, checks) is the walls'."""

    walls: object
    far: CharacteristicFarField

    def apply(self, p: Particles, params) -> Particles:
        """The far field first, then the walls (mirror ghosts of far-field particles copy their
        new state)."""
        return self.walls.apply(self.far.apply(p, params), params)

    def fix(self, p: Particles, params) -> WithFarField:
        """The walls' searches done once for fixed particles (:func:`mlsph_jax.integrate.fixed_boundary`)."""
        fix = getattr(self.walls, "fix", None)
        return self if fix is None else dataclasses.replace(self, walls=fix(p, params))

    def __getattr__(self, name):
        if name.startswith("__") or name in ("walls", "far"):
            raise AttributeError(name)
        return getattr(self.walls, name)


def with_far_field(boundary, far):
    """The boundary object of a problem with walls ``boundary`` (or None) and far field ``far``
    (or None, the ``frozen`` far field)."""
    if far is None:
        return boundary
    return far if boundary is None else WithFarField(boundary, far)


class FrozenFarField:
    """``frozen``: the frozen particles keep their initial (free-stream) state; nothing to apply."""

    @staticmethod
    def setup(particles: Particles, eos: str, reference: Callable):
        return None


@dataclasses.dataclass(frozen=True)
class Characteristic:
    """``characteristic`` (and ``inflow_outflow``): :class:`CharacteristicFarField` (module
    docstring) with the frozen particles' ``state``."""

    state: Callable = characteristic_state

    def setup(self, particles: Particles, eos: str, reference: Callable) -> CharacteristicFarField:
        """Pair every FROZEN particle with its nearest FLUID particle (host side, once: the
        particles of a run with a far field do not move) and take the outward normal along the
        pair.  Errors name the EOS or the layout that does not allow it."""
        if self.state is characteristic_state and eos not in _INVARIANT_EOS:
            raise InputError(f"invalid eos.kind={eos!r} with case.far_field=\"characteristic\": the Riemann "
                             f"invariants u +- 2c/(gamma-1) hold for {', '.join(_INVARIANT_EOS)}; allowed: one of "
                             "those, or case.far_field=\"frozen\"")
        from scipy.spatial import cKDTree

        x = np.asarray(particles.x, float)
        kind = np.asarray(particles.kind)
        frozen = np.flatnonzero(kind == int(Kind.FROZEN))
        fluid = np.flatnonzero(kind == int(Kind.FLUID))
        if frozen.size == 0 or fluid.size == 0:
            raise InputError(f"invalid layout for a far field of case.far_field: {frozen.size} frozen and "
                             f"{fluid.size} fluid particles; allowed: both present")
        dist, k = cKDTree(x[fluid]).query(x[frozen])
        source = fluid[k]
        if np.any(dist <= 0.0):
            f = int(frozen[np.argmin(dist)])
            raise InputError(f"invalid layout: frozen particle {f} at {x[f].tolist()} coincides with a fluid "
                             "particle; allowed: distinct positions")
        normal = (x[frozen] - x[source]) / dist[:, None]
        return CharacteristicFarField(frozen=jnp.asarray(frozen, jnp.int32), source=jnp.asarray(source, jnp.int32),
                                      normal=jnp.asarray(normal), eos=eos, reference=reference, state=self.state)


FAR_FIELDS.register("frozen", FrozenFarField())
FAR_FIELDS.register("characteristic", Characteristic())
FAR_FIELDS.register("inflow_outflow", Characteristic(inflow_outflow_state))
