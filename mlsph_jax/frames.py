"""The ALE frame: how fast particles move (registries ``scheme.frame``, ``scheme.shift_law`` and
``scheme.position_update``).

MLSPH-ALE writes the balance laws in a frame moving with velocity w (thesis eq. 2.17-2.19,
4.28, 4.32): the fluxes are taken relative to w, the volumes change with the divergence of w and
the particles move with an interpolant of w.

A **frame** has ``moving`` (whether particles move, hence whether neighbour lists and operators
change every stage), ``velocity(U, kind, eos, params) -> w[N, d]`` (the frame velocity before any
shifting drift; zero for non-fluid particles, whose motion, if any, the wall treatment gives:
mirror ghosts move with their parents,
:meth:`mlsph_jax.boundaries.MirrorWalls.ghost_frame_velocity`) and ``drift(w, geom, kind, scheme, vol) -> dw[N, d]``
(the particle-shifting correction added in the right-hand side, or ``None``).

A **shifting law** has ``drift(geom, scheme, vol) -> [N, d]``, the unscaled drift direction
(the frame multiplies it by C U_max, SPEC §9).

A **position update** has ``weights(values, dx, h, jsafe, mask, vol, kernel) -> [N, K] | None``:
the interpolation weights of dx_i/dt = sum_j N_j(x_i) w_j (thesis eq. 4.28), from the method's own
shape-function values ``values`` (``None`` for kernel SPH-ALE), or ``None`` for dx_i/dt = w_i.
Whatever it is, the velocity a particle moves with is also the w_i of its fluxes (eq. 4.36) and
of its volume rate (eq. 4.32), so that the volumes follow the particles (architecture decision
44; the thesis' fluxes use the un-interpolated w_i, which breaks that, docs/moving_particles.md).
The shifting drift is added to the interpolated velocity, not interpolated.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp

from .approximation import mls
from .eos import to_primitive
from .errors import InputError
from .kernels import get_kernel
from .registry import Registry
from .state import Kind

FRAMES: Registry = Registry("scheme.frame", protocol=("moving", "velocity", "drift"),
                            doc="ALE frame velocity w")
SHIFT_LAWS: Registry = Registry("scheme.shift_law", protocol=("drift",), doc="particle-shifting drift laws")
POSITION_UPDATES: Registry = Registry("scheme.position_update", protocol=("weights", "fluxes_use_motion"),
                                      doc="interpolant of w that moves the particles")


def _fluid_velocity(U, kind, eos, params):
    vel = to_primitive(U, eos, params).vel
    return jnp.where((kind == Kind.FLUID)[:, None], vel, 0.0)


@dataclasses.dataclass(frozen=True)
class Eulerian:
    """w = 0: particles stay where they are (fixed-particle finite volumes)."""

    moving: bool = False

    def velocity(self, U, kind, eos, params):
        d = U.shape[1] - eos.n_vars(1) + 1
        return jnp.zeros((U.shape[0], d), U.dtype)

    def drift(self, w, geom, kind, scheme, vol):
        return None


@dataclasses.dataclass(frozen=True)
class Lagrangian:
    """w = u: particles move with the fluid (thesis eq. 4.28 with w = u)."""

    moving: bool = True

    def velocity(self, U, kind, eos, params):
        return _fluid_velocity(U, kind, eos, params)

    def drift(self, w, geom, kind, scheme, vol):
        return None


@dataclasses.dataclass(frozen=True)
class ShiftedALE:
    """w = u + dw: Lagrangian motion plus the particle-shifting drift of ``scheme.shift_law``
    (SPEC §9, within the ALE frame of thesis T:L1563-1565), dw_i = C U_max drift_i with
    U_max = max |w| over fluid particles and C = ``scheme.shift_coefficient``.  Because the
    fluxes are computed relative to the particle velocity (eq. 4.36, 4.32), no interpolation
    correction is needed."""

    moving: bool = True

    def velocity(self, U, kind, eos, params):
        return _fluid_velocity(U, kind, eos, params)

    def drift(self, w, geom, kind, scheme, vol):
        law = SHIFT_LAWS.get(scheme.shift_law, "scheme.shift_law")
        drift = law.drift(geom, scheme, vol)
        fluid = kind == Kind.FLUID
        umax = jnp.max(jnp.where(fluid, jnp.sqrt(jnp.sum(w * w, axis=1) + 1e-300), 0.0))
        return jnp.where(fluid[:, None], scheme.shift_coefficient * umax * drift, 0.0)


FRAMES.register("eulerian", Eulerian())
FRAMES.register("lagrangian", Lagrangian())
FRAMES.register("ale_shift", ShiftedALE())


def _inside_support(geom, scheme):
    """Pairs strictly inside i's support (relative margin): lattice neighbours at exactly the
    cut-off are in or out of the list by round-off, which must not break the lattice's symmetry.
    (r^2 summed component by component: XLA:CPU's reduction over a length-d axis costs as much
    as the whole drift.)"""
    dx = [geom.dx[..., a] for a in range(geom.dx.shape[-1])]
    r2 = dx[0] * dx[0]
    for c in dx[1:]:
        r2 = r2 + c * c
    reach = scheme.support * geom.h[:, None]
    return r2, geom.pair_mask & (r2 > 0) & (r2 < (reach * (1.0 - 1e-9)) ** 2)


@dataclasses.dataclass(frozen=True)
class XuShift:
    """Xu et al. (2009) type repulsion: drift_i = 1/n_i sum_j (r_i / r_ij)^2 (x_i - x_j) / r_ij over
    the n_i neighbours strictly inside i's support, r_i their mean distance (SPEC §9 default).
    Two passes over the stencil, each one variadic reduction (:func:`mls.stencil_sums`)."""

    def drift(self, geom, scheme, vol):
        r2, pos = _inside_support(geom, scheme)
        r = jnp.sqrt(jnp.where(pos, r2, 1.0))
        n_in, r_sum = mls.stencil_sums([pos.astype(r.dtype), jnp.where(pos, r, 0.0)])
        cnt = jnp.maximum(n_in, 1.0)
        rbar = r_sum / cnt
        wt = jnp.where(pos, (rbar[:, None] / r) ** 2 / r, 0.0)
        sums = mls.stencil_sums([wt * geom.dx[..., a] for a in range(geom.dx.shape[-1])])
        return -jnp.stack(sums, axis=-1) / cnt[:, None]   # dx = x_j - x_i


@dataclasses.dataclass(frozen=True)
class FickianShift:
    """Lind et al. (2012) type Fickian drift: drift_i = -h_i sum_j V_j grad_i W(x_i - x_j, h_i), down
    the gradient of the particle concentration; smooth where a neighbour crosses the support edge."""

    def drift(self, geom, scheme, vol):
        if vol is None:
            raise InputError("the fickian shift law needs the particle volumes (vol=...)")
        _, pos = _inside_support(geom, scheme)
        gradw = get_kernel(scheme.kernel).grad(-geom.dx, geom.h[:, None])          # grad_i W(x_i - x_j)
        vj = vol[geom.jsafe]
        return -geom.h[:, None] * jnp.sum(jnp.where(pos, vj, 0.0)[..., None] * gradw, axis=1)


@dataclasses.dataclass(frozen=True)
class SmoothXuShift:
    """The Xu et al. (2009) repulsion of :class:`XuShift` with every neighbour weighted by the
    taper f_ij = (1 - r_ij^2 / R_i^2)^2 (R_i = support * h_i): drift_i = 1/n_i sum_j f_ij (r_i /
    r_ij)^2 (x_i - x_j) / r_ij with n_i = sum_j f_ij and r_i = sum_j f_ij r_ij / n_i. f and its
    slope vanish at the support edge, so the drift, and with it the right-hand side, is C^1 in
    the positions where a neighbour crosses the edge, as long as another neighbour stays inside
    (n_i > 0; a particle losing its last neighbour drops its drift to zero, as with ``xu``):
    SSP-RK3 keeps its third order in time (the plain ``xu`` drift jumps there, which makes it
    order ~1; docs/moving_particles.md §7, decision 80). Its drift is ~1.5x the ``xu`` one at
    the same C on a jittered lattice. Opt-in: on the §4.5.1 vortex at t = 2 its E_k and velocity
    errors are ~1.5x those of ``xu`` (decision 80)."""

    def drift(self, geom, scheme, vol):
        r2, pos = _inside_support(geom, scheme)
        reach = scheme.support * geom.h[:, None]
        r = jnp.sqrt(jnp.where(pos, r2, 1.0))
        f = jnp.where(pos, (1.0 - r2 / (reach * reach)) ** 2, 0.0)
        n_f, r_sum = mls.stencil_sums([f, f * r])
        cnt = jnp.where(n_f > 0, n_f, 1.0)
        rbar = r_sum / cnt
        wt = f * (rbar[:, None] / r) ** 2 / r
        sums = mls.stencil_sums([wt * geom.dx[..., a] for a in range(geom.dx.shape[-1])])
        return -jnp.stack(sums, axis=-1) / cnt[:, None]   # dx = x_j - x_i


SHIFT_LAWS.register("xu", XuShift())
SHIFT_LAWS.register("xu_smooth", SmoothXuShift())
SHIFT_LAWS.register("fickian", FickianShift())


def shepard_weights(dx, h, jsafe, mask, vol, kernel):
    """Shepard weights W_ij V_j / sum_k W_ik V_k with h_ij = (h_i + h_j)/2 (thesis eq. 3.7)."""
    hij = 0.5 * (h[:, None] + h[jsafe])
    w = kernel.w_vec(dx, hij) * jnp.where(mask, vol[jsafe], 0.0)
    return w / jnp.sum(w, axis=1, keepdims=True)


@dataclasses.dataclass(frozen=True)
class MethodInterpolant:
    """The method's own interpolant of w: the MLS shape functions for mlsph_ale (thesis eq. 4.28),
    the Shepard kernel average for sph_ale, which has no shape functions of its own (eq. 3.7).

    ``fluxes_use_motion``: the fluxes and dV/dt use the interpolated velocity the particle moves
    with (True, geometric conservation) or, as printed in the thesis, the particle's own w_i
    (False: ``mls_literal``, kept to reproduce the thesis and the diagnosis in
    docs/moving_particles.md; its volumes drift away from the particles)."""

    fluxes_use_motion: bool = True

    def weights(self, values, dx, h, jsafe, mask, vol, kernel):
        return values if values is not None else shepard_weights(dx, h, jsafe, mask, vol, kernel)


@dataclasses.dataclass(frozen=True)
class ShepardInterpolant:
    """The Shepard kernel average of w (thesis eq. 3.7) for every method."""

    fluxes_use_motion: bool = True

    def weights(self, values, dx, h, jsafe, mask, vol, kernel):
        return shepard_weights(dx, h, jsafe, mask, vol, kernel)


@dataclasses.dataclass(frozen=True)
class OwnVelocity:
    """dx_i/dt = w_i: each particle moves with its own frame velocity (no interpolation)."""

    fluxes_use_motion: bool = True

    def weights(self, values, dx, h, jsafe, mask, vol, kernel):
        return None


POSITION_UPDATES.register("mls", MethodInterpolant())
POSITION_UPDATES.register("mls_literal", MethodInterpolant(fluxes_use_motion=False))
POSITION_UPDATES.register("shepard", ShepardInterpolant())
POSITION_UPDATES.register("w_i", OwnVelocity())


def frame_velocity(U, kind, scheme, params):
    """w_i of ``scheme.frame`` before any shifting drift; non-fluid particles do not move."""
    from .eos import get_eos

    return FRAMES.get(scheme.frame, "scheme.frame").velocity(U, kind, get_eos(scheme.eos), params)


def shifting_velocity(w, geom, kind, scheme, vol=None):
    """The shifting drift dw_i of the ``ale_shift`` frame for ``scheme.shift_law`` (whatever
    ``scheme.frame`` is; see :class:`ShiftedALE`)."""
    return FRAMES.get("ale_shift").drift(w, geom, kind, scheme, vol)
