"""Consistency correction of the area vectors (registry ``scheme.area_correction``; decision 59).

With the self-flux term (``scheme.self_flux``, thesis eq. 4.36) the convective rate of particle i
is - sum_j (G_ij - F_i) . A_ij, which for a smooth flux and exact midpoint states G_ij = F(x_ij),
x_ij = (x_i + x_j)/2, should equal - V_i div F(x_i).  With the MLSPH-ALE area vectors
A_ij = V_i grad N_j(x_i) - V_j grad N_i(x_j) (thesis eq. 4.36, 5.77) this holds, for fluxes of
degree <= q, when at every particle i and for every monomial phi of degree 1..q of
xi = (x - x_i)/h_i

    sum_j A_ij [phi(xi_ij) - phi(0)] = V_i grad phi(x_i),      xi_ij = (x_ij - x_i)/h_i.     (*)

The first half of A_ij (the MLS gradients at x_i) satisfies its share of (*) exactly; the second
half, - V_j grad N_i(x_j), is a one-point quadrature of int -grad N_i (...) and satisfies it only
on symmetric (lattice) stencils.  On a layout jittered by +-0.15 dx the linear rows of (*) are
off by ~9 % rms *at every resolution*: a zeroth-order error of the divergence, which dominates
the Taylor-Green error on that layout (docs/validation.md, "Taylor-Green on the perturbed layout").

``linear`` / ``quadratic`` add the smallest antisymmetric Delta A (least squares over the stencil
pairs, equal weights) for which (*) holds exactly to degree q = 1 / 2: the midpoint divergence of
every flux of degree <= q is then exact on any layout (second-order consistent for ``quadratic``).
Antisymmetry (Delta A_ji = -Delta A_ij, hence conservation of the pair terms) is kept by
construction: Delta A_ij = Y_ij - Y_ji.  The constraints couple neighbouring particles; the
normal equations L L^T mu = r are solved by block-Jacobi preconditioned conjugate gradients
(matrix-free, jit-able, differentiable).  The closure sum_j A_ij (the quadrature defect of SPEC
§5.5) is not constrained: with it the system converged 10 x slower and gave a larger error
(decision 59).  On a lattice (*) already holds to round-off, so the areas are unchanged there.
One CG solve per geometry: once per run for Eulerian particles (and after a neighbour regrowth),
once per stage for moving ones.
``linear_interior`` / ``quadratic_interior`` (decision 88) impose (*) only on the rows whose
uncorrected closure |sum_j A_ij| h_i / V_i is at most ``INTERIOR_CLOSURE``: complete stencils.  Where a
stencil is truncated (a body's first rings, the outer edge of frozen far-field rings) the exact identity
has a boundary term that (*) lacks; imposing (*) there makes Delta A O(1) and, through the coupling of
the rows, spreads it over the whole layout (the cylinder diverged: docs/validation.md, cylinder).
The closure is not a completeness test on irregular periodic layouts (perturbed Taylor-Green: median
0.27 V/h, 614 of 625 rows above the threshold): use ``quadratic`` there.
``linear_complete`` / ``quadratic_complete`` (decision 92) decide completeness from the structure,
not from a threshold.  With partition of unity and linear reproduction of the MLS shape functions
N_j, the continuous areas A_ij = int (N_i grad N_j - N_j grad N_i) dOmega satisfy
sum_j A_ij (x) (x_j - x_i)/2 = V_i I - (1/2) int_dOmega N_i n (x) (x - x_i) dGamma (integration by
parts, thesis eqs. 4.19-4.24), so (*) is the right identity exactly on the rows whose shape function
does not reach the boundary of the particle region: the rows of :func:`complete_rows`, fluid
particles in no wall point's stencil (N_i(x_b) = 0 for every quadrature point x_b; SPEC §5.8).  The
wall rows' identity holds the wall integral: decision 60's first-moment correction (computed from
the corrected areas) makes them exact.  Frozen far-field rings and mirror ghosts are not
constrained (their rates are not used; the outermost frozen rings are truncated by the layout's
edge, and the frozen reach is a full support, so no fluid row's support crosses it).  The caller
passes the rows (``rhs.geometry(..., complete=...)``; the drivers do).
``apply`` returns ``(A, converged)``; a solve that stops at ``CG_MAXITER`` above its tolerance sets
``Status.AREA_CORRECTION_UNCONVERGED`` (through ``Geometry.overflow``), which stops the run loudly.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from .approximation import basis
from .errors import InputError
from .registry import Registry
from .state import Kind
from .stencil import reverse_gather

AREA_CORRECTIONS: Registry = Registry("scheme.area_correction", protocol=("apply",),
                                      doc="corrections of the area vectors A_ij; apply(...) -> (A, converged)")

#: CG stopping rule (absolute residual of the constraints in units of the areas' size) and cap.
CG_ATOL = 1e-13
CG_MAXITER = 5000
#: Relative regularisation of the normal equations and floor of the preconditioner blocks.
EPS = 1e-10


@dataclasses.dataclass(frozen=True)
class NoCorrection:
    """The thesis' one-point-quadrature area vectors, unchanged."""

    #: whether ``apply`` needs the structurally complete rows (:func:`complete_rows`)
    structural = False

    def apply(self, A, dx, h, vol, jsafe, rev, pair_mask, complete=None):
        return A, jnp.asarray(True)


def constraint_planes(dx, h, degree: int):
    """Q[N, K, m-1] = phi(xi_ij) for the monomials phi of degree 1..q of xi = (x - x_i)/h_i at the
    pair midpoints (phi(0) = 0), and G[N, m-1, d] = grad phi(x_i): the rows of (*) are
    sum_k A[i, k, a] Q[i, k, r] = V_i G[i, r, a]."""
    xi = 0.5 * dx / h[:, None, None]
    Q = basis.evaluate(xi, degree)[..., 1:]
    G = jnp.asarray(basis.gradient_at_origin(degree, dx.shape[-1])[1:])[None] / h[:, None, None]
    return Q, G


def moment_defect(A, dx, h, vol, pair_mask, degree: int):
    """Left minus right side of (*) per particle, ``[N, d, m-1]``, relative to V_i / h_i."""
    Q, G = constraint_planes(dx, h, degree)
    Q = jnp.where(pair_mask[..., None], Q, 0.0)
    lhs = jnp.einsum("nka,nkr->nar", A, Q)
    return (lhs - vol[:, None, None] * jnp.swapaxes(G, 1, 2)) * (h / vol)[:, None, None]


def complete_rows(p, boundary=None):
    """Rows whose stencil is complete by construction (decision 92): fluid particles that are in no
    wall point's stencil (no boundary-integral term, ``boundary.wall_rows``).  Frozen, ghost and
    boundary particles are left out: their rates are not used (frozen rings are reset each stage,
    ghosts regenerated), and the outermost of them are truncated by the layout's outer edge."""
    rows = p.kind == Kind.FLUID
    walls = getattr(boundary, "wall_rows", None)
    return rows if walls is None else rows & ~walls(p)


def wants_complete_rows(scheme) -> bool:
    """Whether ``scheme``'s area correction needs :func:`complete_rows`."""
    return bool(getattr(scheme.component("area_correction"), "structural", False))


@dataclasses.dataclass(frozen=True)
class ConsistentCorrection:
    """Smallest antisymmetric correction making the midpoint divergence exact to degree ``degree``
    (module docstring)."""

    degree: int = 2
    #: ``None``: (*) on every row.  A number: (*) only on the rows whose closure
    #: |sum_j A_ij| h_i / V_i is at most this (complete stencils; decision 88)
    closure_tol: float | None = None
    #: (*) only on the rows ``complete`` (:func:`complete_rows`: fluid rows without a wall term;
    #: decision 92), which the caller must then pass
    structural: bool = False

    def apply(self, A, dx, h, vol, jsafe, rev, pair_mask, complete=None):
        # solved in float64 whatever the state's precision (run.precision = "float32" keeps the
        # small moment differences, like the MLS moment matrices, in float64); A returned in its own
        out_dtype = A.dtype
        A, dx, h, vol = (jnp.asarray(a, jnp.float64) for a in (A, dx, h, vol))
        Q, G = constraint_planes(dx, h, self.degree)
        Q = jnp.where(pair_mask[..., None], Q, 0.0)
        target = vol[:, None, None] * jnp.swapaxes(G, 1, 2)          # [N, d, m-1]
        w = pair_mask[..., None].astype(A.dtype)
        if self.structural:
            if complete is None:
                raise InputError("scheme.area_correction: the complete-stencil variants (decision 92) need the "
                                 "particles' kinds and walls (rhs.geometry(..., complete=complete_rows(p, boundary)))")
            rows = jnp.asarray(complete).astype(A.dtype)
        elif self.closure_tol is None:
            rows = jnp.ones_like(vol)
        else:
            rows = (jnp.linalg.norm(jnp.sum(A, axis=1), axis=-1) * h / vol <= self.closure_tol).astype(A.dtype)

        def moments(a):                                              # [N, K, d] -> [N, d, m-1]
            return rows[:, None, None] * jnp.einsum("nka,nkr->nar", a, Q)

        def lift(y):                                                 # free slot field -> antisymmetric
            return w * (y - reverse_gather(y, jsafe, rev))

        def L(y):
            return moments(lift(y))

        LT = jax.linear_transpose(L, jnp.zeros_like(A))
        # block-Jacobi preconditioner: the per-particle diagonal blocks 2 sum_k Q Q^T of L L^T, with
        # a relative floor; the same small multiple regularises the normal equations
        J = 2.0 * jnp.einsum("nk,nkr,nks->nrs", w[..., 0], Q, Q)
        m = Q.shape[-1]
        floor = EPS * jnp.trace(J, axis1=1, axis2=2) / m
        Jinv = jnp.linalg.inv(J + floor[:, None, None] * jnp.eye(m, dtype=J.dtype))
        reg = EPS * jnp.mean(floor)

        def normal(mu):
            return L(LT(mu)[0]) + reg * mu

        def precond(v):
            return jnp.einsum("nrs,nas->nar", Jinv, v)

        scale = jnp.sqrt(jnp.sum((vol / h) ** 2))                    # the size of the areas (V / h)
        r = (rows[:, None, None] * target - moments(A)) / scale
        # the tolerance of the areas' own precision: a float32 state only needs (and its rounded
        # lattice offsets only allow) the correction to float32 resolution
        atol = CG_ATOL if out_dtype == jnp.float64 else 0.1 * float(jnp.finfo(out_dtype).eps)
        mu, _ = jax.scipy.sparse.linalg.cg(normal, r, tol=0.0, atol=atol, maxiter=CG_MAXITER, M=precond)
        # jax's cg returns no convergence flag: the residual of the normal equations, checked
        # against a hundred times the stopping tolerance (a solve that ran into CG_MAXITER)
        res = normal(mu) - r
        converged = jax.lax.stop_gradient(jnp.sqrt(jnp.sum(res * res)) <= 100.0 * atol)
        return (A + scale * lift(LT(mu)[0])).astype(out_dtype), converged


AREA_CORRECTIONS.register("none", NoCorrection())
AREA_CORRECTIONS.register("linear", ConsistentCorrection(1))
AREA_CORRECTIONS.register("quadratic", ConsistentCorrection(2))
#: decision 88: (*) only on complete stencils (closure below INTERIOR_CLOSURE)
INTERIOR_CLOSURE = 0.05
AREA_CORRECTIONS.register("linear_interior", ConsistentCorrection(1, INTERIOR_CLOSURE))
AREA_CORRECTIONS.register("quadratic_interior", ConsistentCorrection(2, INTERIOR_CLOSURE))
#: decision 92: (*) only on the structurally complete rows (fluid rows without a wall term)
AREA_CORRECTIONS.register("linear_complete", ConsistentCorrection(1, structural=True))
AREA_CORRECTIONS.register("quadratic_complete", ConsistentCorrection(2, structural=True))
