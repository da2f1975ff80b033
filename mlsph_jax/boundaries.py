"""Solid walls by mirror ghost particles (thesis §3.7.4-3.7.5, eq. 3.22; SPEC §8.2-8.3).

Walls are axis-aligned planes ``x[axis] = position`` with the fluid on one ``side`` (+1: fluid
at larger coordinates).  At setup (:func:`mirror_walls`, host side) every fluid particle within
``band`` of a wall gets a GHOST particle, its mirror image across the wall; a particle within
``band`` of two perpendicular walls also gets a corner ghost, mirrored across both (point
mirror at the corner vertex).  Every Runge-Kutta stage (:meth:`MirrorWalls.apply`, inside jit)
regenerates the ghosts from their parents:

* position: mirrored parent position (ghosts follow moving parents), hence in moving frames the
  frame velocity w of a ghost is its parent's mirrored (:meth:`MirrorWalls.ghost_frame_velocity`);
* volume, density and pressure (hence e): copied from the parent (zero normal gradient; SPEC
  §8.2 [REC]);
* velocity, no-slip:  u_G = 2 u_W - u_F (thesis eq. 3.22, Marrone et al. 2011), so the wall
  velocity is the pair average; free-slip: the normal component is reversed, the tangential one
  copied;
* corner ghosts (thesis §3.7.5, Szewc et al. 2012): u_GC = 4 u_V - u_F - u_G1 - u_G2 with the two
  wall ghosts u_Gk = 2 u_Wk - u_F and the vertex velocity u_V = (u_W1 + u_W2)/2 (SPEC §8.3
  default: half the lid speed at the lid corners, zero at fixed corners), which gives
  u_GC = u_F for no-slip walls; a slip wall's u_Gk is its mirrored (normal-reversed) velocity, so
  a free-slip/free-slip corner ghost has both components reversed, u_GC = -u_F (a point mirror).

Wall velocities are the differentiable parameter ``boundary.wall_velocity[n_walls, d]`` (moving
walls such as the Couette plate or the cavity lid).  The ghost set is fixed at setup: a particle
that later moves into the band has no ghost, so mirror walls are meant for flows parallel to the
walls or fixed (Eulerian) particles; ``ghost_band`` should cover the kernel support.  A run
stops with ``Status.GHOST_BAND`` when a fluid particle enters the band of a wall it has no ghost
across (:meth:`MirrorWalls.band_status`).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from .eos import get_eos, to_conservative, to_primitive
from .errors import InputError
from .registry import Registry
from .state import Kind, Params, Particles

#: Wall treatments (registry ``boundary``): ``setup(p_fluid, walls, band, params, eos, *, scheme,
#: domain) -> (particles, boundary)`` appends whatever the treatment needs to the fluid particles and
#: returns the object whose ``apply(particles, params)`` the integrator calls before every stage and
#: after each step (``mirror_ghosts`` here; ``boundary_integral`` in :mod:`mlsph_jax.wall_integral`,
#: whose object also adds ``wall_terms`` to the right-hand side).
BOUNDARIES: Registry = Registry("boundary", protocol=("setup",), doc="wall treatments")


@dataclasses.dataclass(frozen=True)
class Wall:
    """An axis-aligned wall ``x[axis] = position``; the fluid is on ``side`` (+1 or -1)."""

    axis: int
    position: float
    side: int
    slip: bool = False

    def __post_init__(self):
        if self.side not in (1, -1):
            raise InputError(f"invalid wall side={self.side!r}; allowed: +1 (fluid above) or -1 (fluid below)")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class MirrorWalls:
    """Ghost bookkeeping: ghost ``g`` (state index ``ghost[g]``) mirrors ``parent[g]`` across the
    walls with ``walls[g, w] = True`` (one wall, or two for a corner ghost)."""

    ghost: jax.Array      # [G] int
    parent: jax.Array     # [G] int
    walls: jax.Array      # [G, n_walls] bool
    axis: jax.Array = dataclasses.field(metadata=dict(static=True))       # tuple of ints
    position: jax.Array = dataclasses.field(metadata=dict(static=True))   # tuple of floats
    slip: jax.Array = dataclasses.field(metadata=dict(static=True))       # tuple of bools
    eos: str = dataclasses.field(metadata=dict(static=True), default="tait")
    #: [N, n_walls] bool: particle i has a (single-wall) ghost across wall k; None: not checked
    has_ghost: jax.Array | None = None
    side: tuple = dataclasses.field(metadata=dict(static=True), default=())
    band: float = dataclasses.field(metadata=dict(static=True), default=0.0)

    def band_status(self, p: Particles, params=None):
        """``(Status.GHOST_BAND or 0, first such particle or -1)``: a fluid particle within
        ``band`` of a wall it has no ghost across.  The ghost set is fixed at setup, so such a
        particle's mirror image is missing and the wall is incomplete around it (traceable)."""
        from .status import Status

        if self.has_ghost is None:
            return jnp.zeros((), jnp.int32), jnp.asarray(-1, jnp.int32)
        x = jax.lax.stop_gradient(p.x)
        dist = jnp.stack([(x[:, ax] - pos) * sd for ax, pos, sd in zip(self.axis, self.position, self.side,
                                                                           strict=True)], axis=1)
        bad = (p.kind == Kind.FLUID) & jnp.any((dist < self.band) & ~self.has_ghost, axis=1)
        hit = jnp.any(bad)
        return (jnp.where(hit, jnp.int32(Status.GHOST_BAND), 0).astype(jnp.int32),
                jnp.where(hit, jnp.argmax(bad), -1).astype(jnp.int32))

    def check_motion(self, params: Params) -> None:
        """Refuse a wall velocity with a component along the wall's normal axis, or a non-finite
        one: the walls (and the ghost set) stay where they were set up, so such a wall would move
        through the particles.  Called by :func:`mlsph_jax.run.setup_run` with the problem's Params."""
        from .geometry.checks import WALL_MOTION_RTOL, normal_wall_motion, wall_motion_problem

        if "boundary.wall_velocity" not in params:
            return
        uW = np.asarray(params["boundary.wall_velocity"], np.float64)
        normal = np.zeros_like(uW)
        for k, ax in enumerate(self.axis):
            normal[k, ax] = 1.0
        hit = normal_wall_motion(uW, normal)
        if hit is None:
            return
        k, vn = hit
        raise InputError(f"invalid boundary.wall_velocity[{k}]={uW[k].tolist()}: the wall x[{self.axis[k]}] = "
                         f"{self.position[k]:.10g} {wall_motion_problem(vn)}, but walls stay where they were set "
                         "up, so it would move through the particles; allowed: a finite velocity along the wall "
                         f"(component {self.axis[k]} zero, to {WALL_MOTION_RTOL:g} of the largest wall speed)")

    def apply(self, p: Particles, params: Params) -> Particles:
        """Regenerate every ghost from its parent (positions, volumes, states)."""
        eos = get_eos(self.eos)
        d = p.x.shape[1]
        W = self.walls.astype(p.x.dtype)                                     # [G, nw]
        xF = p.x[self.parent]
        UF = p.q[self.parent] / p.vol[self.parent][:, None]
        prim = to_primitive(UF, eos, params)
        uF = prim.vel
        xG, uG = xF, uF
        uW = params["boundary.wall_velocity"]                                # [nw, d]
        n_mirror = jnp.sum(W, axis=1)
        corner = n_mirror > 1
        wall_sum = W @ uW                                                    # sum of mirrored walls' velocities
        for w, (ax, pos, slip) in enumerate(zip(self.axis, self.position, self.slip, strict=True)):
            on = self.walls[:, w]
            xG = xG.at[:, ax].set(jnp.where(on, 2.0 * pos - xG[:, ax], xG[:, ax]))
            if slip:  # reverse the normal component (relative to the wall)
                un = uF[:, ax] - uW[w, ax]
                uG = uG.at[:, ax].set(jnp.where(on & ~corner, uW[w, ax] - un, uG[:, ax]))
        no_slip = jnp.asarray([not s for s in self.slip])
        ns_single = (~corner) & jnp.any(self.walls & no_slip[None, :], axis=1)
        uG = jnp.where(ns_single[:, None], 2.0 * wall_sum - uF, uG)
        # corner: u_GC = 4 u_V - u_F - u_G1 - u_G2, u_V = (u_W1 + u_W2)/2, u_Gk the ghost velocity of
        # wall k alone; two no-slip walls: u_Gk = 2 u_Wk - u_F (the form below, bit for bit as before)
        uGC = 4.0 * 0.5 * wall_sum + uF - 2.0 * wall_sum
        if any(self.slip):   # u_Gk of a slip wall: the normal component reversed relative to the wall
            single = jnp.zeros_like(uF)
            for w, (ax, slip) in enumerate(zip(self.axis, self.slip, strict=True)):
                uk = uF.at[:, ax].set(2.0 * uW[w, ax] - uF[:, ax]) if slip else 2.0 * uW[w] - uF
                single = single + jnp.where(self.walls[:, w:w + 1], uk, 0.0)
            any_slip = jnp.any(self.walls & ~no_slip[None, :], axis=1)
            uGC = jnp.where(any_slip[:, None], 2.0 * wall_sum - uF - single, uGC)
        uG = jnp.where(corner[:, None], uGC, uG)
        UG = to_conservative(prim.rho, uG, prim.p, eos, params)
        volG = p.vol[self.parent]
        x = p.x.at[self.ghost].set(xG[:, :d])
        vol = p.vol.at[self.ghost].set(volG)
        q = p.q.at[self.ghost].set(volG[:, None] * UG)
        return p.replace(x=x, vol=vol, q=q)


    def wall_tangential(self, n: int, d: int, dtype=jnp.float64):
        """``[n, d]``: 1 where component k of particle i is tangential to the (single) wall it is a
        ghost across, else 0 (fluid particles and corner ghosts); the pairs whose wall-tangential
        velocity jump ``scheme.ghost_shear_dissipation = false`` removes (decision 81)."""
        single = (jnp.sum(self.walls, axis=1) == 1)[:, None]
        normal = jnp.zeros((self.walls.shape[0], d), dtype)
        for k, ax in enumerate(self.axis):
            normal = normal.at[:, ax].add(self.walls[:, k].astype(dtype))
        tang = jnp.where(single, 1.0 - jnp.minimum(normal, 1.0), 0.0)
        return jnp.zeros((n, d), dtype).at[self.ghost].set(tang)

    def ghost_frame_velocity(self, w):
        """``w`` with every ghost's frame velocity the mirror image of its parent's (the normal
        component across each mirrored wall reversed): a ghost's position is the mirror of its
        parent's, so it moves with the mirrored velocity.  Used by :func:`mlsph_jax.rhs.rhs` in
        moving frames, where the MLS position update and dV/dt near a wall interpolate w over
        the ghosts (w = 0 there made the first fluid row lag behind the flow)."""
        wG = w[self.parent]
        for k, ax in enumerate(self.axis):
            wG = wG.at[:, ax].set(jnp.where(self.walls[:, k], -wG[:, ax], wG[:, ax]))
        return w.at[self.ghost].set(wG)


def mirror_walls(x_fluid: np.ndarray, walls: list[Wall], band: float, first_index: int, eos: str):
    """Ghost positions and bookkeeping for ``walls`` (host side, at setup).

    Returns ``(MirrorWalls, parent indices [G])``; ghost ``g`` gets state index
    ``first_index + g``.  ``band``: distance from a wall within which fluid particles are
    mirrored (at least the kernel support radius).
    """
    x = np.asarray(x_fluid, float)
    n, d = x.shape
    if not walls:
        raise InputError("invalid walls=[]; allowed: at least one Wall")
    for w in walls:
        if not 0 <= w.axis < d:
            raise InputError(f"invalid wall axis={w.axis}; allowed: 0..{d - 1}")
    dist = np.stack([(x[:, w.axis] - w.position) * w.side for w in walls], axis=1)   # [N, nw]
    if np.any(dist <= 0):
        i, k = np.argwhere(dist <= 0)[0]
        raise InputError(f"invalid layout: fluid particle {i} at {x[i].tolist()} is not on the fluid side of "
                         f"wall {k} (axis {walls[k].axis}, position {walls[k].position}); allowed: strictly inside")
    near = dist < band
    parents, masks = [], []
    nw = len(walls)
    for k in range(nw):
        idx = np.flatnonzero(near[:, k])
        parents.append(idx)
        m = np.zeros((idx.size, nw), bool)
        m[:, k] = True
        masks.append(m)
    for a in range(nw):
        for b in range(a + 1, nw):
            if walls[a].axis == walls[b].axis:
                continue
            idx = np.flatnonzero(near[:, a] & near[:, b])
            parents.append(idx)
            m = np.zeros((idx.size, nw), bool)
            m[:, a] = m[:, b] = True
            masks.append(m)
    parent = np.concatenate(parents).astype(np.int32)
    mask = np.concatenate(masks, axis=0)
    g = parent.size
    has_ghost = np.zeros((first_index + g, nw), bool)
    has_ghost[:n] = near
    mw = MirrorWalls(ghost=jnp.arange(first_index, first_index + g, dtype=jnp.int32), parent=jnp.asarray(parent),
                     walls=jnp.asarray(mask), axis=tuple(w.axis for w in walls),
                     position=tuple(float(w.position) for w in walls), slip=tuple(bool(w.slip) for w in walls),
                     eos=eos, has_ghost=jnp.asarray(has_ghost), side=tuple(int(w.side) for w in walls),
                     band=float(band))
    return mw, parent


def with_ghosts(p_fluid: Particles, walls: list[Wall], band: float, params: Params, eos: str):
    """Append the ghosts of ``walls`` to the particle set (kind GHOST) and fill them in."""
    mw, parent = mirror_walls(np.asarray(p_fluid.x), walls, band, p_fluid.n, eos)
    g = parent.size
    cat = lambda a, b: jnp.concatenate([a, b], axis=0)  # noqa: E731
    p = p_fluid.replace(x=cat(p_fluid.x, p_fluid.x[parent]), vol=cat(p_fluid.vol, p_fluid.vol[parent]),
                        q=cat(p_fluid.q, p_fluid.q[parent]),
                        kind=cat(p_fluid.kind, jnp.full(g, int(Kind.GHOST), p_fluid.kind.dtype)),
                        ppd=cat(p_fluid.ppd, p_fluid.ppd[parent]))
    return mw.apply(p, params), mw


class MirrorGhosts:
    """Mirror-ghost walls (module docstring; thesis eq. 3.22): :func:`with_ghosts`."""

    @staticmethod
    def setup(p_fluid: Particles, walls: list[Wall], band: float, params: Params, eos: str, *, scheme=None,
              domain=None):
        """:func:`with_ghosts` (``scheme`` and ``domain`` are not needed by mirror ghosts)."""
        return with_ghosts(p_fluid, walls, band, params, eos)


BOUNDARIES.register("mirror_ghosts", MirrorGhosts())
