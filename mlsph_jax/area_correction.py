"""Consistency correction of the area vectors (registry ``scheme.area_correction``; decision 59).

The MLSPH-ALE area vectors A_ij = V_i grad N_j(x_i) - V_j grad N_i(x_j) (thesis eq. 4.36, 5.77)
replace the integrals of the weak form by one-point quadrature.  With the exact integrals they
would satisfy, in a periodic box,

    sum_j A_ij = int grad N_i = 0                               (closure)
    sum_j A_ij (x) (x_j - x_i) = 2 int N_i I = 2 V_i I          (linear consistency)

and the scheme's divergence sum_j (F_ij - F_i) . A_ij with the midpoint flux F_ij = F(x_ij) would
be exact for linear fluxes.  On a lattice the one-point rule keeps both to round-off (symmetry);
on an irregular layout it does not: with a +-0.15 dx jitter the linear defect is ~9 % rms per
particle *at every resolution*, a zeroth-order error of the divergence that dominates the
Taylor-Green error there (docs/validation.md, "Taylor-Green on the perturbed layout").

The correction adds the smallest antisymmetric Delta A (least squares, weighted by |A_ij|) for
which, at every particle i and for every monomial phi of (x - x_i)/h_i of degree 1..q,

    sum_j (A_ij + Delta A_ij) [phi(xi_ij) - phi(0)] = V_i grad phi(x_i),   xi_ij = (x_ij - x_i)/h_i,

i.e. the discrete divergence of every polynomial flux of degree <= q, evaluated at the pair
midpoints, is exact, and sum_j (A_ij + Delta A_ij) = 0 (closure, hence the self-flux term vanishes
and the pair terms alone conserve).  q = 1 (``linear``) or 2 (``quadratic``; a quadratic flux is
then also exact).  Antisymmetry is kept by construction (Delta A_ij = w_ij (Y_ij - Y_ji)), so the
scheme stays conservative.  The constraints couple all particles; the normal equations
L L^T mu = r are solved by conjugate gradients (matrix-free, jit-able and differentiable).
Exact on a lattice (r = 0 to round-off there); costs one CG solve per geometry (once per chunk for
Eulerian particles, once per stage for moving ones).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from .approximation import basis
from .registry import Registry
from .stencil import reverse_gather

AREA_CORRECTIONS: Registry = Registry("scheme.area_correction", protocol=("apply",),
                                      doc="corrections of the area vectors A_ij")

#: CG stopping rule: relative residual of the constraints, and the iteration cap.
CG_TOL = 1e-13
CG_MAXITER = 20000
#: Relative regularisation of the normal equations and floor of the preconditioner blocks.
EPS = 1e-10


@dataclasses.dataclass(frozen=True)
class NoCorrection:
    """The thesis' one-point-quadrature area vectors, unchanged."""

    def apply(self, A, dx, h, vol, jsafe, rev, pair_mask):
        return A


def constraint_planes(dx, h, degree: int):
    """Q[N, K, m]: 1 (closure) and phi(xi_ij) - phi(0) for the monomials phi of degree 1..q of
    xi = (x - x_i)/h_i at the pair midpoints, and the targets' factor G[N, m, d] = grad phi(x_i)
    (so that the target of row (i, a, phi) is V_i G[i, phi, a])."""
    d = dx.shape[-1]
    xi = 0.5 * dx / h[:, None, None]
    P = basis.evaluate(xi, degree)                                   # [N, K, m]; phi(0) = 0 except 1
    Q = P.at[..., 0].set(1.0)
    G = jnp.asarray(basis.gradient_at_origin(degree, d))[None] / h[:, None, None]
    return Q, G


@dataclasses.dataclass(frozen=True)
class ConsistentCorrection:
    """Smallest antisymmetric correction making the midpoint divergence exact to degree ``degree``
    (module docstring)."""

    degree: int = 1
    weight_power: float = 1.0
    closure: bool = True

    def apply(self, A, dx, h, vol, jsafe, rev, pair_mask):
        Q, G = constraint_planes(dx, h, self.degree)
        Q = jnp.where(pair_mask[..., None], Q, 0.0)
        if not self.closure:
            Q = Q[..., 1:]
            G = G[:, 1:]
        target = vol[:, None, None] * jnp.swapaxes(G, 1, 2)          # [N, d, m]
        mag = jnp.sqrt(jnp.sum(A * A, axis=-1))
        w = jnp.where(pair_mask, (mag / jnp.maximum(jnp.max(mag), 1e-300)) ** self.weight_power, 0.0)[..., None]

        def moments(a):                                              # [N, K, d] -> [N, d, m]
            return jnp.einsum("nka,nkm->nam", a, Q)

        def lift(y):                                                 # free slot field -> antisymmetric
            return w * (y - reverse_gather(y, jsafe, rev))

        def L(y):
            return moments(lift(y))

        y0 = jnp.zeros_like(A)
        LT = jax.linear_transpose(L, y0)
        # block-Jacobi preconditioner: the per-particle diagonal blocks 2 sum_k w^2 Q Q^T of L L^T,
        # with a relative floor that also regularises the null space (constant multipliers of the
        # closure rows, which the antisymmetric lift cannot see)
        J = 2.0 * jnp.einsum("nk,nkm,nkl->nml", w[..., 0] ** 2, Q, Q)
        m = Q.shape[-1]
        floor = EPS * jnp.trace(J, axis1=1, axis2=2) / m
        Jinv = jnp.linalg.inv(J + floor[:, None, None] * jnp.eye(m))
        reg = EPS * jnp.mean(floor)

        def normal(mu):
            return L(LT(mu)[0]) + reg * mu

        def precond(v):
            return jnp.einsum("nml,nal->nam", Jinv, v)

        r = target - moments(A)
        scale = jnp.sqrt(jnp.sum((vol / h) ** 2))                    # the size of the areas (V / h)
        mu, _ = jax.scipy.sparse.linalg.cg(normal, r / scale, tol=0.0, atol=CG_TOL, maxiter=CG_MAXITER,
                                           M=precond)
        return A + scale * lift(LT(mu)[0])


AREA_CORRECTIONS.register("none", NoCorrection())
AREA_CORRECTIONS.register("closure", ConsistentCorrection(0))
AREA_CORRECTIONS.register("linear", ConsistentCorrection(1))
AREA_CORRECTIONS.register("quadratic", ConsistentCorrection(2))
AREA_CORRECTIONS.register("quadratic_w0", ConsistentCorrection(2, 0.0))
AREA_CORRECTIONS.register("quadratic_w05", ConsistentCorrection(2, 0.5))
AREA_CORRECTIONS.register("linear_w0", ConsistentCorrection(1, 0.0))
AREA_CORRECTIONS.register("linear_noclosure", ConsistentCorrection(1, 1.0, False))
AREA_CORRECTIONS.register("quadratic_noclosure", ConsistentCorrection(2, 1.0, False))
AREA_CORRECTIONS.register("quadratic_noclosure_w0", ConsistentCorrection(2, 0.0, False))
