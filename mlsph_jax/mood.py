"""MOOD a-posteriori order reduction inside every SSP-RK3 stage (thesis §3.6.3, eq. 3.12-3.13;
SPEC §6 and §13.3).

Every stage of :func:`mlsph_jax.integrate.ssp_rk3_step` is a forward-Euler sub-step
E = z + dt L(z) of the stage input z followed by the Shu-Osher combination a y^n + b E.  With
``scheme.limiter = "mood"`` the sub-step is computed a posteriori:

1. the particle polynomial degree map (PPD) is reset to the reconstruction degree everywhere
   (thesis "order 3" = degree 2: quadratic reconstruction);
2. the candidate E is computed with pair degree min(PPD_i, PPD_j) (:func:`mlsph_jax.rhs.rhs`);
3. the detector chain flags fluid particles whose candidate is
   * not finite, or physically inadmissible (PAD, EOS-aware: rho > 0 always; p > 0 for the
     ideal gas; p + p_c > 0 for the stiffened gas; nothing more for Tait, whose pressure may be
     <= 0 legitimately, SPEC §13.3 item 22), or
   * a new extremum (NAD, relaxed discrete maximum principle, eq. 3.12): for each selected
     variable phi, min_S phi(z) - delta <= phi_i(E) <= max_S phi(z) + delta over the particle's
     stencil S (support neighbours and the particle itself, SPEC item 19), with
     delta = max(delta_abs, delta_rel (max_S - min_S)) (eq. 3.13).  The printed floor delta_abs
     = 1e-4 is absolute, i.e. in Pa for a pressure of 1e9 Pa, where round-off alone exceeds it
     and flat regions get flagged; by default (``mood_delta_floor = "scaled"``, SPEC item 21)
     the floor is delta_abs max_i |phi_i| (the variable's magnitude over all particles, so it
     is unit-free and not zero where a Tait pressure passes through 0), ``"absolute"`` keeps
     the printed form;
4. flagged particles drop to degree 0 (the parachute: first-order states U_i, U_j, which
   passes the detectors by construction) and the candidate is recomputed;
5. 3-4 repeat until no new particle is flagged, at most ``mood_max_iter`` times.

Only two degrees are used (the reconstruction degree and 0), as in the thesis.  Areas, the
time integrator and (later) viscous fluxes are not order-reduced (SPEC item 24).

Differentiability: the flags are computed from stop-gradient values and the PPD map is an
integer array, so gradients flow through the selected branch only.  The iteration is a
``lax.scan`` of fixed length whose body is a ``lax.cond``: once converged, the remaining
iterations cost nothing, and the whole loop is reverse-mode differentiable (a ``while_loop``
would not be).

Statistics per stage: the PPD map after the loop, the number of right-hand-side evaluations,
and whether flags were left unresolved after ``mood_max_iter`` iterations.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from .eos import get_eos, to_primitive
from .registry import Registry
from .state import Kind, Params, Particles

__all__ = ["LIMITERS", "NAD_VARIABLES", "DELTA_FLOORS", "admissible", "detect", "mood_substep", "nad_fields",
           "stencil_bounds"]

LIMITERS: Registry = Registry("scheme.limiter",
                              protocol=("substep", "needs_high_order", "acts_on_substeps", "summary_key"),
                              doc="a-posteriori limiters of the forward-Euler sub-step of each stage")
NAD_VARIABLES: Registry = Registry("scheme.mood_variables", protocol=("fields",),
                                   doc="variables checked by MOOD's NAD detector")
DELTA_FLOORS: Registry = Registry("scheme.mood_delta_floor", protocol=("floor",), doc="NAD tolerance floors")


def admissible(U, scheme, params: Params):
    """PAD: finite state and the EOS' own admissibility (rho > 0 always; p > 0 for the ideal gas,
    p + p_c > 0 for the stiffened gas, :attr:`mlsph_jax.eos.EOS.admissible`), per particle ``[N]``."""
    eos = get_eos(scheme.eos)
    prim = to_primitive(U, eos, params)
    ok = jnp.all(jnp.isfinite(U), axis=1) & eos.admissible(prim.rho, prim.p, params)
    return ok & jnp.isfinite(prim.p)


@dataclasses.dataclass(frozen=True)
class NADVariable:
    """A variable checked by NAD: ``fields(U, prim, eos) -> [N, k]`` columns, or ``None`` where the
    EOS does not have it."""

    extract: object
    description: str = ""

    def fields(self, U, prim, eos):
        return self.extract(U, prim, eos)


NAD_VARIABLES.register("rho", NADVariable(lambda U, pr, eos: pr.rho[:, None], "density"))
NAD_VARIABLES.register("p", NADVariable(lambda U, pr, eos: pr.p[:, None], "pressure"))
NAD_VARIABLES.register("vel", NADVariable(lambda U, pr, eos: pr.vel, "every velocity component"))
NAD_VARIABLES.register("e", NADVariable(lambda U, pr, eos: pr.e[:, None] if eos.has_energy else None,
                                        "specific internal energy (EOS with an energy equation)"))
NAD_VARIABLES.register("conservative", NADVariable(lambda U, pr, eos: U, "every component of U"))


class ScaledFloor:
    """delta_abs max_i |phi_i|: the variable's magnitude over all particles (unit-free; not zero
    where a Tait pressure passes through 0; SPEC item 21, default)."""

    @staticmethod
    def floor(delta_abs, lo, hi):
        return delta_abs * jnp.max(jnp.maximum(jnp.abs(lo), jnp.abs(hi)), axis=0)


class AbsoluteFloor:
    """delta_abs as printed in thesis eq. 3.13, in the variable's units (Pa, kg/m^3)."""

    @staticmethod
    def floor(delta_abs, lo, hi):
        return delta_abs


DELTA_FLOORS.register("scaled", ScaledFloor())
DELTA_FLOORS.register("absolute", AbsoluteFloor())


def nad_fields(U, scheme, params: Params):
    """The variables checked by NAD as columns ``[N, nv]`` (``scheme.mood_variables``)."""
    eos = get_eos(scheme.eos)
    prim = to_primitive(U, eos, params)
    cols = [NAD_VARIABLES.get(name, "scheme.mood_variables").fields(U, prim, eos) for name in scheme.mood_variables]
    return jnp.concatenate([c for c in cols if c is not None], axis=1)


def stencil_bounds(phi, idx, mask):
    """(min, max) of ``phi[N, nv]`` over each particle's stencil (neighbours incl. itself)."""
    n = phi.shape[0]
    jsafe = jnp.where(mask, idx, jnp.arange(n, dtype=idx.dtype)[:, None])
    vals = phi[jsafe]                                    # [N, K, nv]
    m = mask[..., None]
    lo = jnp.minimum(jnp.min(jnp.where(m, vals, jnp.inf), axis=1), phi)
    hi = jnp.maximum(jnp.max(jnp.where(m, vals, -jnp.inf), axis=1), phi)
    return lo, hi


def detect(U_cand, bounds, scheme, params: Params):
    """Flags ``[N]`` of the detector chain (PAD, then NAD against ``bounds = (lo, hi)``)."""
    U_cand = jax.lax.stop_gradient(U_cand)
    if scheme.mood_pad:
        bad = ~admissible(U_cand, scheme, params)
    else:
        bad = ~jnp.all(jnp.isfinite(U_cand), axis=1)
    if scheme.mood_nad:
        lo, hi = bounds
        floor_rule = DELTA_FLOORS.get(scheme.mood_delta_floor, "scheme.mood_delta_floor")
        floor = floor_rule.floor(scheme.mood_delta_abs, lo, hi)
        delta = jnp.maximum(floor, scheme.mood_delta_rel * (hi - lo))
        phi = nad_fields(U_cand, scheme, params)
        out = (phi < lo - delta) | (phi > hi + delta) | ~jnp.isfinite(phi)
        bad = bad | jnp.any(out, axis=1)
    return bad


def mood_substep(z: Particles, params: Params, dt, geom, scheme, euler):
    """The MOOD-limited forward-Euler sub-step of one stage.

    ``euler(z_with_ppd) -> (E, dz)`` computes the candidate for a PPD map (the caller's rhs and
    update).  Returns ``(E, ppd, n_evals, unresolved[N])``: ``unresolved`` flags the particles
    still flagged after ``mood_max_iter`` iterations, and those already at the parachute (degree
    0) whose candidate is inadmissible (PAD) — first order is the last resort, so such a stage is
    never accepted silently.
    """
    high = scheme.reconstruction_degree
    fluid = z.kind == Kind.FLUID
    ppd0 = jnp.full_like(z.ppd, high)
    U_z = jax.lax.stop_gradient(z.q / z.vol[:, None])
    bounds = stencil_bounds(nad_fields(U_z, scheme, params), geom.idx, geom.mask) if scheme.mood_nad else None

    def flags(E, ppd):
        return detect(E.q / E.vol[:, None], bounds, scheme, params) & fluid & (ppd > 0)

    E0 = euler(z.replace(ppd=ppd0))
    f0 = flags(E0, ppd0)

    def body(c, _):
        E, ppd, f, n = c

        def redo(c):
            E, ppd, f, n = c
            ppd = jnp.where(f, 0, ppd)
            E = euler(z.replace(ppd=ppd))
            return E, ppd, flags(E, ppd), n + 1

        return jax.lax.cond(jnp.any(f), redo, lambda c: c, c), None

    (E, ppd, f, n), _ = jax.lax.scan(body, (E0, ppd0, f0, jnp.asarray(1, jnp.int32)), None,
                                     length=scheme.mood_max_iter)
    # the parachute itself must be admissible: a first-order particle whose candidate fails PAD
    # cannot be demoted further, so the stage is unresolved (the run's status then stops it)
    U_E = jax.lax.stop_gradient(E.q / E.vol[:, None])
    pad_fail = ~admissible(U_E, scheme, params) if scheme.mood_pad else ~jnp.all(jnp.isfinite(U_E), axis=1)
    parachute_failed = fluid & (ppd == 0) & pad_fail
    return E, ppd, n, f | parachute_failed


@dataclasses.dataclass(frozen=True)
class NoLimiter:
    """No a-posteriori limiting: the candidate of the scheme's reconstruction degree is accepted.

    Limiter protocol: ``substep(z, params, dt, geom, scheme, euler) -> (E, ppd, n_evals,
    unresolved[N])`` computes the stage's forward-Euler sub-step E = z + dt L(z) (``euler(z)``
    evaluates it for the degree map ``z.ppd``); ``needs_high_order``: it works on per-particle
    reconstruction degrees (reset to the scheme's degree every step) and needs one above 0;
    ``acts_on_substeps``: it has no ODE form (the diffrax path refuses it); ``summary_key``: the
    summary entry of its statistics, or ``None``."""

    needs_high_order: bool = False
    acts_on_substeps: bool = False
    summary_key: str | None = None

    def substep(self, z: Particles, params: Params, dt, geom, scheme, euler):
        return euler(z), z.ppd, jnp.asarray(1, jnp.int32), jnp.zeros(z.ppd.shape, bool)


@dataclasses.dataclass(frozen=True)
class MOODLimiter:
    """MOOD a-posteriori order reduction (module docstring; thesis §3.6.3)."""

    needs_high_order: bool = True
    acts_on_substeps: bool = True
    summary_key: str | None = "mood"

    def substep(self, z: Particles, params: Params, dt, geom, scheme, euler):
        return mood_substep(z, params, dt, geom, scheme, euler)


LIMITERS.register("none", NoLimiter())
LIMITERS.register("mood", MOODLimiter())
