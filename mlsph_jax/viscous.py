"""Viscous and heat fluxes (thesis eq. 3.14 and 4.40; SPEC §1.2, §5.6, §13.2 item 16).

The Navier-Stokes flux is F - D with the diffusive flux (rows: mass, momentum, energy)

    D(U, grad u, grad e) = (0,  tau,  tau u - q),
    tau = mu (grad u + grad u^T - 2/3 (div u) I)      (``scheme.stress = "stokes"``), or
    tau = mu (grad u + grad u^T)                      (``"incompressible"``: thesis ch. 3 form),
    q   = -kappa grad e                                (``physics.kappa`` = k / c_v; Fourier's law
                                                        for a calorically perfect fluid),

and enters the particle balance like the convective flux (thesis eq. 4.36 with eq. 4.40):

    d(V_i U_i)/dt += sum_j [D_ij - s D_i] . A_ij,     D_ij = 1/2 (D^-_ij + D^+_ij).

D^-_ij is evaluated at the pair midpoint x_ij from particle i's fixed-centre MLS fit of the
primitive velocity (and e): values p(xi_ij)^T a_i and gradients grad p(xi_ij)^T a_i / h_i with
xi_ij = (x_ij - x_i)/h_i (SPEC §5.6 [REC]); D^+_ij is the same quantity of the reverse pair
(j's fit at the same midpoint).  D_i uses the fit's gradient at x_i and the particle's own
velocity; s is ``scheme.self_flux``.  Viscous fluxes are not order-reduced by MOOD (SPEC item
24).  For the Tait EOS there is no energy equation, so no energy row and no heat flux.

Time step: dt <= ``time.cfl_viscous`` min_i rho_i dx_i^2 / mu (explicit diffusion limit), and
likewise with kappa for heat conduction (:func:`mlsph_jax.integrate.cfl_dt`).
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp

from .approximation import basis
from .eos import get_eos
from .registry import Registry
from .stencil import reverse_gather

STRESSES: Registry = Registry("scheme.stress", protocol=("tensor",), doc="viscous stress laws")


@dataclasses.dataclass(frozen=True)
class StokesStress:
    """tau = mu (grad u + grad u^T - 2/3 (div u) I) (Stokes' hypothesis, thesis eq. 4.40)."""

    def tensor(self, G, mu, d: int):
        tau = G + jnp.swapaxes(G, -1, -2)
        div = jnp.trace(G, axis1=-2, axis2=-1)
        return mu * (tau - (2.0 / 3.0) * div[..., None, None] * jnp.eye(d, dtype=G.dtype))


@dataclasses.dataclass(frozen=True)
class IncompressibleStress:
    """tau = mu (grad u + grad u^T) (thesis ch. 3 form, eq. 3.14)."""

    def tensor(self, G, mu, d: int):
        return mu * (G + jnp.swapaxes(G, -1, -2))


STRESSES.register("stokes", StokesStress())
STRESSES.register("incompressible", IncompressibleStress())


def _flux_tensor(G, u, ge, mu, kappa, stress: str, has_energy: bool, d: int):
    """D[..., nv, d] from velocity gradient G[..., d, d] (G[a, b] = du_a/dx_b), velocity u[..., d]
    and (energy) gradient of e ge[..., d]."""
    tau = STRESSES.get(stress, "scheme.stress").tensor(G, mu, d)
    rows = [jnp.zeros(G.shape[:-2] + (1, d), G.dtype), tau]
    if has_energy:
        e_flux = jnp.einsum("...ab,...a->...b", tau, u)
        if ge is not None:
            e_flux = e_flux + kappa * ge
        rows.append(e_flux[..., None, :])
    return jnp.concatenate(rows, axis=-2)


def viscous_terms(prim, geom, scheme, params, degree: int):
    """sum_j [D_ij - s D_i] . A_ij for every particle, ``[N, nv]`` (module docstring)."""
    eos = get_eos(scheme.eos)
    vel = prim.vel
    n, d = vel.shape
    heat = scheme.heat_conduction and eos.has_energy
    cols = [vel] + ([prim.e[:, None]] if heat else [])
    f = jnp.concatenate(cols, axis=1)                                # [N, nc]
    jsafe = geom.jsafe
    a = jnp.einsum("nmk,nkc->nmc", geom.coeffs, f[jsafe])            # fixed-centre fit a_i
    h = geom.h[:, None, None]
    xi = 0.5 * geom.dx / h                                           # midpoint in i's scaled frame
    P = basis.evaluate(xi, degree)                                   # [N, K, m]
    dP = basis.gradient(xi, degree) / h[..., None]                   # [N, K, m, d]
    val = jnp.einsum("nkm,nmc->nkc", P, a)
    grad = jnp.einsum("nkmd,nmc->nkcd", dP, a)                       # [N, K, nc, d]
    dP0 = jnp.asarray(basis.gradient_at_origin(degree, d), geom.h.dtype) / geom.h[:, None, None]   # [N, m, d]
    grad0 = jnp.einsum("nmd,nmc->ncd", dP0, a)                       # [N, nc, d]
    mu = params["physics.mu"] if scheme.viscous else 0.0
    kappa = params["physics.kappa"] if heat else 0.0
    ge, ge0 = (grad[..., d, :], grad0[:, d, :]) if heat else (None, None)
    D_own = _flux_tensor(grad[..., :d, :], val[..., :d], ge, mu, kappa, scheme.stress, eos.has_energy, d)
    D_other = reverse_gather(D_own, jsafe, geom.rev)
    D_pair = 0.5 * (D_own + D_other)
    if scheme.self_flux:
        D_i = _flux_tensor(grad0[:, :d, :], vel, ge0, mu, kappa, scheme.stress, eos.has_energy, d)
        D_pair = D_pair - D_i[:, None]
    D_pair = jnp.where(geom.pair_mask[..., None, None], D_pair, 0.0)
    return jnp.einsum("nkvd,nkd->nv", D_pair, geom.A)


def particle_flux(prim, geom, scheme, params):
    """D_i ``[N, nv, d]``: the diffusive flux of every particle from its own fixed-centre fit's
    gradient at x_i and its own velocity (the self term of :func:`viscous_terms`; used by the
    boundary-integral walls, :mod:`mlsph_jax.wall_integral`)."""
    eos = get_eos(scheme.eos)
    vel = prim.vel
    d = vel.shape[1]
    heat = scheme.heat_conduction and eos.has_energy
    f = jnp.concatenate([vel] + ([prim.e[:, None]] if heat else []), axis=1)
    a = jnp.einsum("nmk,nkc->nmc", geom.coeffs, f[geom.jsafe])
    dP0 = jnp.asarray(basis.gradient_at_origin(scheme.fit_degree, d), geom.h.dtype) / geom.h[:, None, None]
    grad0 = jnp.einsum("nmd,nmc->ncd", dP0, a)
    mu = params["physics.mu"] if scheme.viscous else 0.0
    kappa = params["physics.kappa"] if heat else 0.0
    return _flux_tensor(grad0[:, :d, :], vel, grad0[:, d, :] if heat else None, mu, kappa, scheme.stress,
                        eos.has_energy, d)


def wall_flux(G, u_wall, mu, scheme):
    """Diffusive flux ``[..., nv, d]`` at a no-slip adiabatic wall point from the velocity gradient
    ``G[..., d, d]`` of a fit that passes through the wall velocity ``u_wall[..., d]`` (no heat
    flux through the wall)."""
    eos = get_eos(scheme.eos)
    return _flux_tensor(G, u_wall, None, mu, 0.0, scheme.stress, eos.has_energy, G.shape[-1])
