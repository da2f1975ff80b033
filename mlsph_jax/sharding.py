"""Particle-axis sharding of a run over several devices, through JAX's own distribution.

``run.devices = D`` (``Simulation(..., devices=D)``) places every per-particle array of the
state (positions, volumes, conserved quantities, kinds, degrees), of the neighbour list and of
the geometry on a 1-D :class:`jax.sharding.Mesh` of ``D`` devices with
``NamedSharding(mesh, P("particles"))``: device ``k`` holds particles ``k N/D .. (k+1) N/D - 1``.
Scalars (time, step, status) and the parameters are replicated.  The jitted chunk is the same
function as on one device; XLA's SPMD partitioner decides the communication of the neighbour
gathers, the cell sort of moving particles and the global reductions (CFL step, status).  No
home-made communication: the same program runs on host devices
(``XLA_FLAGS=--xla_force_host_platform_device_count=D``), several GPUs, and several processes
after :func:`jax.distributed.initialize` (the mesh spans :func:`jax.devices`, i.e. every
process's devices; each process holds the whole initial state and places its own shards).

Every per-particle quantity is a function of the particle's own state and of its neighbours',
so a sharded run computes the same numbers as the one-device run; only the order of global
sums (the conservation totals of the summary, MOOD statistics) may differ, at round-off.

The particle count must be a multiple of ``D`` (no padding particles: a padding particle would
have to be invisible to the neighbour search and the reductions; an error naming
``run.devices`` says which counts are allowed instead).
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from .errors import InputError

__all__ = ["AXIS", "ParticleSharding", "available_devices", "check_devices", "particle_sharding"]

#: Name of the mesh axis the particles are sharded over.
AXIS = "particles"


def available_devices() -> int:
    """Number of devices a run may shard over: every device of every process (``jax.devices()``)."""
    return len(jax.devices())


def check_devices(devices, *, name: str = "run.devices") -> int:
    """The device count ``devices`` asks for (``0``: every available device), refused
    (``InputError`` naming ``name`` and the value) if negative or above :func:`available_devices`."""
    if isinstance(devices, bool) or not isinstance(devices, int | np.integer) or devices < 0:
        raise InputError(f"invalid {name}={devices!r}; allowed: an int >= 0 (0 = every available device, "
                         f"{available_devices()} here)")
    avail = available_devices()
    d = avail if devices == 0 else int(devices)
    if d > avail:
        raise InputError(
            f"invalid {name}={devices}: only {avail} device(s) available ({jax.devices()[0].platform}); allowed: "
            f"1..{avail} (on a CPU, more host devices need XLA_FLAGS=--xla_force_host_platform_device_count={d} "
            "set before jax is imported; across hosts, jax.distributed.initialize first)")
    return d


def particle_sharding(devices: int, n_particles: int, *, name: str = "run.devices") -> ParticleSharding | None:
    """The :class:`ParticleSharding` of ``devices`` devices for ``n_particles`` particles, or
    ``None`` for one device (the unsharded run).  ``devices = 0`` selects every available device.

    Refused (``InputError`` naming ``name`` and the value): a negative count, more devices than
    :func:`available_devices`, a count that does not divide the particle count."""
    d = check_devices(devices, name=name)
    avail = available_devices()
    if n_particles % d:
        ok = [k for k in range(1, avail + 1) if n_particles % k == 0]
        raise InputError(
            f"invalid {name}={devices}: the {n_particles} particles do not split evenly over {d} devices "
            f"(each device holds N/{name} particles and none is dropped or padded); allowed here: "
            f"{', '.join(map(str, ok))}")
    if d == 1:
        return None
    return ParticleSharding(Mesh(np.asarray(jax.devices()[:d]), (AXIS,)), int(n_particles))


@dataclasses.dataclass(frozen=True)
class ParticleSharding:
    """A 1-D mesh over the particle axis and the particle count ``n`` it was made for.

    Any array whose leading dimension is ``n`` is sharded over the mesh, every other array
    (scalars, parameters, non-particle tables) is replicated."""

    mesh: Mesh
    n: int

    @property
    def devices(self) -> int:
        return self.mesh.size

    def spec_of(self, a) -> NamedSharding:
        """Sharding of one array: split along axis 0 if it is a per-particle array, else replicated."""
        shape = np.shape(a)
        return NamedSharding(self.mesh, P(AXIS) if shape and shape[0] == self.n else P())

    def place(self, tree):
        """``tree`` (host or device arrays, the same global value on every process) as global
        arrays sharded by :meth:`spec_of`; each process builds only its own shards."""

        def put(a):
            if a is None:
                return None
            if isinstance(a, jax.Array) and a.sharding == self.spec_of(a):
                return a
            h = np.asarray(a)
            return jax.make_array_from_callback(h.shape, self.spec_of(h), lambda idx: h[idx])

        return jax.tree_util.tree_map(put, tree)

    def replicate(self, tree):
        """``tree`` replicated on every device whatever its shape (the parameters: a parameter
        array that happens to have N entries is not a per-particle field)."""
        rep = NamedSharding(self.mesh, P())

        def put(a):
            if a is None:
                return None
            h = np.asarray(a)
            return jax.make_array_from_callback(h.shape, rep, lambda idx: h[idx])

        return jax.tree_util.tree_map(put, tree)

    def constrain(self, tree):
        """Inside ``jit``: pin the layout of ``tree`` to :meth:`spec_of` (so that a chunk's
        output carry has the sharding of its input and the compiled chunk is reused)."""
        return jax.tree_util.tree_map(lambda a: jax.lax.with_sharding_constraint(a, self.spec_of(a)), tree)

    def gather(self, tree):
        """Host-side copy of ``tree`` as ordinary single-device arrays (every process gets the
        whole state; across processes this is a collective, so every process must call it)."""
        from jax.experimental import multihost_utils

        def get(a):
            if not isinstance(a, jax.Array):
                return a
            if a.is_fully_addressable:
                return jax.numpy.asarray(np.asarray(a))
            return jax.numpy.asarray(np.asarray(multihost_utils.process_allgather(a, tiled=True)))

        return jax.tree_util.tree_map(get, tree)
