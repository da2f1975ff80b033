"""Static, hashable description of a numerical scheme (the "method switchboard", SPEC §10.5).

A :class:`Scheme` is a jit static argument: changing it recompiles, changing
:class:`~mlsph_jax.state.Params` does not.  Built from the ``[scheme]`` config table with
:meth:`Scheme.from_config`; every field is validated against its registry.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

from .approximation import APPROXIMATIONS, ApproxSpec
from .config import METHOD_BETA
from .eos import get_eos
from .errors import InputError
from .flux import FLUXES, WAVE_SPEEDS
from .kernels import get_kernel
from .registry import Registry

NAD_VARIABLES = ("rho", "p", "vel", "e", "conservative")

METHODS = Registry("scheme.method")
METHODS.register("mlsph_ale")("MLSPH-ALE: MLS area vectors (thesis eq. 4.36) and direct MLS reconstruction (eq. 4.39)")
METHODS.register("sph_ale")(
    "SPH-ALE: kernel area vectors 2 V_i V_j grad W_ij (eq. 3.5) and Taylor reconstruction (eq. 3.11)")
FRAMES = Registry("scheme.frame")
FRAMES.register("eulerian")("w = 0")
FRAMES.register("lagrangian")("w = u")
FRAMES.register("ale_shift")("w = u + dw (particle shifting, SPEC §9)")
SHIFT_LAWS = Registry("scheme.shift_law")
SHIFT_LAWS.register("xu")("repulsion C U_max sum_j (r_i/r_ij)^2 e_ji / n_i (Xu et al. 2009 type, SPEC §9)")
SHIFT_LAWS.register("fickian")("-C U_max h_i sum_j V_j grad W_ij (Lind et al. 2012 type; smooth at the support edge)")
POSITION_UPDATES = ("mls", "shepard", "w_i")
RECONSTRUCTIONS = ("taylor", "mls_direct")
LIMITERS = Registry("scheme.limiter")
LIMITERS.register("none")("no limiter")
LIMITERS.register("mood")("MOOD a-posteriori order reduction")


@dataclasses.dataclass(frozen=True)
class Scheme:
    """Numerical scheme.

    method:                   ``mlsph_ale`` | ``sph_ale``
    approximation, degree:    shape functions of the MLSPH-ALE area vectors (mls/kernel/shepard/corrected)
    kernel, beta:             kernel / MLS weight and h_i = beta V_i^(1/d)
    derivative:               ``full`` | ``fixed_centre`` MLS derivative
    reconstruction_degree:    polynomial degree of the Riemann-state reconstruction (0 = first order)
    reconstruction:           ``taylor`` (U_i + MLS derivatives, thesis eq. 3.11; default) |
                              ``mls_direct`` (the MLS fit evaluated at x_ij, eq. 4.39 read
                              literally; unstable on irregular layouts, see docs/architecture.md)
    reconstruction_variables: ``conservative`` | ``primitive``
    flux, wave_speed, dissipation_normal: numerical flux options (:mod:`mlsph_jax.flux`)
    self_flux:                keep the -F_i . sum_j A_ij term (thesis eq. 4.36)
    frame:                    ``eulerian`` | ``lagrangian`` | ``ale_shift`` (w = u + dw)
    shift_coefficient:        C of the shifting drift (:func:`mlsph_jax.rhs.shifting_velocity`)
    shift_law:                ``xu`` (default) | ``fickian``: the drift law of ``ale_shift``
    position_update:          ``mls`` (the method's own interpolant of w: MLS for mlsph_ale, the
                              Shepard kernel average T(3.7) for sph_ale) | ``shepard`` | ``w_i``
    limiter:                  ``none`` | ``mood``
    viscous, heat_conduction: include the viscous stress / heat flux (:mod:`mlsph_jax.viscous`;
                              set by the case builders from physics.mu > 0 / physics.kappa > 0)
    stress:                   ``stokes`` (with -2/3 div u) | ``incompressible`` (thesis ch. 3)
    mood_*:                   MOOD detectors (:mod:`mlsph_jax.mood`): NAD variables, delta_abs and
                              delta_rel of eq. 3.13, PAD/NAD switches, iteration bound
    eos:                      EOS kind
    rcond:                    MLS degree-fallback threshold
    """

    method: str = "mlsph_ale"
    approximation: str = "mls"
    degree: int = 2
    kernel: str = "cubic_spline"
    beta: float = 1.5
    derivative: str = "full"
    reconstruction_degree: int = 2
    reconstruction: str = "taylor"
    reconstruction_variables: str = "conservative"
    flux: str = "rusanov"
    wave_speed: str = "rusanov_abs"
    dissipation_normal: str = "area"
    self_flux: bool = True
    frame: str = "eulerian"
    shift_coefficient: float = 0.02
    shift_law: str = "xu"
    position_update: str = "mls"
    limiter: str = "none"
    viscous: bool = False
    heat_conduction: bool = False
    stress: str = "stokes"
    mood_variables: tuple[str, ...] = ("rho", "p")
    mood_delta_abs: float = 1e-4
    mood_delta_rel: float = 1e-3
    mood_delta_floor: str = "scaled"
    mood_pad: bool = True
    mood_nad: bool = True
    mood_max_iter: int = 8
    eos: str = "ideal_gas"
    rcond: float = 1e-6

    def __post_init__(self):
        METHODS.get(self.method, "scheme.method")
        APPROXIMATIONS.get(self.approximation, "scheme.approximation")
        get_kernel(self.kernel)
        FLUXES.get(self.flux, "scheme.flux")
        WAVE_SPEEDS.get(self.wave_speed, "scheme.wave_speed")
        FRAMES.get(self.frame, "scheme.frame")
        SHIFT_LAWS.get(self.shift_law, "scheme.shift_law")
        if self.heat_conduction and not get_eos(self.eos).has_energy:
            raise InputError(f"invalid heat_conduction=True with eos={self.eos!r}: it has no energy equation; "
                             "allowed: False, or an EOS with an energy equation (ideal_gas, stiffened_gas)")
        LIMITERS.get(self.limiter, "scheme.limiter")
        get_eos(self.eos)
        for name in ("degree", "reconstruction_degree"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= 3:
                raise InputError(f"invalid scheme.{name}={v!r}; allowed: an integer in 0..3")
        if not self.beta > 0:
            raise InputError(f"invalid scheme.beta={self.beta!r}; allowed: > 0")
        if self.dissipation_normal not in ("area", "pair"):
            raise InputError(f"invalid scheme.dissipation_normal={self.dissipation_normal!r}; allowed: area, pair")
        if self.reconstruction not in RECONSTRUCTIONS:
            raise InputError(f"invalid scheme.reconstruction={self.reconstruction!r}; "
                             f"allowed: {', '.join(RECONSTRUCTIONS)}")
        if self.reconstruction_variables not in ("conservative", "primitive"):
            raise InputError(f"invalid scheme.reconstruction_variables={self.reconstruction_variables!r}; "
                             "allowed: conservative, primitive")
        object.__setattr__(self, "mood_variables", tuple(self.mood_variables))
        bad = [v for v in self.mood_variables if v not in NAD_VARIABLES]
        if bad or not self.mood_variables:
            raise InputError(f"invalid scheme.mood_variables={list(self.mood_variables)!r}; allowed: a non-empty "
                             f"list of {', '.join(NAD_VARIABLES)}")
        if not (self.mood_delta_abs >= 0 and self.mood_delta_rel >= 0):
            raise InputError(f"invalid scheme.mood_delta_abs={self.mood_delta_abs!r} / mood_delta_rel="
                             f"{self.mood_delta_rel!r}; allowed: >= 0")
        if self.mood_delta_floor not in ("scaled", "absolute"):
            raise InputError(f"invalid scheme.mood_delta_floor={self.mood_delta_floor!r}; allowed: scaled, absolute")
        if isinstance(self.mood_max_iter, bool) or not isinstance(self.mood_max_iter, int) or self.mood_max_iter < 1:
            raise InputError(f"invalid scheme.mood_max_iter={self.mood_max_iter!r}; allowed: an integer >= 1")
        if self.limiter == "mood" and self.reconstruction_degree == 0:
            raise InputError("invalid scheme.limiter='mood' with scheme.reconstruction_degree=0; allowed: MOOD "
                             "needs a high-order candidate (reconstruction_degree 1..3) to reduce")
        if self.stress not in ("stokes", "incompressible"):
            raise InputError(f"invalid scheme.stress={self.stress!r}; allowed: stokes, incompressible")
        if self.position_update not in POSITION_UPDATES:
            raise InputError(f"invalid scheme.position_update={self.position_update!r}; "
                             f"allowed: {', '.join(POSITION_UPDATES)}")

    @classmethod
    def from_config(cls, table: Mapping, eos_kind: str) -> Scheme:
        """Build from a validated ``[scheme]`` table (``beta = 0`` selects the method default)."""
        kw = {f.name: table[f.name] for f in dataclasses.fields(cls) if f.name in table}
        kw.pop("neighbor_headroom", None)
        if not kw.get("beta"):
            kw["beta"] = METHOD_BETA[kw.get("method", "mlsph_ale")]
        return cls(**kw, eos=eos_kind)

    @property
    def moving(self) -> bool:
        """Whether particles move (neighbour lists and operators change every stage)."""
        return self.frame != "eulerian"

    @property
    def support(self) -> float:
        return get_kernel(self.kernel).support

    @property
    def diffusive(self) -> bool:
        """Whether the diffusive flux D (viscous stress and/or heat flux, thesis eq. 4.40) is on."""
        return self.viscous or self.heat_conduction

    @property
    def needs_fit(self) -> bool:
        """Whether per-particle MLS fits are needed (high-order reconstruction or diffusive fluxes)."""
        return self.reconstruction_degree > 0 or self.diffusive

    @property
    def fit_degree(self) -> int:
        """Degree of the fixed-centre fit: the reconstruction degree, or (first-order convective
        states with viscous fluxes) the area degree, at least 1."""
        return self.reconstruction_degree if self.reconstruction_degree > 0 else max(self.degree, 1)

    def area_spec(self) -> ApproxSpec:
        """Shape functions of the MLSPH-ALE area vectors (coefficients kept when they can be
        reused for the reconstruction and the viscous gradients)."""
        reuse = self.approximation == "mls" and self.degree == self.fit_degree
        return ApproxSpec(self.approximation, self.degree, self.kernel, self.derivative, self.rcond,
                          with_coeffs=reuse and self.needs_fit)

    def reconstruction_spec(self) -> ApproxSpec:
        """Fixed-centre MLS fit used for the reconstruction, SPH-ALE Taylor derivatives and the
        viscous gradients."""
        return ApproxSpec("mls", self.fit_degree, self.kernel, "fixed_centre", self.rcond, with_coeffs=True)
