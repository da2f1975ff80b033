"""ALE fluxes and the Rusanov numerical flux contracted with a pair area vector.

ALE flux in the direction of a vector a (thesis eq. 2.17, 2.19, 4.3-4.5; SPEC §1.3):

    F_w(U, w) . a = ( rho v_a,  rho u v_a + p a,  rho E v_a + p u.a ),   v_a = (u - w) . a

Rusanov (local Lax-Friedrichs) flux at the interface point x_ij (thesis §3.6.2 and eq.
4.37-4.38, read as SPEC §5.4 recommends):

    G_ij . A_ij = 1/2 [F_w(U^-, w_ij) + F_w(U^+, w_ij)] . A_ij - 1/2 S_ij (U^+ - U^-) (n . A_ij)

with the non-negative wave speed S_ij = max(|v^-_n| + c^-, |v^+_n| + c^+) (``rusanov_abs``,
default).  The thesis' printed signed maxima are kept as ``printed_ch3`` (T:L1233) and
``printed_ch4`` (T(4.38)) for reproduction studies; they can be negative (anti-diffusive).
The normal is n = A/|A| (``area``, default: dissipation 1/2 S dU |A|) or the unit pair vector
n_ij (``pair``), identical for kernel SPH-ALE where A_ij is parallel to n_ij.

HLLC (Toro, *Riemann Solvers and Numerical Methods for Fluid Dynamics*, 3rd ed., ch. 10) and
its low-dissipation variants ``hllc_lm`` and ``hllc_zha``: see :func:`hllc_components`.
Every flux is written elementwise on lists of component arrays, so that XLA fuses it into the
blocked pair sweep of :mod:`mlsph_jax.rhs`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .eos import EOS, Primitive
from .registry import Registry
from .stencil import columns

FLUXES: Registry = Registry("scheme.flux", protocol=("pair_flux",), doc="numerical (Riemann) fluxes")
WAVE_SPEEDS: Registry = Registry("scheme.wave_speed", protocol=("speed",), doc="wave-speed estimates")
DISSIPATION_NORMALS: Registry = Registry("scheme.dissipation_normal", protocol=("project", "needs_pair_vector"),
                                         doc="normal of the dissipation term")


def ale_flux_dot(U, pr: Primitive, w, a, eos: EOS):
    """F_w(U, w) . a for states ``U[..., nv]`` with primitives ``pr``, frame velocity ``w[..., d]``
    and direction vectors ``a[..., d]`` (thesis eq. 2.19)."""
    va = jnp.sum((pr.vel - w) * a, axis=-1)
    parts = [U[..., :1] * va[..., None],
             U[..., 1:1 + a.shape[-1]] * va[..., None] + pr.p[..., None] * a]
    if eos.has_energy:
        parts.append((U[..., -1] * va + pr.p * jnp.sum(pr.vel * a, axis=-1))[..., None])
    return jnp.concatenate(parts, axis=-1)


def _dot(u, v):
    s = u[0] * v[0]
    for a in range(1, len(u)):
        s = s + u[a] * v[a]
    return s


def primitive_components(U, eos: EOS, params):
    """``(vel, p, c)`` of states given as a list of component arrays ``[rho, rho u.., (rho E)]``.

    Same formulas as :func:`mlsph_jax.eos.to_primitive` with one reciprocal of rho per state
    (the velocity and energy are products with it), so that XLA fuses the whole pair flux into
    one loop.
    """
    d = len(U) - (2 if eos.has_energy else 1)
    rho = U[0]
    inv = 1.0 / rho
    vel = [U[1 + a] * inv for a in range(d)]
    e = U[1 + d] * inv - 0.5 * _dot(vel, vel) if eos.has_energy else jnp.zeros_like(rho)
    p = eos.pressure(rho, e, params)
    return vel, p, eos.sound_speed(rho, p, params)


class RusanovAbs:
    """S = max(|v^-_n| + c^-, |v^+_n| + c^+), non-negative (the standard Rusanov estimate; default)."""

    @staticmethod
    def speed(vm, vp, cm, cp):
        return jnp.maximum(jnp.abs(vm) + cm, jnp.abs(vp) + cp)


class PrintedCh3:
    """S = max(v^+_n + c^+, v^-_n - c^-) as printed in thesis ch. 3 (T:L1233); may be negative."""

    @staticmethod
    def speed(vm, vp, cm, cp):
        return jnp.maximum(vp + cp, vm - cm)


class PrintedCh4:
    """S = max(v + c_ij, v - c_ij, v) with interface averages v, c_ij as printed in thesis eq. 4.38."""

    @staticmethod
    def speed(vm, vp, cm, cp):
        v = 0.5 * (vm + vp)
        cij = 0.5 * (cm + cp)
        return jnp.maximum(jnp.maximum(v + cij, v - cij), v)


WAVE_SPEEDS.register("rusanov_abs", RusanovAbs())
WAVE_SPEEDS.register("printed_ch3", PrintedCh3())
WAVE_SPEEDS.register("printed_ch4", PrintedCh4())


class AreaNormal:
    """n = A_ij / |A_ij|: the dissipation is 1/2 S (U^+ - U^-) |A_ij|."""

    needs_pair_vector = False

    @staticmethod
    def project(relm, relp, A, n_pair):
        """Normal relative velocities (v^-_n, v^+_n) and n . A_ij."""
        r2 = _dot(A, A)
        pos = r2 > 0
        amag = jnp.where(pos, jnp.sqrt(jnp.where(pos, r2, 1.0)), 0.0)     # safe_norm(A)
        den = jnp.where(amag > 0, amag, 1.0)
        return _dot(relm, A) / den, _dot(relp, A) / den, amag


class PairNormal:
    """n = n_ij, the unit vector from i to j (identical to ``area`` for kernel SPH-ALE).  The
    dissipation uses |n_ij . A_ij|: MLS area vectors need not point along n_ij, and a negative
    projection would make the dissipation term anti-diffusive."""

    needs_pair_vector = True

    @staticmethod
    def project(relm, relp, A, n_pair):
        return _dot(relm, n_pair), _dot(relp, n_pair), jnp.abs(_dot(n_pair, A))


DISSIPATION_NORMALS.register("area", AreaNormal())
DISSIPATION_NORMALS.register("pair", PairNormal())


def safe_sqrt(a):
    """sqrt(a) for a >= 0 with a finite gradient at a = 0 (where it is 0)."""
    pos = a > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, a, 1.0)), 0.0)


def local_mach(relm, relp, cm, cp):
    """M_loc = max(|u^- - w| / c^-, |u^+ - w| / c^+): the Mach number of the whole relative
    velocity (not only its normal part), so that every low-Mach option is the plain scheme
    wherever the flow is supersonic in some direction."""
    cm2, cp2 = cm * cm, cp * cp           # one division (see the performance note in hllc_components)
    return safe_sqrt(jnp.maximum(_dot(relm, relm) * cp2, _dot(relp, relp) * cm2) / (cm2 * cp2))


class RusanovFlux:
    """Rusanov (local Lax-Friedrichs) flux in the ALE frame (module docstring):
    G_ij . A_ij = 1/2 [F_w(U^-) + F_w(U^+)] . A_ij - 1/2 S_ij (U^+ - U^-) (n . A_ij), with S_ij from
    ``scheme.wave_speed`` and n from ``scheme.dissipation_normal``.

    Flux protocol: ``pair_flux(Um, Up, w, A, n_pair, eos, params, scheme) -> list of nv arrays``
    on lists of component arrays (structure of arrays): ``Um``/``Up`` the i-/j-side states
    ``[rho, rho u.., (rho E)]``, ``w`` the frame velocity at the interface (list of d arrays) or
    ``None`` for w = 0, ``A`` the area vector, ``n_pair`` the unit pair vector (only when the
    dissipation normal asks for it).  Pairs with A = 0 must give exactly zero.

    Optional attributes of a flux: ``scheme_fields`` (the scheme fields among ``wave_speed`` and
    ``dissipation_normal`` it reads; a flux without the attribute is taken to read both; a
    non-default value that no flux in use reads is an error), ``uses_reference_mach`` (whether
    it reads ``scheme.reference_mach``) and ``check_scheme(scheme)``.
    """

    scheme_fields = ("wave_speed", "dissipation_normal")
    uses_reference_mach = False

    def pair_flux(self, Um, Up, w, A, n_pair, eos: EOS, params, scheme):
        return rusanov_components(Um, Up, w, A, n_pair, eos, params, wave_speed=scheme.wave_speed,
                                  normal=scheme.dissipation_normal)


FLUXES.register("rusanov", RusanovFlux())


def rusanov_components(Um, Up, w, A, n_pair, eos: EOS, params, *, wave_speed: str = "rusanov_abs",
                       normal: str = "area"):
    """G_ij . A_ij on lists of component arrays (structure of arrays), see :func:`rusanov_dot_area`.

    ``Um``/``Up``: lists of nv arrays; ``w``: list of d arrays or ``None`` (w = 0); ``A`` and
    ``n_pair``: lists of d arrays (``n_pair`` only read when the dissipation normal needs it).
    Returns a list of nv arrays.
    """
    d = len(A)
    velm, pm, cm = primitive_components(Um, eos, params)
    velp, pp, cp = primitive_components(Up, eos, params)
    relm = velm if w is None else [velm[k] - w[k] for k in range(d)]
    relp = velp if w is None else [velp[k] - w[k] for k in range(d)]
    vam, vap = _dot(relm, A), _dot(relp, A)          # (u -+ w) . A
    vm, vp, n_dot_A = DISSIPATION_NORMALS.get(normal, "scheme.dissipation_normal").project(relm, relp, A, n_pair)
    S = WAVE_SPEEDS.get(wave_speed, "scheme.wave_speed").speed(vm, vp, cm, cp)
    diss = 0.5 * (S * n_dot_A)
    out = [0.5 * (Um[0] * vam + Up[0] * vap) - diss * (Up[0] - Um[0])]
    for k in range(d):
        out.append(0.5 * ((Um[1 + k] * vam + pm * A[k]) + (Up[1 + k] * vap + pp * A[k]))
                   - diss * (Up[1 + k] - Um[1 + k]))
    if eos.has_energy:
        out.append(0.5 * ((Um[-1] * vam + pm * _dot(velm, A)) + (Up[-1] * vap + pp * _dot(velp, A)))
                   - diss * (Up[-1] - Um[-1]))
    return out


def rusanov_dot_area(Um, Up, w_ij, A, n_pair, eos: EOS, params, *, wave_speed: str = "rusanov_abs",
                     normal: str = "area"):
    """G_ij . A_ij for reconstructed states ``Um`` (i side) and ``Up`` (j side), ``[..., nv]``.

    ``n_pair`` is the unit vector from i to j (used when ``normal == "pair"`` and by nothing
    else).  Pairs with A = 0 give exactly zero.  (Array front end of
    :func:`rusanov_components`.)
    """
    comps = columns
    out = rusanov_components(comps(Um), comps(Up), None if w_ij is None else comps(w_ij), comps(A),
                             None if n_pair is None else comps(n_pair), eos, params,
                             wave_speed=wave_speed, normal=normal)
    return jnp.stack(out, axis=-1)


# ---------------------------------------------------------------------------------------------
# HLLC and its low-dissipation variants
# ---------------------------------------------------------------------------------------------

#: eta of the Zhang, Hu & Adams (2017) limiter beta = min(eta max(v^- - v^+, 0), c_bar).
ZHA_ETA = 3.0

HLLC_VARIANTS = ("hllc", "lm", "zha")


def _star_increment(U, p, a, b, Ss, amag, A, wA, energy):
    """a |A| U + b (0, A, S* |A| + w.A) + a |A| (0, .., 0, p): the term S_K |A| (U*_K - U_K) of
    the HLLC flux written with a = S_K g / (S_K - S*), b = S_K Pi / (S_K - S*) (see
    :func:`hllc_components`)."""
    d = len(A)
    aa = a * amag
    out = [aa * U[0]] + [aa * U[1 + k] + b * A[k] for k in range(d)]
    if energy:
        sa = Ss * amag if wA is None else Ss * amag + wA
        out.append(aa * (U[-1] + p) + b * sa)
    return out


def hllc_components(Um, Up, w, A, eos: EOS, params, *, variant: str = "hllc", reference_mach: float = 0.0):
    """HLLC flux G_ij . A_ij (Toro 2009, ch. 10) in the ALE frame, on lists of component arrays.

    Arguments as :func:`rusanov_components` (``Um`` the i side = L, ``Up`` the j side = R).
    Normal n = A/|A| (pairs with A = 0 give exactly 0, with finite gradients: the safe norm of
    :class:`AreaNormal`), relative normal velocities v_K = (u_K - w) . n, and G . A = |A| G_n
    with the ALE flux of :func:`ale_flux_dot`, F_w(U) . A = (rho v_A, rho u v_A + p A,
    rho E v_A + p u . A), v_A = (u - w) . A.

    * Wave speeds (Davis 1988; Toro eq. 10.48): S_L = min(v_L - c_L, v_R - c_R),
      S_R = max(v_L + c_L, v_R + c_R).  They need only the two sound speeds (no Roe average,
      which would need the EOS' enthalpy: Einfeldt's estimate is not EOS-independent).
    * Contact speed (Toro eq. 10.37), with z_K = rho_K (S_K - v_K) (z_L < 0 < z_R):
      S* = (p_R - p_L + z_L v_L - z_R v_R) / (z_L - z_R).
    * Star states (Toro eq. 10.39), f_K = (S_K - v_K)/(S_K - S*):
      U*_K = f_K [rho_K, rho_K (u_K + (S* - v_K) n), rho E_K + rho_K (S* - v_K)(S*_abs + p_K / z_K)]
      with S*_abs = S* + w.n (the energy carries the absolute velocity, as in F_w).  In the
      frame of the interface (normal speed w.n) the ALE flux obeys the same jump relations as the
      fixed-frame flux with the wave speeds taken relative to w.n, so HLLC in the ALE frame is
      HLLC with relative speeds and F_w.
    * Flux: G = F_w(U_K) + S_K^clip (U*_K - U_K), K = L if S* >= 0 else R, S_L^clip =
      min(S_L, 0), S_R^clip = max(S_R, 0) (this is Toro's four-case formula: supersonic pairs
      give F_w(U_L) or F_w(U_R)).  Written with g_K = S* - v_K and f_K - 1 = g_K/(S_K - S*):
      S_K^clip |A| (U*_K - U_K) = a |A| U_K + b (0, A, S*|A| + w.A) + a |A| (0, p_K) with
      a = S_K^clip g_K/(S_K - S*), b = S_K^clip Pi_K/(S_K - S*) and Pi_K = z_K g_K = p* - p_K.
      A stationary contact (v_L = v_R = 0, p_L = p_R) gives S* = 0, g = 0 and the exact flux
      (0, p A, 0); a uniform state gives F_w(U) . A to round-off.  Evaluated with K chosen from
      the sign of the numerator of S* (Dn = z_L - z_R < 0) and S*, a, b from one reciprocal
      1/(Dn (S_K Dn - num)).

    Any EOS: the star states follow from the Rankine-Hugoniot conditions across the three waves
    and p*_L = p*_R alone (Toro §10.4.2); the EOS enters through p and c of the two states only.
    Barotropic EOS (Tait): the energy row is dropped; the star densities are still
    rho*_K = rho_K (S_K - v_K)/(S_K - S*) (two of them, not rho(p*)), and the contact carries the
    tangential velocity (a shear layer is advected, not diffused).

    ``variant``:

    * ``"hllc"``: the above.
    * ``"lm"``: HLLC-LM of Fleischmann, Adami & Adams (2020, JCP 423, 109762), the centred form
      G = 1/2 (F_L + F_R) + 1/2 [phi S_L (U*_L - U_L) + |S*| (U*_L - U*_R) + phi S_R (U*_R - U_R)]
      with phi = sin(min(1, M_loc / M_ref) pi/2), M_ref = ``reference_mach`` (their Ma_limit,
      0.1 in the paper) and M_loc from :func:`local_mach`.  Using the jump relations it is
      G = F_K + (1 + phi)/2 S_K (U*_K - U_K) + (phi - 1)/2 S_O (U*_O - U_O) (O the other side),
      which is what is evaluated (with clipped speeds: phi = 1 wherever a pair is supersonic,
      since M_loc >= |v_K|/c_K > 1 >= M_ref there).  phi = 1 (plain HLLC) for M_loc >= M_ref.
      [The form and phi agree with the JAX-Fluids HLLC-LM of the same group (Fleischmann et al.
      eq. 18-19, 23-25, Ma_limit = 0.1), which takes Ma_local with the face-normal velocity; here
      the whole relative velocity, so that the flux is HLLC wherever M >= 1.]
    * ``"zha"``: HLLC in Toro's star-pressure form (Pi_K = P* - p_K) with the dissipative part of
      P* limited after Zhang, Hu & Adams (2017, JCP 335, "A weakly compressible SPH method based
      on a low-dissipation Riemann solver"): P* = (p_L + p_R)/2 + chi D,
      D = 1/2 [z_L (S* - v_L) + z_R (S* - v_R)] (so that chi = 1 is HLLC: P* = p*), and
      chi = min(1, max(M_loc, eta max(v_L - v_R, 0) / c_bar)), eta = 3, c_bar = (c_L + c_R)/2;
      since p* = p_K + z_K g_K on either side, Pi_K = chi z_K g_K - (1 - chi)(p_K - p_O)/2 (what
      is evaluated; O the other side).
      In the acoustic limit D = 1/2 rho c (v_L - v_R), and chi D = 1/2 rho beta (v_L - v_R)
      with Zhang et al.'s beta = min(eta max(v_L - v_R, 0), c_bar): no pressure dissipation in
      expansion, full dissipation in strong compression.  The floor M_loc is not in the paper
      (theirs is a weakly compressible scheme); it makes the flux HLLC for M >= 1 and keeps the
      low-Mach (Rieper-type, O(M)) pressure dissipation in expansion.  [The limiter agrees with
      the authors' SPHinXsys AcousticRiemannSolver (pressure dissipation rho c u_jump
      min(3 max(u_jump/c, 0), 1), velocity dissipation unlimited); its transcription to HLLC and
      the Mach floor are this code's, not their scheme.]
    """
    if variant not in HLLC_VARIANTS:
        raise ValueError(f"invalid variant={variant!r}; allowed: {', '.join(HLLC_VARIANTS)}")
    # Performance (XLA:CPU): an expensive op (divide, sqrt) with several users is not duplicated
    # into the fused pair loop but written to memory, and so are the states it reads.  Hence
    # 1/|A| by one rsqrt, the side K chosen from the sign of the numerator of S* (not from S*),
    # and S*, t_K (and t_O) from one reciprocal: 14 instead of 28 materialised [rows, K] planes,
    # HLLC / Rusanov 1.14 instead of 1.32 (experiments/bench_rhs.py, N = 4e4, 2D degree 2); after the
    # later changes of the Rusanov sweep (decisions 89-94) 1.23 / 1.27 at N = 1e4 / 4e4 (2026-12-06,
    # docs/validation.md "Cost of the fluxes").
    d = len(A)
    energy = eos.has_energy
    velm, pm, cm = primitive_components(Um, eos, params)
    velp, pp, cp = primitive_components(Up, eos, params)
    relm = velm if w is None else [velm[k] - w[k] for k in range(d)]
    relp = velp if w is None else [velp[k] - w[k] for k in range(d)]
    r2 = _dot(A, A)
    pos = r2 > 0
    inv = jnp.where(pos, jax.lax.rsqrt(jnp.where(pos, r2, 1.0)), 1.0)     # 1/|A| (1 where A = 0)
    amag = jnp.where(pos, r2 * inv, 0.0)                                  # |A|, safe at A = 0
    vam, vap = _dot(relm, A), _dot(relp, A)
    vm, vp = vam * inv, vap * inv
    SL = jnp.minimum(vm - cm, vp - cp)
    SR = jnp.maximum(vm + cm, vp + cp)
    zm = Um[0] * (SL - vm)                     # < 0
    zp = Up[0] * (SR - vp)                     # > 0
    num = pp - pm + zm * vm - zp * vp          # S* = num / Dn
    Dn = zm - zp                               # < 0 for admissible states
    left = num <= 0.0                          # S* >= 0

    def side(a, b):
        return jnp.where(left, a, b)

    def other(a, b):
        return jnp.where(left, b, a)

    U = [side(a, b) for a, b in zip(Um, Up, strict=True)]
    p, va, v, z = side(pm, pp), side(vam, vap), side(vm, vp), side(zm, zp)
    SK = side(SL, SR)
    Sc = jnp.where(left, jnp.minimum(SL, 0.0), jnp.maximum(SR, 0.0))
    YK = SK * Dn - num                         # Dn (S_K - S*)
    if variant == "lm":
        YO = other(SL, SR) * Dn - num
        R = 1.0 / (Dn * YK * YO)
        Ss = num * YK * YO * R
        t = Sc * Dn * Dn * YO * R              # S_K^clip / (S_K - S*)
    else:
        R = 1.0 / (Dn * YK)
        Ss = num * YK * R
        t = Sc * Dn * Dn * R
    g = Ss - v
    if variant == "zha":
        M = local_mach(relm, relp, cm, cp)
        chi = jnp.minimum(1.0, jnp.maximum(M, (2.0 * ZHA_ETA) * jnp.maximum(vm - vp, 0.0) / (cm + cp)))
        Pi = chi * (z * g) - (0.5 * (1.0 - chi)) * (p - other(pm, pp))   # = p_bar + chi D - p_K
    else:
        Pi = z * g
    a, b = t * g, t * Pi
    if variant == "lm":
        x = local_mach(relm, relp, cm, cp) / reference_mach
        phi = jnp.where(x >= 1.0, 1.0, jnp.sin(jnp.minimum(x, 1.0) * (0.5 * jnp.pi)))
        cK, cO = 0.5 * (1.0 + phi), 0.5 * (phi - 1.0)
        a, b = cK * a, cK * b
    wA = None if w is None else _dot(w, A)
    out = [U[0] * va] + [U[1 + k] * va + p * A[k] for k in range(d)]
    if energy:
        out.append(U[-1] * va + p * (va if wA is None else va + wA))
    inc = _star_increment(U, p, a, b, Ss, amag, A, wA, energy)
    out = [o + i for o, i in zip(out, inc, strict=True)]
    if variant == "lm":
        UO = [other(a_, b_) for a_, b_ in zip(Um, Up, strict=True)]
        pO, gO = other(pm, pp), Ss - other(vm, vp)
        tO = cO * jnp.where(left, jnp.maximum(SR, 0.0), jnp.minimum(SL, 0.0)) * Dn * Dn * YK * R
        incO = _star_increment(UO, pO, tO * gO, tO * other(zm, zp) * gO, Ss, amag, A, wA, energy)
        out = [o + i for o, i in zip(out, incO, strict=True)]
    return out


class HLLCFlux:
    """HLLC (Toro 2009, ch. 10) in the ALE frame with Davis wave speeds; contacts and shear
    layers are resolved (:func:`hllc_components`, ``variant="hllc"``).  Any EOS (it needs only
    p and c); the barotropic form drops the energy row."""

    scheme_fields = ()               # reads neither scheme.wave_speed nor scheme.dissipation_normal
    uses_reference_mach = False
    variant = "hllc"

    def pair_flux(self, Um, Up, w, A, n_pair, eos: EOS, params, scheme):
        return hllc_components(Um, Up, w, A, eos, params, variant=self.variant)


class HLLCLowMachFlux(HLLCFlux):
    """HLLC-LM (Fleischmann, Adami & Adams 2020, JCP 423): the acoustic wave terms of HLLC scaled
    by phi = sin(min(1, M_loc/M_ref) pi/2), M_ref = ``scheme.reference_mach`` (required); plain
    HLLC for M_loc >= M_ref (:func:`hllc_components`, ``variant="lm"``)."""

    uses_reference_mach = True
    variant = "lm"

    def pair_flux(self, Um, Up, w, A, n_pair, eos: EOS, params, scheme):
        return hllc_components(Um, Up, w, A, eos, params, variant="lm", reference_mach=scheme.reference_mach)

    def check_scheme(self, scheme):
        from .errors import InputError

        if not 0.0 < scheme.reference_mach <= 1.0:
            field = "scheme.flux" if FLUXES.get(scheme.flux) is self else "scheme.parachute_flux"
            name = scheme.flux if field == "scheme.flux" else scheme.parachute_flux
            raise InputError(
                f"invalid scheme.reference_mach={scheme.reference_mach!r} with {field}={name!r}: this flux needs the "
                "cutoff Mach number M_ref of phi = sin(min(1, M/M_ref) pi/2); allowed: a float in (0, 1] "
                "(0.1 in Fleischmann et al. 2020), or a flux without a reference Mach number "
                f"({', '.join(n for n, f in FLUXES.items() if not getattr(f, 'uses_reference_mach', False))})")


class HLLCZhangHuAdamsFlux(HLLCFlux):
    """HLLC with the star-pressure dissipation limited after Zhang, Hu & Adams (2017, JCP 335):
    chi = min(1, max(M_loc, 3 max(v_L - v_R, 0)/c_bar)); plain HLLC for M_loc >= 1
    (:func:`hllc_components`, ``variant="zha"``)."""

    variant = "zha"


FLUXES.register("hllc", HLLCFlux())
FLUXES.register("hllc_lm", HLLCLowMachFlux())
FLUXES.register("hllc_zha", HLLCZhangHuAdamsFlux())
