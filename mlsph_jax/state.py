"""Particle state, differentiable parameters, static scheme and domain descriptions.

* :class:`Particles` — pytree of per-particle arrays: positions ``x[N,d]``, effective volumes
  ``vol[N]``, conserved quantities ``q[N,nv] = V_i U_i`` (thesis eq. 4.18: the carried quantity
  of the ALE particle method), particle ``kind[N]`` and MOOD polynomial degree ``ppd[N]``.
* :class:`Params` — pytree of floats a user may differentiate or calibrate (EOS constants,
  viscosity, body force, ...).  Keys are the dotted config keys (``"eos.c0"``).
* :class:`Domain` — static, hashable: box bounds and periodic axes.

The dimension ``d`` is always read from ``x.shape[1]``; 1D, 2D and 3D share one code path.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from enum import IntEnum

import jax
import jax.numpy as jnp
import numpy as np

from .errors import InputError


class Kind(IntEnum):
    """Role of a particle.

    FLUID particles are updated; GHOST particles are regenerated from fluid particles every stage
    (mirror walls); BOUNDARY particles carry a prescribed state (walls); FROZEN particles keep
    their initial state (transmissive ends, far field) but act as neighbours.
    """

    FLUID = 0
    GHOST = 1
    BOUNDARY = 2
    FROZEN = 3


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Particles:
    """Particle state (a pytree).  ``q = vol[:, None] * U`` holds the conserved variables."""

    x: jax.Array
    vol: jax.Array
    q: jax.Array
    kind: jax.Array
    ppd: jax.Array

    @property
    def n(self) -> int:
        return self.x.shape[0]

    @property
    def dim(self) -> int:
        return self.x.shape[1]

    @property
    def U(self) -> jax.Array:
        """Conservative state per unit volume, ``U_i = q_i / V_i``."""
        return self.q / self.vol[:, None]

    def replace(self, **changes) -> Particles:
        return dataclasses.replace(self, **changes)


def make_particles(x, vol, U, kind=None, ppd=None) -> Particles:
    """Build a validated :class:`Particles` from positions, volumes and conservative states.

    Raises :class:`InputError` for wrong shapes, non-finite values or non-positive volumes.
    """
    x = jnp.asarray(x, dtype=jnp.float64)
    if x.ndim == 1:
        x = x[:, None]
    if x.ndim != 2 or x.shape[1] not in (1, 2, 3):
        raise InputError(f"invalid x with shape {x.shape}; allowed: an array of shape (N, d), d in 1..3")
    n = x.shape[0]
    vol = jnp.asarray(vol, dtype=jnp.float64)
    if vol.shape != (n,):
        raise InputError(f"invalid vol with shape {vol.shape}; allowed: shape ({n},)")
    U = jnp.asarray(U, dtype=jnp.float64)
    if U.ndim != 2 or U.shape[0] != n:
        raise InputError(f"invalid U with shape {U.shape}; allowed: shape ({n}, nv)")
    for name, a in (("x", x), ("vol", vol), ("U", U)):
        bad = np.flatnonzero(~np.isfinite(np.asarray(a)).reshape(n, -1).all(axis=1))
        if bad.size:
            raise InputError(f"non-finite {name} at particle {int(bad[0])} ({bad.size} particles); "
                             "allowed: finite values")
    bad = np.flatnonzero(np.asarray(vol) <= 0)
    if bad.size:
        raise InputError(f"invalid vol={float(vol[bad[0]])!r} at particle {int(bad[0])}; "
                         "allowed: volumes > 0")
    bad = np.flatnonzero(np.asarray(U[:, 0]) <= 0)
    if bad.size:
        raise InputError(f"invalid density U[:, 0]={float(U[bad[0], 0])!r} at particle {int(bad[0])} "
                         f"({bad.size} particles); allowed: densities > 0")
    kind = jnp.zeros(n, jnp.int32) if kind is None else jnp.asarray(kind, jnp.int32)
    ppd = jnp.full(n, 3, jnp.int32) if ppd is None else jnp.asarray(ppd, jnp.int32)
    return Particles(x=x, vol=vol, q=vol[:, None] * U, kind=kind, ppd=ppd)


@jax.tree_util.register_pytree_node_class
class Params(Mapping):
    """Immutable mapping of differentiable physical/numerical parameters (a pytree).

    Keys are dotted config keys such as ``"eos.gamma"`` or ``"physics.mu"``; values are float64
    scalars (or arrays, e.g. a body-force vector).  ``jax.grad`` with respect to a ``Params``
    returns a ``Params`` of the same keys.
    """

    def __init__(self, values: Mapping[str, object] | None = None, **kw):
        vals = dict(values or {})
        vals.update(kw)
        self._v = {k: (v if isinstance(v, jax.Array | jax.core.Tracer) or not _is_number(v)
                       else jnp.asarray(v, jnp.float64)) for k, v in sorted(vals.items())}

    def __getitem__(self, key: str):
        try:
            return self._v[key]
        except KeyError:
            raise InputError(f"missing parameter {key!r}; present: {', '.join(self._v) or 'none'}") from None

    def __contains__(self, key: object) -> bool:
        return key in self._v

    def __iter__(self):
        return iter(self._v)

    def __len__(self):
        return len(self._v)

    def replace(self, **changes) -> Params:
        """Return a copy with some values replaced; keys use ``__`` for dots (``eos__c0=...``)
        or pass a dict via :meth:`updated`."""
        return self.updated({k.replace("__", "."): v for k, v in changes.items()})

    def updated(self, changes: Mapping[str, object]) -> Params:
        v = dict(self._v)
        v.update(changes)
        return Params(v)

    def tree_flatten(self):
        keys = tuple(self._v)
        return tuple(self._v[k] for k in keys), keys

    @classmethod
    def tree_unflatten(cls, keys, leaves):
        obj = object.__new__(cls)
        obj._v = dict(zip(keys, leaves, strict=True))
        return obj

    def __repr__(self):
        inner = ", ".join(f"{k}={_short(v)}" for k, v in self._v.items())
        return f"Params({inner})"


def _is_number(v) -> bool:
    return isinstance(v, int | float | np.floating | np.integer) and not isinstance(v, bool)


def _short(v):
    try:
        return f"{float(v):.6g}"
    except Exception:  # noqa: BLE001 - arrays, tracers
        return type(v).__name__


@dataclasses.dataclass(frozen=True)
class Domain:
    """Static, hashable description of the computational box.

    ``lower``/``upper`` bound the box along each axis; ``periodic[a]`` says whether axis ``a``
    wraps (minimum-image convention).  Non-periodic axes only need bounds that contain the
    particles (they size the cell grid).
    """

    lower: tuple[float, ...]
    upper: tuple[float, ...]
    periodic: tuple[bool, ...]

    def __post_init__(self):
        d = len(self.lower)
        if not (len(self.upper) == d == len(self.periodic)) or d not in (1, 2, 3):
            raise InputError(f"invalid Domain(lower={self.lower}, upper={self.upper}, "
                             f"periodic={self.periodic}); allowed: three tuples of equal length 1..3")
        for a in range(d):
            if not self.upper[a] > self.lower[a]:
                raise InputError(f"invalid domain axis {a}: lower={self.lower[a]}, upper={self.upper[a]}; "
                                 "allowed: upper > lower")

    @property
    def dim(self) -> int:
        return len(self.lower)

    @property
    def length(self) -> tuple[float, ...]:
        return tuple(u - l for l, u in zip(self.lower, self.upper, strict=True))

    @property
    def any_periodic(self) -> bool:
        return any(self.periodic)


def tiny(dtype) -> float:
    """Positive floor of a guarded division in ``dtype``: ``1e-300`` in float64 (the historical
    guard), the smallest normal number in float32 (where ``1e-300`` is 0)."""
    return max(1e-300, float(jnp.finfo(dtype).tiny))


def with_precision(tree, precision: str, *, name: str = "run.precision"):
    """``tree`` (particles, parameters, geometry) with every floating array in ``precision``
    (``"float64"``: unchanged; ``"float32"``: cast); integer and boolean arrays unchanged."""
    if precision not in PRECISIONS:
        raise InputError(f"invalid {name}={precision!r}; allowed: one of {', '.join(map(repr, PRECISIONS))}")
    if precision == "float64":
        return tree
    dt = jnp.dtype(precision)

    def cast(a):
        if isinstance(a, jax.Array | np.ndarray) and jnp.issubdtype(a.dtype, jnp.floating):
            return jnp.asarray(a, dt)
        return a

    return jax.tree_util.tree_map(cast, tree)


#: Allowed values of ``run.precision`` (the precision of the state; float64 is the default).
PRECISIONS = ("float64", "float32")


def minimum_image(dx: jax.Array, box_length: jax.Array | None, periodic: jax.Array | None) -> jax.Array:
    """Wrap separation vectors ``dx[..., d]`` to the nearest periodic image on periodic axes."""
    if box_length is None or periodic is None:
        return dx
    L = jnp.asarray(box_length, dx.dtype)
    wrapped = dx - L * jnp.round(dx / L)
    return jnp.where(jnp.asarray(periodic), wrapped, dx)
