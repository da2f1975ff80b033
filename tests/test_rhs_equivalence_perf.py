"""The performance-oriented implementations of :mod:`mlsph_jax.rhs`, :mod:`mlsph_jax.flux` and the
batched MLS operators (:func:`mlsph_jax.approximation.mls.operators_block`) equal straightforward
reference implementations to round-off.

The references below are written the obvious way (per-particle ``jnp.linalg.solve`` and
``jax.jacfwd`` of N(x) = p(0)^T M(x)^{-1} P W(x), ``einsum`` reconstructions, 2D reverse-slot
indexing, array-valued Rusanov flux); the library computes the same quantities block-wise on
structure-of-arrays planes with variadic reductions, a closed-form full MLS derivative
(dz = -M^{-1} (dM) z with the Cholesky factor of the fit) and a flat reverse gather.  Tolerances
are relative to the magnitude of each compared array (outputs of the right-hand side relative
to the largest pair flux, since d(VU)/dt is a sum of nearly cancelling fluxes).
"""

from __future__ import annotations

import dataclasses
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mlsph_jax  # noqa: F401  (float64)
from mlsph_jax import Domain, Params, make_particles
from mlsph_jax import approximation as apx
from mlsph_jax import neighbors as nb
from mlsph_jax.approximation import basis, mls
from mlsph_jax.eos import get_eos, to_conservative, to_primitive
from mlsph_jax.kernels import get_kernel, safe_norm
from mlsph_jax.rhs import Geometry, geometry, reconstruct, rhs, source
from mlsph_jax.scheme import Scheme
from mlsph_jax.state import Kind

DOMAIN = Domain((0.0, 0.0), (1.0, 1.0), (True, True))
GAS = Params({"eos.gamma": 1.4})
TAIT = Params({"eos.rho0": 1.0, "eos.c0": 10.0, "eos.gamma": 7.0, "eos.p0": 0.0})
RTOL = 1e-12


def close(new, ref, rtol=RTOL, scale=None):
    new, ref = np.asarray(new), np.asarray(ref)
    scale = np.abs(ref).max() if scale is None else scale
    err = np.abs(new - ref).max()
    assert err <= rtol * max(scale, 1e-300), f"max error {err:.3e} vs scale {scale:.3e}"


def setup(scheme: Scheme, n1=18, jitter=0.3, eos="ideal_gas", seed=0):
    rng = np.random.default_rng(seed)
    g = (
        np.stack(np.meshgrid(np.arange(n1), np.arange(n1), indexing="ij"), -1).reshape(-1, 2) + 0.5
    ) / n1
    x = (g + rng.uniform(-jitter, jitter, g.shape) / n1) % 1.0
    vol = np.full(len(x), 1.0 / len(x)) * rng.uniform(0.9, 1.1, len(x))
    k = 2 * np.pi
    rho = 1.0 + 0.2 * np.sin(k * x[:, 0]) * np.cos(k * x[:, 1])
    vel = np.stack([0.3 * np.sin(k * x[:, 1]), 0.2 * np.cos(k * x[:, 0])], 1)
    p = 1.0 + 0.1 * np.cos(k * (x[:, 0] + x[:, 1]))
    params = GAS if eos == "ideal_gas" else TAIT
    U = to_conservative(jnp.asarray(rho), jnp.asarray(vel), jnp.asarray(p), get_eos(eos), params)
    kind = np.zeros(len(x), np.int32)
    kind[5] = Kind.FROZEN
    ppd = np.full(len(x), 3, np.int32)
    ppd[::11] = 0  # MOOD first-order particles
    particles = make_particles(x, vol, U, kind=kind, ppd=ppd)
    h = scheme.beta * np.sqrt(vol)
    _, nl = nb.allocate(x, h, DOMAIN, support=scheme.support)
    return particles, params, nl


# ----------------------------------------------------------------------------------------------
# straightforward references
# ----------------------------------------------------------------------------------------------


def ref_mls(dx, mask, h, degree, derivative):
    """Per particle: C = M^-1 P^T W by jnp.linalg.solve, N = C[0], gradients by jax.jacfwd of
    N(x_e + s) (full) or h^-1 grad p(0)^T C (fixed centre).  No degree fallback: the layouts
    used here keep the full degree everywhere (checked)."""
    kern = get_kernel("cubic_spline")
    d = dx.shape[-1]

    def shape(dxe, me, he, s):
        y = jnp.where(me[:, None], dxe, 0.0) - s
        w = kern.w_vec(y, he) * me
        P = basis.evaluate(y / he, degree)
        M = (P * w[:, None]).T @ P
        z = jnp.linalg.solve(M, jnp.eye(M.shape[0])[0])
        return w * (P @ z), jnp.linalg.solve(M, (P * w[:, None]).T)

    def one(dxe, me, he):
        vals, C = shape(dxe, me, he, jnp.zeros(d))
        if derivative == "full":
            g = jax.jacfwd(lambda s: shape(dxe, me, he, s)[0])(jnp.zeros(d))
        else:
            g = jnp.einsum("md,mk->kd", jnp.asarray(basis.gradient_at_origin(degree, d)), C) / he
        return jnp.where(me, vals, 0.0), jnp.where(me[:, None], g, 0.0), C

    return jax.vmap(one)(dx, mask, h)


def ref_geometry(x, vol, nl, scheme: Scheme):
    n, d = x.shape
    L, per = jnp.asarray(DOMAIN.length), jnp.asarray(DOMAIN.periodic)
    h = apx.smoothing_length(vol, scheme.beta, d)
    dx = apx.pair_offsets(x, nl.idx, nl.mask, L, per)
    jsafe = jnp.where(nl.mask, nl.idx, jnp.arange(n)[:, None])
    pair_mask = nl.mask & (nl.idx != jnp.arange(n)[:, None])
    coeffs = None
    if scheme.method == "mlsph_ale":
        values, G, C = ref_mls(dx, nl.mask, h, scheme.degree, scheme.derivative)
        A = vol[:, None, None] * G - vol[jsafe][..., None] * G[jsafe, nl.rev]
        interp = values
        if scheme.reconstruction_degree == scheme.degree:
            coeffs = C
    else:
        hij = 0.5 * (h[:, None] + h[jsafe])
        A = (
            2.0
            * vol[:, None, None]
            * vol[jsafe][..., None]
            * get_kernel(scheme.kernel).grad(-dx, hij)
        )
        interp = None
    if coeffs is None and scheme.reconstruction_degree > 0:
        coeffs = ref_mls(dx, nl.mask, h, scheme.reconstruction_degree, "fixed_centre")[2]
    A = jnp.where(pair_mask[..., None], A, 0.0)
    return dict(dx=dx, A=A, coeffs=coeffs, interp=interp, pair_mask=pair_mask, jsafe=jsafe)


def ref_flux(Um, Up, w_ij, A, n_pair, eos, params, wave_speed, normal):
    def fdot(U, pr, a):
        va = jnp.sum((pr.vel - w_ij) * a, axis=-1)
        parts = [
            U[..., :1] * va[..., None],
            U[..., 1 : 1 + a.shape[-1]] * va[..., None] + pr.p[..., None] * a,
        ]
        if eos.has_energy:
            parts.append((U[..., -1] * va + pr.p * jnp.sum(pr.vel * a, axis=-1))[..., None])
        return jnp.concatenate(parts, axis=-1)

    pm, pp = to_primitive(Um, eos, params), to_primitive(Up, eos, params)
    central = 0.5 * (fdot(Um, pm, A) + fdot(Up, pp, A))
    if normal == "area":
        amag = safe_norm(A)
        n, ndA = A / jnp.where(amag > 0, amag, 1.0)[..., None], amag
    else:
        n, ndA = n_pair, jnp.abs(jnp.sum(n_pair * A, axis=-1))   # |n . A|: never anti-diffusive (decision 38)
    vm, vp = jnp.sum((pm.vel - w_ij) * n, -1), jnp.sum((pp.vel - w_ij) * n, -1)
    if wave_speed == "rusanov_abs":
        S = jnp.maximum(jnp.abs(vm) + pm.c, jnp.abs(vp) + pp.c)
    elif wave_speed == "printed_ch3":
        S = jnp.maximum(vp + pp.c, vm - pm.c)
    else:
        v, cij = 0.5 * (vm + vp), 0.5 * (pm.c + pp.c)
        S = jnp.maximum(jnp.maximum(v + cij, v - cij), v)
    return central - 0.5 * (S * ndA)[..., None] * (Up - Um)


def ref_rhs(particles, params, geom: Geometry, scheme: Scheme):
    """The dense array formulation: returns (dx/dt, dV/dt, d(VU)/dt, per-pair G.A)."""
    eos = get_eos(scheme.eos)
    x, vol, kind = particles.x, particles.vol, particles.kind
    n, d = x.shape
    U = particles.q / vol[:, None]
    prim = to_primitive(U, eos, params)
    fluid = kind == Kind.FLUID
    w = (
        jnp.zeros_like(x)
        if scheme.frame == "eulerian"
        else jnp.where(fluid[:, None], prim.vel, 0.0)
    )
    jsafe = jnp.where(geom.mask, geom.idx, jnp.arange(n)[:, None])
    w_frame = w
    if scheme.frame != "eulerian" and scheme.position_update in ("mls", "shepard"):
        # decision 44: fluxes and dV/dt use the velocity the particles move with
        w = jnp.where(fluid[:, None], jnp.einsum("nk,nkd->nd", geom.interp, w[jsafe]), w)
    if scheme.reconstruction_variables == "primitive":
        F = jnp.concatenate(
            [prim.rho[:, None], prim.vel] + ([prim.p[:, None]] if eos.has_energy else []), -1
        )
    else:
        F = U
    Fm, Fp = jnp.broadcast_to(F[:, None], jsafe.shape + F.shape[1:]), F[jsafe]
    if scheme.reconstruction_degree > 0:
        a = jnp.einsum("nmk,nkv->nmv", geom.coeffs, F[jsafe])
        own = jnp.einsum(
            "nkm,nmv->nkv",
            basis.evaluate(0.5 * geom.dx / geom.h[:, None, None], scheme.reconstruction_degree),
            a,
        )
        if scheme.reconstruction == "taylor":
            own = Fm + own - a[:, None, 0, :]
        high = (jnp.minimum(particles.ppd[:, None], particles.ppd[jsafe]) > 0)[..., None]
        Fm, Fp = jnp.where(high, own, Fm), jnp.where(high, own[jsafe, geom.rev], Fp)
    if scheme.reconstruction_variables == "primitive":
        conv = lambda W: to_conservative(
            W[..., 0], W[..., 1 : 1 + d], W[..., 1 + d] if eos.has_energy else None, eos, params
        )
        Fm, Fp = conv(Fm), conv(Fp)
    w_ij = 0.5 * (w[:, None] + w[jsafe])
    r = safe_norm(geom.dx)
    n_pair = geom.dx / jnp.where(r > 0, r, 1.0)[..., None]
    GA = ref_flux(
        Fm, Fp, w_ij, geom.A, n_pair, eos, params, scheme.wave_speed, scheme.dissipation_normal
    )
    GA = jnp.where(geom.pair_mask[..., None], GA, 0.0)
    dq = -GA.sum(1)
    if scheme.self_flux:
        sA = geom.A.sum(1)
        va = jnp.sum((prim.vel - w) * sA, -1)
        parts = [U[:, :1] * va[:, None], U[:, 1 : 1 + d] * va[:, None] + prim.p[:, None] * sA]
        if eos.has_energy:
            parts.append((U[:, -1] * va + prim.p * jnp.sum(prim.vel * sA, -1))[:, None])
        dq = dq + jnp.concatenate(parts, -1)
    dq = dq + vol[:, None] * source(U, prim, params, eos)
    dvol = jnp.sum((w_ij - w[:, None]) * geom.A, axis=(1, 2))
    if scheme.frame == "eulerian":
        dxdt = jnp.zeros_like(x)
    elif scheme.position_update == "mls_literal":     # the thesis as printed
        dxdt = jnp.einsum("nk,nkd->nd", geom.interp, w_frame[jsafe])
    else:
        dxdt = w
    return (
        jnp.where(fluid[:, None], dxdt, 0.0),
        jnp.where(fluid, dvol, 0.0),
        jnp.where(fluid[:, None], dq, 0.0),
        GA,
    )


# ----------------------------------------------------------------------------------------------
# tests
# ----------------------------------------------------------------------------------------------

MLS2 = Scheme(method="mlsph_ale", degree=2, reconstruction_degree=2, beta=1.5)
SPH = Scheme(method="sph_ale", degree=2, reconstruction_degree=2, beta=2.0)


@pytest.mark.parametrize(   # degree 3 is slow (CI time); test_geometry_equals_reference[mlsph3] too
    "degree,derivative", [(1, "full"), (2, "full"), (2, "fixed_centre"),
                          pytest.param(3, "full", marks=pytest.mark.slow)]
)
def test_batched_mls_operators_equal_reference(degree, derivative):
    """Values, gradients (closed-form full derivative vs jax.jacfwd) and coefficients."""
    scheme = dataclasses.replace(
        MLS2, degree=degree, reconstruction_degree=degree, beta=2.0 if degree == 3 else 1.5
    )
    particles, _, nl = setup(scheme)
    h = apx.smoothing_length(particles.vol, scheme.beta, 2)
    L, per = jnp.asarray(DOMAIN.length), jnp.asarray(DOMAIN.periodic)
    spec = apx.ApproxSpec("mls", degree, "cubic_spline", derivative, with_coeffs=True)
    ops = apx.build(particles.x, h, particles.vol, nl.idx, nl.mask, spec, L, per)
    assert np.all(np.asarray(ops.degree) == degree)
    dx = apx.pair_offsets(particles.x, nl.idx, nl.mask, L, per)
    values, grads, C = jax.jit(ref_mls, static_argnums=(3, 4))(dx, nl.mask, h, degree, derivative)
    close(ops.values, values)
    close(ops.gradients, grads)
    close(ops.coeffs, C)
    # and the library's own per-particle path (autodiff of the masked-factor shape functions)
    f = jax.vmap(
        lambda a, m, hh: mls.particle_operators(
            a,
            m,
            hh,
            kernel=get_kernel("cubic_spline"),
            degree=degree,
            rcond=1e-6,
            derivative=derivative,
            with_coeffs=True,
        )
    )
    v2, g2, C2, deg2 = jax.jit(f)(dx, nl.mask, h)
    close(ops.gradients, g2)
    close(ops.coeffs, C2)


def _hlo_instructions(compiled) -> int:
    return len(re.findall(r"^\s*(ROOT\s+)?%?[\w.\-]+ = ", compiled.as_text(), re.M))


def test_per_row_factor_is_computed_once_and_gives_the_inlined_outputs(monkeypatch):
    """Decision 94: the unrolled factor of a row block (``cholesky_lists``: factor and pivot
    flags) runs inside a conditional, so XLA's fusion cannot copy it into every consumer over the
    stencil planes.  The outputs (with a per-row degree fallback) are those of the same code inlined
    (``per_row_once`` replaced by a plain call): bit for bit with XLA:CPU's default code generator,
    to round-off of the ill-conditioned cubic moments (7.6e-12 relative at LLVM O0, which the
    default test run compiles with, decision 98) here, and the compiled 2D cubic block
    with the full derivative is much smaller (experiments/bench_mls_block.py, B = 1077, K = 38:
    26,267 HLO instructions inlined, 12,480 with the conditional, XLA of jax 0.10)."""
    rng = np.random.default_rng(4)
    B, K = 300, 38
    dx = jnp.asarray(rng.uniform(-1.0, 1.0, (B, K, 2)) * 0.08)
    mask = jnp.asarray(rng.uniform(size=(B, K)) > 0.1).at[:, 0].set(True).at[:40, 7:].set(False)
    h = jnp.full(B, 0.05)

    def block(dx, mask, h):
        return mls.operators_block(dx, mask, h, kernel=get_kernel("cubic_spline"), degree=3, rcond=1e-2,
                                   derivative="full", with_coeffs=True)

    once = jax.jit(block).lower(dx, mask, h).compile()
    out = once(dx, mask, h)
    assert int(np.asarray(out[3]).min()) < 3 == int(np.asarray(out[3]).max())   # the fallback acts
    with monkeypatch.context() as mp:
        mp.setattr(mls, "per_row_once", lambda fn, *ops: fn(*ops))
        inlined = jax.jit(lambda *a: block(*a)).lower(dx, mask, h).compile()   # (a new trace)
        ref = inlined(dx, mask, h)
    for a, b in zip(out, ref, strict=True):
        a, b = np.asarray(a), np.asarray(b)
        if b.dtype.kind == "f":
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-10 * max(np.abs(b).max(), 1e-300))
        else:
            np.testing.assert_array_equal(a, b)          # degrees and pivot flags: exactly
    n_once, n_inlined = _hlo_instructions(once), _hlo_instructions(inlined)
    assert n_once < 0.7 * n_inlined, (n_once, n_inlined)


def test_batched_mls_degree_fallback_matches_per_particle_path():
    """A sparse stencil set (small beta): per-particle fallback to lower degrees is identical."""
    scheme = dataclasses.replace(MLS2, beta=0.7)
    particles, _, nl = setup(scheme, jitter=0.45, seed=3)
    h = apx.smoothing_length(particles.vol, scheme.beta, 2)
    L, per = jnp.asarray(DOMAIN.length), jnp.asarray(DOMAIN.periodic)
    spec = apx.ApproxSpec("mls", 2, "cubic_spline", "full", with_coeffs=True)
    ops = apx.build(particles.x, h, particles.vol, nl.idx, nl.mask, spec, L, per)
    deg = np.asarray(ops.degree)
    assert deg.min() < 2, "the layout should trigger the degree fallback"
    dx = apx.pair_offsets(particles.x, nl.idx, nl.mask, L, per)
    f = jax.vmap(
        lambda a, m, hh: mls.particle_operators(
            a,
            m,
            hh,
            kernel=get_kernel("cubic_spline"),
            degree=2,
            rcond=1e-6,
            derivative="full",
            with_coeffs=True,
        )
    )
    v2, g2, C2, deg2 = jax.jit(f)(dx, nl.mask, h)
    np.testing.assert_array_equal(deg, np.asarray(deg2))
    # row by row: stencils whose pivots are barely accepted (pivot ratio ~ rcond) amplify the
    # round-off of the moments (summed in a different order) by their condition number
    for a, b in ((ops.values, v2), (ops.coeffs, C2), (ops.gradients, g2)):
        a, b = np.asarray(a), np.asarray(b)
        ax = tuple(range(1, a.ndim))
        row_err = np.abs(a - b).max(axis=ax) / np.abs(b).max(axis=ax)
        assert row_err.max() < 1e-8 and np.median(row_err) < 1e-13, (
            row_err.max(),
            np.median(row_err),
        )


@pytest.mark.parametrize(
    "scheme",
    [
        MLS2,
        # cubic is slow (CI time); the cylinder fingerprints run the cubic geometry
        pytest.param(dataclasses.replace(MLS2, degree=3, reconstruction_degree=3, beta=2.0),
                     marks=pytest.mark.slow, id="mlsph3"),
        dataclasses.replace(MLS2, reconstruction_degree=1),
        SPH,
    ],
    ids=["mlsph2", "mlsph3", "mlsph2-recon1", "sph"],
)
def test_geometry_equals_reference(scheme):
    scheme = dataclasses.replace(scheme, position_update="mls")   # the interpolation weights too
    particles, _, nl = setup(scheme)
    g = jax.jit(lambda p, nl: geometry(p.x, p.vol, nl, scheme, DOMAIN))(particles, nl)
    r = jax.jit(lambda p, nl: ref_geometry(p.x, p.vol, nl, scheme))(particles, nl)
    close(g.dx, r["dx"], rtol=0.0)
    np.testing.assert_array_equal(g.pair_mask, r["pair_mask"])
    close(g.A, r["A"])
    close(g.coeffs, r["coeffs"])
    if r["interp"] is not None:
        close(g.interp, r["interp"])
    # A_ij = -A_ji (to round-off: XLA may contract V_i G - V_j G' into a fused multiply-add)
    A = np.asarray(g.A)
    jsafe = np.asarray(r["jsafe"])
    close(
        A,
        -A[jsafe, np.asarray(nl.rev)] * np.asarray(g.pair_mask)[..., None],
        rtol=1e-14,
        scale=np.abs(A).max(),
    )


RHS_VARIANTS = [
    (MLS2, {}),
    (MLS2, dict(reconstruction="mls_direct")),
    (MLS2, dict(reconstruction_variables="primitive", frame="lagrangian")),
    (MLS2, dict(dissipation_normal="pair", wave_speed="printed_ch3")),
    (MLS2, dict(wave_speed="printed_ch4", self_flux=False)),
    (MLS2, dict(reconstruction_degree=0, frame="lagrangian", position_update="w_i")),
    (MLS2, dict(eos="tait", frame="lagrangian")),
    (MLS2, dict(eos="tait", frame="lagrangian", position_update="mls")),
    (SPH, dict(frame="lagrangian")),
    (SPH, dict(frame="lagrangian", position_update="mls")),
    (MLS2, dict(frame="lagrangian", position_update="mls_literal")),
    (SPH, dict(reconstruction_variables="primitive")),
]


@pytest.mark.parametrize(
    "base,change", RHS_VARIANTS, ids=lambda v: str(v) if isinstance(v, dict) else v.method
)
def test_rhs_equals_reference(base, change):
    scheme = dataclasses.replace(base, **change)
    particles, params, nl = setup(scheme, eos=scheme.eos)
    geom = jax.jit(lambda p, nl: geometry(p.x, p.vol, nl, scheme, DOMAIN))(particles, nl)
    new = jax.jit(lambda p, prm, g: rhs(p, prm, g, scheme))(particles, params, geom)
    ref = jax.jit(lambda p, prm, g: ref_rhs(p, prm, g, scheme))(particles, params, geom)
    flux_scale = float(jnp.abs(ref[3]).max())
    close(new[2], ref[2], scale=flux_scale)  # d(VU)/dt
    close(
        new[1],
        ref[1],
        scale=float(
            jnp.abs(geom.A).max() * jnp.abs(particles.U[:, 1:3] / particles.U[:, :1]).max()
        ),
    )
    close(
        new[0],
        ref[0],
        rtol=1e-14 if scheme.frame == "eulerian" else RTOL,
        scale=float(jnp.abs(particles.U[:, 1:3] / particles.U[:, :1]).max()),
    )
    if scheme.reconstruction_degree > 0:  # the public reconstruct(): j side = reverse i side
        Fm, Fp = reconstruct(
            particles.U,
            geom,
            scheme.reconstruction_degree,
            scheme.reconstruction == "taylor",
            particles.ppd,
        )
        Fm, Fp, mask = np.asarray(Fm), np.asarray(Fp), np.asarray(geom.mask)
        rev_side = Fm[np.asarray(geom.jsafe), np.asarray(geom.rev)]
        np.testing.assert_array_equal(Fp[mask], rev_side[mask])


@pytest.mark.parametrize("change", [{}, dict(eos="tait", frame="lagrangian")], ids=str)
def test_rhs_without_demoted_particles_equals_reference(change):
    """Every particle high order (no MOOD demotion): the right-hand side takes the pair sweep
    without the first-order fallback (decision 89's ``lax.cond``), which must give the reference's
    values like the general sweep does (the test above demotes every 11th particle)."""
    scheme = dataclasses.replace(MLS2, **change)
    particles, params, nl = setup(scheme, eos=scheme.eos)
    particles = dataclasses.replace(particles, ppd=jnp.full_like(particles.ppd, 3))
    geom = jax.jit(lambda p, nl: geometry(p.x, p.vol, nl, scheme, DOMAIN))(particles, nl)
    new = jax.jit(lambda p, prm, g: rhs(p, prm, g, scheme))(particles, params, geom)
    ref = jax.jit(lambda p, prm, g: ref_rhs(p, prm, g, scheme))(particles, params, geom)
    close(new[2], ref[2], scale=float(jnp.abs(ref[3]).max()))


def test_rhs_parameter_gradient_equals_reference():
    """Reverse mode through the blocked passes: d/d gamma of a scalar of the right-hand side."""
    scheme = MLS2
    particles, params, nl = setup(scheme, n1=12)
    geom = jax.jit(lambda p, nl: geometry(p.x, p.vol, nl, scheme, DOMAIN))(particles, nl)

    def loss(f):
        return lambda prm: jnp.sum(f(particles, prm, geom, scheme)[2] ** 2)

    g_new = jax.jit(jax.grad(loss(rhs)))(params)["eos.gamma"]
    g_ref = jax.jit(jax.grad(loss(lambda *a: ref_rhs(*a)[:3])))(params)["eos.gamma"]
    np.testing.assert_allclose(float(g_new), float(g_ref), rtol=1e-9)


DIFFUSIVE_VARIANTS = [
    dict(viscous=True, heat_conduction=True),
    dict(heat_conduction=True, stress="incompressible", frame="lagrangian", reconstruction="mls_direct",
         self_flux=False),
    dict(viscous=True, eos="tait", frame="lagrangian", reconstruction_variables="primitive"),
]


@pytest.mark.parametrize("change", DIFFUSIVE_VARIANTS, ids=str)
def test_diffusive_terms_in_the_pair_sweep_equal_the_separate_pass(change):
    """The reconstruction's fit serves the viscous and heat fluxes inside the one pair sweep; the
    result equals the inviscid right-hand side plus the separate array pass
    :func:`mlsph_jax.viscous.viscous_terms` (thesis eq. 4.40) to round-off."""
    from mlsph_jax.viscous import viscous_terms

    scheme = dataclasses.replace(MLS2, **change)
    particles, params, nl = setup(scheme, eos=scheme.eos)
    params = params.updated({"physics.mu": 0.05, "physics.kappa": 0.07})
    geom = jax.jit(lambda p, nl: geometry(p.x, p.vol, nl, scheme, DOMAIN))(particles, nl)
    inviscid = dataclasses.replace(scheme, viscous=False, heat_conduction=False)

    def ref(p, prm, g):
        out = rhs(p, prm, g, inviscid)
        eos = get_eos(scheme.eos)
        visc = viscous_terms(to_primitive(p.q / p.vol[:, None], eos, prm), g, scheme, prm, scheme.fit_degree)
        return out[0], out[1], out[2] + jnp.where((p.kind == Kind.FLUID)[:, None], visc, 0.0), visc

    new = jax.jit(lambda p, prm, g: rhs(p, prm, g, scheme))(particles, params, geom)
    old = jax.jit(ref)(particles, params, geom)
    assert float(jnp.abs(old[3]).max()) > 1e-3          # the diffusive terms are not negligible
    close(new[2], old[2], scale=float(jnp.abs(old[2]).max() + jnp.abs(old[3]).max()))
    # the frame velocity and the volume rate do not involve the diffusive terms: the same arithmetic,
    # but in two programs whose fusions the code generator may round differently (a 1.3e-13
    # relative difference of the volume rate on an AVX/FMA CPU without AVX2), so to round-off
    close(new[0], old[0])
    close(new[1], old[1])


def test_a_reconstruction_without_fits_extra_takes_the_separate_diffusive_pass():
    """A user reconstruction that does not declare ``fits_extra`` (docs/extending.md) is called
    without ``extra``; its right-hand side equals the fused one of the built-in reconstruction it
    wraps, to round-off (the separate pass of :func:`mlsph_jax.viscous.viscous_terms`)."""
    from mlsph_jax.reconstruction import RECONSTRUCTIONS

    taylor = RECONSTRUCTIONS.get("taylor")
    calls = []

    class Plain:
        def midpoint_states(self, F, geom, degree):
            calls.append(degree)
            return taylor.midpoint_states(F, geom, degree)

    RECONSTRUCTIONS.register("test_plain", Plain())
    try:
        scheme = dataclasses.replace(MLS2, viscous=True, heat_conduction=True)
        particles, params, nl = setup(scheme, eos=scheme.eos)
        params = params.updated({"physics.mu": 0.05, "physics.kappa": 0.07})
        geom = jax.jit(lambda p, nl: geometry(p.x, p.vol, nl, scheme, DOMAIN))(particles, nl)
        plain = dataclasses.replace(scheme, reconstruction="test_plain")
        new = jax.jit(lambda p, prm, g: rhs(p, prm, g, plain))(particles, params, geom)
        fused = jax.jit(lambda p, prm, g: rhs(p, prm, g, scheme))(particles, params, geom)
    finally:
        RECONSTRUCTIONS.unregister("test_plain")
    assert calls, "the plain reconstruction was not used"
    close(new[2], fused[2], scale=float(jnp.abs(fused[2]).max()))
