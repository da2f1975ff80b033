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

    def planes(self, G, mu, d: int):
        """The same on nested lists of planes ``G[a][b]`` (the pair sweep)."""
        div = G[0][0]
        for a in range(1, d):
            div = div + G[a][a]
        return [[mu * (G[a][b] + G[b][a] - (2.0 / 3.0) * div if a == b else G[a][b] + G[b][a]) for b in range(d)]
                for a in range(d)]


@dataclasses.dataclass(frozen=True)
class IncompressibleStress:
    """tau = mu (grad u + grad u^T) (thesis ch. 3 form, eq. 3.14)."""

    def tensor(self, G, mu, d: int):
        return mu * (G + jnp.swapaxes(G, -1, -2))

    def planes(self, G, mu, d: int):
        """The same on nested lists of planes ``G[a][b]`` (the pair sweep)."""
        return [[mu * (G[a][b] + G[b][a]) for b in range(d)] for a in range(d)]


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


def diffusive_fields(prim, scheme):
    """The fields whose fits the diffusive flux needs, ``[N, nc]``: the velocity and, with heat
    conduction (and an energy equation), the specific internal energy e."""
    heat = scheme.heat_conduction and get_eos(scheme.eos).has_energy
    return jnp.concatenate([prim.vel] + ([prim.e[:, None]] if heat else []), axis=1)


def _coefficients(scheme, params):
    heat = scheme.heat_conduction and get_eos(scheme.eos).has_energy
    return (params["physics.mu"] if scheme.viscous else 0.0), (params["physics.kappa"] if heat else 0.0), heat


def _side_flux(a, xi, h, d: int, degree: int, heat: bool, mu, kappa, scheme, has_energy: bool):
    """Rows of D(U, grad u, grad e) (``[v][b]`` planes) at the points ``xi`` (list of d planes, in
    the fit's scaled frame) of the fit with coefficients ``a[mm][c]``, ``h`` its smoothing length."""
    from .approximation import mls

    nc = d + (1 if heat else 0)
    m = len(a)
    P = mls.monomial_planes(xi, degree)
    dP = mls.monomial_gradient_planes(xi, degree)
    val = []
    for c in range(d):
        o = a[0][c]
        for mm in range(1, m):
            o = o + P[mm] * a[mm][c]
        val.append(o)
    inv_h = 1.0 / h
    grad = []                                                   # grad[c][b] = d f_c / d x_b
    for c in range(nc):
        row = []
        for b in range(d):
            g = None
            for mm in range(1, m):
                t = dP[b][mm]
                if t is None:
                    continue
                term = a[mm][c] if isinstance(t, float) and t == 1.0 else t * a[mm][c]
                g = term if g is None else g + term
            row.append(g * inv_h)
        grad.append(row)
    law = STRESSES.get(scheme.stress, "scheme.stress")
    if hasattr(law, "planes"):
        tau = law.planes(grad[:d], mu, d)
    else:                                   # a stress law with only the array form (protocol)
        T = law.tensor(jnp.stack([jnp.stack(row, axis=-1) for row in grad[:d]], axis=-2), mu, d)
        tau = [[T[..., r, c] for c in range(d)] for r in range(d)]
    rows = list(tau)
    if has_energy:
        e_row = []
        for b in range(d):
            t = tau[0][b] * val[0]
            for c in range(1, d):
                t = t + tau[c][b] * val[c]
            if heat:
                t = t + kappa * grad[d][b]
            e_row.append(t)
        rows.append(e_row)
    return rows


def pair_diffusive_flux(ai, aj, dx, hi, hj, A, degree: int, scheme, params):
    """D_ij . A_ij = 1/2 (D^-_ij + D^+_ij) . A_ij on lists of component planes (the blocked pair
    sweep of :func:`mlsph_jax.rhs.rhs`): D^- from i's fit (coefficients ``ai[mm][c]``, broadcast
    rows) at xi = (x_ij - x_i)/h_i, D^+ from j's fit (``aj``, gathered) at (x_ij - x_j)/h_j;
    ``dx`` = x_j - x_i and ``A`` lists of d planes.  Returns nv planes; the mass row is zero."""
    d = len(A)
    mu, kappa, heat = _coefficients(scheme, params)
    has_energy = get_eos(scheme.eos).has_energy
    Di = _side_flux(ai, [(0.5 * c) / hi for c in dx], hi, d, degree, heat, mu, kappa, scheme, has_energy)
    Dj = _side_flux(aj, [(-0.5 * c) / hj for c in dx], hj, d, degree, heat, mu, kappa, scheme, has_energy)
    out = [jnp.zeros_like(A[0])]
    for ri, rj in zip(Di, Dj, strict=True):
        t = (ri[0] + rj[0]) * A[0]
        for b in range(1, d):
            t = t + (ri[b] + rj[b]) * A[b]
        out.append(0.5 * t)
    return out


def self_diffusive_flux(prim, coeffs, h, sum_A, scheme, params):
    """D_i . sum_j A_ij (the self term of the diffusive flux, ``[N, nv]``): D_i with the particle's
    own velocity and the fitted gradients at x_i, the linear coefficients ``coeffs[N, 1 + b, c]``
    of the fit over h_i."""
    d = prim.vel.shape[1]
    grad0 = jnp.swapaxes(coeffs[:, 1:1 + d, :], 1, 2) / h[:, None, None]     # [N, nc, d]
    mu, kappa, heat = _coefficients(scheme, params)
    has_energy = get_eos(scheme.eos).has_energy
    ge0 = grad0[:, d, :] if heat else None
    D_i = _flux_tensor(grad0[:, :d, :], prim.vel, ge0, mu, kappa, scheme.stress, has_energy, d)
    return jnp.einsum("nvd,nd->nv", D_i, sum_A)


def viscous_terms(prim, geom, scheme, params, degree: int):
    """sum_j [D_ij - s D_i] . A_ij for every particle, ``[N, nv]`` (module docstring), as a separate
    array pass.  :func:`mlsph_jax.rhs.rhs` uses it only for first-order convective states; with a
    reconstruction the fit of the reconstruction serves the diffusive fields and the pair terms
    are part of the one pair sweep (:func:`pair_diffusive_flux`, :func:`self_diffusive_flux`)."""
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
