"""Static, hashable description of a numerical scheme (the "method switchboard", SPEC §10.5).

A :class:`Scheme` is a jit static argument: changing it recompiles, changing
:class:`~mlsph_jax.state.Params` does not.  Built from the ``[scheme]`` config table with
:meth:`Scheme.from_config`; every field is validated against its registry.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

from .approximation import APPROXIMATIONS, ApproxSpec
from .area_correction import AREA_CORRECTIONS
from .eos import EOS_REGISTRY, get_eos
from .errors import InputError
from .flux import DISSIPATION_NORMALS, FLUXES, WAVE_SPEEDS
from .frames import FRAMES, POSITION_UPDATES, SHIFT_LAWS
from .kernels import KERNELS, get_kernel
from .methods import METHODS, default_beta
from .mood import DELTA_FLOORS, LIMITERS, NAD_VARIABLES
from .reconstruction import LOW_MACH_RECONSTRUCTIONS, RECONSTRUCTION_VARIABLES, RECONSTRUCTIONS
from .registry import Registry
from .viscous import STRESSES

__all__ = ["COMPONENTS", "GEOMETRY_UPDATES", "Scheme", "default_beta"]

#: ``scheme.geometry_update``: when moving particles rebuild their geometry (every Runge-Kutta
#: stage, or once per step; :func:`mlsph_jax.integrate.ssp_rk3_step`).
GEOMETRY_UPDATES = ("stage", "step")

#: Scheme field -> the registry of the component it names (the only lists of allowed names).
COMPONENTS: dict[str, Registry] = {
    "method": METHODS,
    "approximation": APPROXIMATIONS,
    "area_correction": AREA_CORRECTIONS,
    "kernel": KERNELS,
    "reconstruction": RECONSTRUCTIONS,
    "reconstruction_variables": RECONSTRUCTION_VARIABLES,
    "low_mach_reconstruction": LOW_MACH_RECONSTRUCTIONS,
    "flux": FLUXES,
    "wave_speed": WAVE_SPEEDS,
    "dissipation_normal": DISSIPATION_NORMALS,
    "frame": FRAMES,
    "shift_law": SHIFT_LAWS,
    "position_update": POSITION_UPDATES,
    "limiter": LIMITERS,
    "stress": STRESSES,
    "mood_delta_floor": DELTA_FLOORS,
    "eos": EOS_REGISTRY,
}

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
    low_mach_reconstruction:  ``none`` | ``thornber``: low-Mach correction of the reconstructed
                              states before the flux (:mod:`mlsph_jax.reconstruction`)
    flux, wave_speed, dissipation_normal: numerical flux options (:mod:`mlsph_jax.flux`); the
                              last two are read by Rusanov only
    reference_mach:           cutoff Mach number of the options that need one (``hllc_lm``);
                              0 = not given
    parachute_flux:           flux of the pairs MOOD reconstructs at first order: ``same`` (the
                              scheme's flux) or a registered flux (e.g. ``rusanov``)
    area_correction:          ``none`` | ``linear`` | ``quadratic`` | ``linear_interior`` |
                              ``quadratic_interior`` (decision 88) | ``linear_complete`` |
                              ``quadratic_complete`` (decision 92): consistency correction of
                              the area vectors (:mod:`mlsph_jax.area_correction`, decision 59)
    self_flux:                keep the -F_i . sum_j A_ij term (thesis eq. 4.36)
    conservation_projection:  subtract V_i R / sum_fluid V from every fluid row's d(V U)/dt (and,
                              moving, V_i R_V / sum V from dV/dt), R the fluid rows' sum of the
                              terms that are not pair or wall fluxes (the self term, the wall
                              bracket's s F_i . beta_i, decision 60's first-moment correction):
                              the totals of V U and V then change by the wall fluxes and sources
                              alone, to round-off (decision 112; needs ``self_flux``; refused with
                              non-fluid particles, open walls, local time stepping and the spatial
                              decomposition)
    ghost_shear_dissipation:  ``True`` (thesis: the flux of a fluid-ghost pair sees the whole
                              velocity jump) | ``False``: the jump of the wall-tangential velocity of
                              every fluid-ghost pair is removed before the flux, so a mirror wall's
                              tangential force is the viscous stress alone (decision 81)
    frame:                    ``eulerian`` | ``lagrangian`` | ``ale_shift`` (w = u + dw)
    shift_coefficient:        C of the shifting drift (:func:`mlsph_jax.rhs.shifting_velocity`)
    shift_law:                ``xu`` (default) | ``xu_smooth`` | ``fickian``: the drift law of ``ale_shift``
    position_update:          ``w_i`` (default: each particle moves with its own w) | ``mls`` (the
                              method's own interpolant of the frame velocity, eq. 4.28: MLS for
                              mlsph_ale, the Shepard average T(3.7) for sph_ale) | ``shepard``;
                              the fluxes and dV/dt use the same particle velocity (decision 44)
    geometry_update:          ``stage`` (default: neighbour list and geometry of every Runge-Kutta
                              stage) | ``step`` (moving frames: the geometry of the step's start
                              reused by its three stages; opt-in, first-order-in-time geometry,
                              docs/performance.md)
    limiter:                  ``none`` | ``mood``
    viscous, heat_conduction: include the viscous stress / heat flux (:mod:`mlsph_jax.viscous`;
                              set by the case builders from physics.mu > 0 / physics.kappa > 0)
    stress:                   ``stokes`` (with -2/3 div u) | ``incompressible`` (thesis ch. 3)
    mood_*:                   MOOD detectors (:mod:`mlsph_jax.mood`): NAD variables, delta_abs and
                              delta_rel of eq. 3.13, PAD/NAD switches, iteration bound
    eos:                      EOS kind
    rcond:                    MLS degree-fallback threshold (pivot ratio; decision 2)
    wall_rcond:               the threshold of the MLS fits (area shape functions, reconstruction
                              and viscous fit) whose stencil a boundary truncates (the rows at
                              boundary-integral walls, the edge of a frozen far field) and of the
                              fits at wall points; max(rcond, wall_rcond) is used (decision 77)
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
    low_mach_reconstruction: str = "none"
    flux: str = "rusanov"
    wave_speed: str = "rusanov_abs"
    dissipation_normal: str = "area"
    area_correction: str = "none"
    self_flux: bool = True
    conservation_projection: bool = False
    ghost_shear_dissipation: bool = True
    reference_mach: float = 0.0
    parachute_flux: str = "same"
    frame: str = "eulerian"
    shift_coefficient: float = 0.02
    shift_law: str = "xu"
    position_update: str = "w_i"
    geometry_update: str = "stage"
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
    rcond: float = 1e-2
    wall_rcond: float = 0.1

    def __post_init__(self):
        for field, reg in COMPONENTS.items():
            reg.get(getattr(self, field), "eos.kind" if field == "eos" else f"scheme.{field}")
        object.__setattr__(self, "mood_variables", tuple(self.mood_variables))
        if self.geometry_update not in GEOMETRY_UPDATES:
            raise InputError(f"invalid scheme.geometry_update={self.geometry_update!r}; allowed: "
                             f"{', '.join(GEOMETRY_UPDATES)}")
        if not self.mood_variables:
            raise InputError(f"invalid scheme.mood_variables={list(self.mood_variables)!r}; allowed: a non-empty "
                             f"list of {', '.join(NAD_VARIABLES.names())}")
        for v in self.mood_variables:
            NAD_VARIABLES.get(v, "scheme.mood_variables")
        if self.heat_conduction and not get_eos(self.eos).has_energy:
            raise InputError(f"invalid heat_conduction=True with eos={self.eos!r}: it has no energy equation; "
                             "allowed: False, or an EOS with an energy equation ("
                             f"{', '.join(n for n, e in EOS_REGISTRY.items() if e.has_energy)})")
        for name in ("degree", "reconstruction_degree"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= 3:
                raise InputError(f"invalid scheme.{name}={v!r}; allowed: an integer in 0..3")
        if not 0.0 <= self.rcond < 1.0:
            raise InputError(f"invalid scheme.rcond={self.rcond!r}; allowed: 0 <= rcond < 1")
        w = self.wall_rcond
        if isinstance(w, bool) or not isinstance(w, int | float) or not 0.0 <= w < 1.0:
            raise InputError(f"invalid scheme.wall_rcond={w!r}; allowed: a float with 0 <= wall_rcond < 1")
        if self.conservation_projection and not self.self_flux:
            raise InputError("invalid scheme.conservation_projection=true with scheme.self_flux=false: without "
                             "the self-flux term every term is a pair or wall flux and the totals are conserved "
                             "already; allowed: scheme.conservation_projection=false, or scheme.self_flux=true")
        if not self.beta > 0:
            raise InputError(f"invalid scheme.beta={self.beta!r}; allowed: > 0")
        if not (self.mood_delta_abs >= 0 and self.mood_delta_rel >= 0):
            raise InputError(f"invalid scheme.mood_delta_abs={self.mood_delta_abs!r} / mood_delta_rel="
                             f"{self.mood_delta_rel!r}; allowed: >= 0")
        if isinstance(self.mood_max_iter, bool) or not isinstance(self.mood_max_iter, int) or self.mood_max_iter < 1:
            raise InputError(f"invalid scheme.mood_max_iter={self.mood_max_iter!r}; allowed: an integer >= 1")
        if self.component("limiter").needs_high_order and self.reconstruction_degree == 0:
            raise InputError(f"invalid scheme.limiter={self.limiter!r} with scheme.reconstruction_degree=0; allowed: "
                             "this limiter needs a high-order candidate (reconstruction_degree 1..3) to reduce")
        self._check_flux_options()
        in_use = [self.component(f) for f in COMPONENTS] + ([self.parachute()] if self.parachute() else [])
        for comp in in_use:     # a component may check the rest of the scheme (e.g. a flux and its EOS)
            check = getattr(comp, "check_scheme", None)
            if check is not None:
                check(self)

    def _check_flux_options(self):
        """The parachute flux, the reference Mach number and the Rusanov-only options: a value that
        nothing in use reads is an error (nothing is silently ignored)."""
        if self.parachute_flux != "same":
            if self.parachute_flux not in FLUXES:
                raise InputError(f"unknown scheme.parachute_flux={self.parachute_flux!r}; allowed: same, "
                                 f"{', '.join(FLUXES.names())}")
            if not self.component("limiter").needs_high_order:
                raise InputError(f"invalid scheme.parachute_flux={self.parachute_flux!r} with scheme.limiter="
                                 f"{self.limiter!r}: only MOOD demotes pairs to first order; allowed: same, or a "
                                 "limiter that reduces the order (mood)")
        m = self.reference_mach
        if isinstance(m, bool) or not isinstance(m, int | float) or not 0.0 <= m <= 1.0:
            raise InputError(f"invalid scheme.reference_mach={m!r}; allowed: a float in [0, 1] (0 = not given)")
        fluxes = [self.component("flux")] + ([self.parachute()] if self.parachute() else [])
        users = fluxes + [self.component("low_mach_reconstruction")]
        if m != 0.0 and not any(getattr(c, "uses_reference_mach", False) for c in users):
            need = [n for n, f in FLUXES.items() if getattr(f, "uses_reference_mach", False)]
            raise InputError(f"invalid scheme.reference_mach={m!r}: nothing in the scheme reads it (scheme.flux="
                             f"{self.flux!r}, scheme.parachute_flux={self.parachute_flux!r}, "
                             f"scheme.low_mach_reconstruction={self.low_mach_reconstruction!r}); allowed: 0, or a "
                             f"flux that needs it ({', '.join(need)})")
        defaults = {f.name: f.default for f in dataclasses.fields(Scheme)}
        for field in ("wave_speed", "dissipation_normal"):
            value = getattr(self, field)
            if value != defaults[field] and not any(field in getattr(f, "scheme_fields", (field,)) for f in fluxes):
                readers = [n for n, f in FLUXES.items() if field in getattr(f, "scheme_fields", (field,))]
                raise InputError(f"invalid scheme.{field}={value!r} with scheme.flux={self.flux!r}: that flux does "
                                 f"not read scheme.{field}; allowed: {defaults[field]!r}, or a flux that reads it "
                                 f"({', '.join(readers)})")

    def parachute(self):
        """The flux of the pairs MOOD demoted to first order, or ``None`` when it is the scheme's
        flux (``parachute_flux = "same"`` or the same registered object)."""
        if self.parachute_flux == "same":
            return None
        obj = FLUXES.get(self.parachute_flux, "scheme.parachute_flux")
        return None if obj is self.component("flux") else obj

    def component(self, field: str):
        """The registered object named by the scheme field ``field`` (e.g. ``scheme.component("flux")``)."""
        try:
            reg = COMPONENTS[field]
        except KeyError:
            raise InputError(f"unknown scheme component {field!r}; allowed: {', '.join(COMPONENTS)}") from None
        return reg.get(getattr(self, field))

    @classmethod
    def from_config(cls, table: Mapping, eos_kind: str) -> Scheme:
        """Build from a validated ``[scheme]`` table (``beta = 0`` selects the method default)."""
        kw = {f.name: table[f.name] for f in dataclasses.fields(cls) if f.name in table}
        kw.pop("neighbor_headroom", None)
        if not kw.get("beta"):
            kw["beta"] = default_beta(kw.get("method", "mlsph_ale"))
        return cls(**kw, eos=eos_kind)

    @property
    def moving(self) -> bool:
        """Whether particles move (neighbour lists and operators change every stage)."""
        return bool(self.component("frame").moving)

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
        approx = self.component("approximation")
        reuse = approx.has_coeffs and approx.basis_degree(self.degree) == self.fit_degree
        return ApproxSpec(self.approximation, self.degree, self.kernel, self.derivative, self.rcond,
                          with_coeffs=reuse and self.needs_fit, wall_rcond=float(self.wall_rcond))

    def reconstruction_spec(self) -> ApproxSpec:
        """Fixed-centre MLS fit used for the reconstruction, SPH-ALE Taylor derivatives and the
        viscous gradients."""
        return ApproxSpec("mls", self.fit_degree, self.kernel, "fixed_centre", self.rcond, with_coeffs=True,
                          wall_rcond=float(self.wall_rcond))

    @property
    def wall_fit_rcond(self) -> float:
        """Pivot threshold of the fits at wall points (the wall state, the constrained wall fit)
        and of truncated stencils: max(rcond, wall_rcond) (decision 77)."""
        return max(float(self.rcond), float(self.wall_rcond))
