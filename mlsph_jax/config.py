"""Schema-validated TOML configurations.

A config is a TOML file with the tables ``[case]``, ``[scheme]``, ``[eos]``, ``[physics]``,
``[time]`` and ``[output]``.  Every key is described by a :class:`Key`: its type, default (or
:data:`REQUIRED`), allowed values or range, unit and a one-line doc.  :func:`load` reads a file,
applies ``--set`` style overrides, fills every default and validates everything; the result is
a plain nested ``dict`` holding every table and every key.

* ``[case]`` — ``name`` selects a case schema registered with :func:`register_case_schema`
  (the other ``[case]`` keys belong to that case).  A case may also change the defaults of the
  other tables (``defaults_override``), check keys against each other (``check``) and fix the
  space dimension (``dim``, used to check ``physics.body_force``).
* ``[eos]`` — ``kind`` selects the EOS schema in :data:`EOS_SCHEMAS`.
* ``[scheme]``, ``[time]``, ``[output]``, ``[physics]`` — :data:`SCHEMA_COMMON`.

Typing rules: an int is accepted for a float key (and converted to float); a float is never
accepted for an int key; bools are not numbers; every number must be finite.  An unknown
table or key, a wrong type or an out-of-range value raises :class:`~mlsph_jax.errors.ConfigError`
naming the dotted key, the value given and what is allowed; all problems of a file are reported
together.

Case schemas are registered by the case modules; :func:`load` imports the package
``mlsph_jax.cases`` (if it exists) before reporting an unknown case, so that the built-in cases
are known without an explicit import.  ``python -m mlsph_jax.config`` prints the reference
(:func:`config_reference_markdown`, the source of ``docs/config.md``).
"""

from __future__ import annotations

import dataclasses
import difflib
import importlib
import math
import re
import tomllib
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np

from .errors import ConfigError
from .registry import Registry

__all__ = [
    "CASE_SCHEMAS",
    "EOS_KIND",
    "EOS_SCHEMAS",
    "METHOD_BETA",
    "REQUIRED",
    "SCHEMA_COMMON",
    "TABLES",
    "CaseSchema",
    "Key",
    "config_reference_markdown",
    "dumps",
    "effective_beta",
    "load",
    "loads",
    "parse_override",
    "register_case_schema",
    "validate",
]


class _Required:
    """Sentinel default of a key that has no default."""

    _instance = None

    def __new__(cls):
        if cls._instance is None:
            cls._instance = super().__new__(cls)
        return cls._instance

    def __repr__(self):
        return "REQUIRED"

    def __reduce__(self):
        return (_Required, ())


REQUIRED = _Required()

_TYPE_NAMES = {float: "float", int: "int", str: "str", bool: "bool", list: "list", dict: "table"}
_SCALARS = (float, int, str, bool)


# --------------------------------------------------------------------------------------------
# Keys
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Key:
    """Schema of one config key.

    ``type`` is one of ``float, int, str, bool, list, dict`` (or a tuple of them: the first
    that accepts the value wins).  ``item_type`` is the scalar type of the items of a list or
    the values of a dict (inline table); ``length`` fixes the length of a list.  ``choices``,
    ``minimum`` and ``maximum`` (inclusive unless ``exclusive_minimum``/``exclusive_maximum``)
    apply to a scalar value or to every item of a list/dict.  ``note`` is extra text appended
    to the "allowed" description (e.g. "0 = method default").
    """

    type: type | tuple
    default: object = REQUIRED
    doc: str = ""
    choices: tuple | None = None
    minimum: float | None = None
    maximum: float | None = None
    exclusive_minimum: bool = False
    exclusive_maximum: bool = False
    item_type: type | None = None
    length: int | None = None
    unit: str = ""
    note: str = ""

    def __post_init__(self):
        for t in self.types:
            if t not in _TYPE_NAMES:
                raise TypeError(f"Key type {t!r} is not one of {sorted(_TYPE_NAMES.values())}")
        if self.item_type is not None and self.item_type not in _SCALARS:
            raise TypeError(f"Key item_type {self.item_type!r} is not a scalar type")
        if self.default is not REQUIRED:
            self.check("<default>", self.default)  # a schema with a bad default is a bug

    @property
    def types(self) -> tuple:
        return self.type if isinstance(self.type, tuple) else (self.type,)

    @property
    def required(self) -> bool:
        return self.default is REQUIRED

    def type_name(self) -> str:
        names = []
        for t in self.types:
            if t in (list, dict) and self.item_type is not None:
                kind = "list" if t is list else "table"
                n = f" (length {self.length})" if t is list and self.length is not None else ""
                names.append(f"{kind} of {_TYPE_NAMES[self.item_type]}{n}")
            else:
                names.append(_TYPE_NAMES[t])
        return " or ".join(names)

    def allowed(self) -> str:
        """Human-readable description of the allowed values."""
        if self.choices is not None:
            text = "one of " + ", ".join(_toml_value(c) for c in self.choices)
        else:
            text = self.type_name()
            rng = self._range_text()
            if rng:
                text += " " + rng
        if self.note:
            text += f" ({self.note})"
        return text

    def _range_text(self) -> str:
        lo, hi = self.minimum, self.maximum
        if lo is not None and hi is not None:
            return (f"in {'(' if self.exclusive_minimum else '['}{_num(lo)}, "
                    f"{_num(hi)}{')' if self.exclusive_maximum else ']'}")
        if lo is not None:
            return f"{'>' if self.exclusive_minimum else '>='} {_num(lo)}"
        if hi is not None:
            return f"{'<' if self.exclusive_maximum else '<='} {_num(hi)}"
        return ""

    # -- checking ---------------------------------------------------------------------------
    def check(self, dotted: str, value):
        """Return ``value`` normalised (ints → floats for float keys, copies of containers) or
        raise :class:`ConfigError` naming ``dotted``, the value and what is allowed."""
        reason = None
        for t in self.types:
            ok, out, why = self._check_as(t, value)
            if ok:
                return out
            reason = reason or why
        raise ConfigError(f"invalid {dotted}={_show(value)}: {reason}; allowed: {self.allowed()}")

    def check_item(self, dotted: str, value):
        """Check one item of a list/dict key (used for ``case.left.rho=...`` overrides)."""
        t = self.item_type
        if t is None:
            raise ConfigError(f"invalid {dotted}: {dotted.rsplit('.', 1)[0]} has no typed items")
        ok, out, why = self._scalar(t, value)
        if ok:
            why = self._range_error(out)
            if why is None:
                return out
        raise ConfigError(f"invalid {dotted}={_show(value)}: {why}; allowed: {self.allowed()}")

    def _check_as(self, t, value):
        if t in _SCALARS:
            ok, out, why = self._scalar(t, value)
            if not ok:
                return False, None, why
            why = self._range_error(out)
            return why is None, out, why
        if t is list:
            if not isinstance(value, list | tuple):
                return False, None, f"expected {self.type_name()}, got {_kind(value)}"
            if self.length is not None and len(value) != self.length:
                return False, None, f"expected {self.length} items, got {len(value)}"
            out = []
            for i, v in enumerate(value):
                ok, o, why = self._item(v)
                if not ok:
                    return False, None, f"item {i}: {why}"
                out.append(o)
            return True, out, None
        # dict (inline table)
        if not isinstance(value, Mapping):
            return False, None, f"expected {self.type_name()}, got {_kind(value)}"
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                return False, None, f"table keys must be strings, got {k!r}"
            ok, o, why = self._item(v)
            if not ok:
                return False, None, f"entry {k!r}: {why}"
            out[k] = o
        return True, out, None

    def _item(self, v):
        if self.item_type is None:
            if isinstance(v, Mapping | list | tuple):
                return False, None, f"nested {_kind(v)} not allowed"
            for t in _SCALARS:
                ok, o, _ = self._scalar(t, v)
                if ok:
                    return True, o, None
            return False, None, f"unsupported value {_kind(v)}"
        ok, o, why = self._scalar(self.item_type, v)
        if ok:
            why = self._range_error(o)
        return why is None, o, why

    @staticmethod
    def _scalar(t, v):
        is_bool = isinstance(v, bool | np.bool_)
        if t is bool:
            if is_bool:
                return True, bool(v), None
            return False, None, f"expected bool (true/false), got {_kind(v)}"
        if t is str:
            if isinstance(v, str):
                return True, v, None
            return False, None, f"expected str, got {_kind(v)}"
        if t is int:
            if isinstance(v, int | np.integer) and not is_bool:
                return True, int(v), None
            if isinstance(v, float | np.floating):
                return False, None, "expected int, got float (write it without a decimal point)"
            return False, None, f"expected int, got {_kind(v)}"
        # float
        if isinstance(v, int | float | np.integer | np.floating) and not is_bool:
            f = float(v)
            if not math.isfinite(f):
                return False, None, "numbers must be finite"
            return True, f, None
        return False, None, f"expected float, got {_kind(v)}"

    def _range_error(self, v) -> str | None:
        if self.choices is not None and v not in self.choices:
            return "not an allowed choice"
        if isinstance(v, int | float) and not isinstance(v, bool):
            lo, hi = self.minimum, self.maximum
            if lo is not None and (v < lo or (self.exclusive_minimum and v == lo)):
                return "out of range"
            if hi is not None and (v > hi or (self.exclusive_maximum and v == hi)):
                return "out of range"
        return None


def _num(x) -> str:
    return _toml_value(x) if isinstance(x, int | float) else str(x)


def _kind(v) -> str:
    if isinstance(v, bool | np.bool_):
        return "bool"
    if isinstance(v, Mapping):
        return "table"
    if isinstance(v, list | tuple):
        return "list"
    if isinstance(v, int | np.integer):
        return "int"
    if isinstance(v, float | np.floating):
        return "float"
    return type(v).__name__


def _show(v) -> str:
    try:
        return _toml_value(v)
    except (ConfigError, TypeError):
        return repr(v)


# --------------------------------------------------------------------------------------------
# Schemas
# --------------------------------------------------------------------------------------------

TABLES = ("case", "scheme", "eos", "physics", "time", "output")

TABLE_DOCS = {
    "case": "The test case: `name` selects the case; its other keys depend on the case.",
    "scheme": "The numerical method: approximation, reconstruction, flux, frame, limiter.",
    "eos": "Equation of state: `kind` selects the EOS; its other keys depend on the kind.",
    "physics": "Physical parameters shared by all cases.",
    "time": "Time integration (SSP-RK3) and time-step control.",
    "output": "What the run writes (snapshots, plots) and shows (progress).",
}

#: Smoothing-length factor beta (h_i = beta V_i^(1/d)) used when ``scheme.beta = 0``.
METHOD_BETA = {"mlsph_ale": 1.5, "sph_ale": 2.0}

SCHEMA_COMMON: dict[str, dict[str, Key]] = {
    "scheme": {
        "method": Key(str, "mlsph_ale", choices=("mlsph_ale", "sph_ale"),
                      doc="particle method: MLSPH-ALE (MLS areas, thesis ch. 4) or kernel SPH-ALE "
                          "(thesis ch. 3)"),
        "approximation": Key(str, "mls", choices=("mls", "kernel", "shepard", "corrected"),
                             doc="shape functions used for the area vectors in mlsph_ale: MLS, "
                                 "kernel W*V, Shepard W/sum(W), or corrected kernel"),
        "degree": Key(int, 2, minimum=0, maximum=3,
                      doc="degree of the MLS polynomial basis (0 constant, 1 linear, 2 quadratic, "
                          "3 cubic)"),
        "kernel": Key(str, "cubic_spline",
                      choices=("cubic_spline", "wendland_c2", "quintic_spline"),
                      doc="smoothing kernel (also the MLS weight function)"),
        "beta": Key(float, 0.0, minimum=0.0, note="0 = method default",
                    doc="smoothing-length factor, h_i = beta V_i^(1/d); 0 selects the method "
                        "default (1.5 for mlsph_ale, 2.0 for sph_ale)"),
        "derivative": Key(str, "full", choices=("full", "fixed_centre"),
                          doc="MLS shape-function derivatives: full (exact derivative of N_j) or "
                              "fixed_centre (diffuse, moment matrix frozen at the centre)"),
        "reconstruction_degree": Key(int, 2, minimum=0, maximum=3,
                                     doc="degree of the MLS reconstruction of the Riemann states "
                                         "at the pair midpoints (0 = first order, no "
                                         "reconstruction)"),
        "reconstruction": Key(str, "taylor", choices=("taylor", "mls_direct"),
                              doc="Riemann-state reconstruction at x_ij: taylor = U_i plus the MLS "
                                  "derivatives of U at x_i (thesis eq. 3.11; stable on irregular "
                                  "layouts), mls_direct = the MLS fit of the stencil evaluated at "
                                  "x_ij (eq. 4.39 read literally; unstable on jittered layouts)"),
        "reconstruction_variables": Key(str, "conservative", choices=("conservative", "primitive"),
                                        doc="variables reconstructed at the pair midpoints"),
        "flux": Key(str, "rusanov", choices=("rusanov",),
                    doc="numerical (Riemann) flux at the pair midpoints"),
        "wave_speed": Key(str, "rusanov_abs", choices=("rusanov_abs", "printed_ch3", "printed_ch4"),
                          doc="Rusanov wave-speed estimate: max(|(u-w).n|+c) (standard), or the "
                              "signed formulas printed in thesis ch. 3 / ch. 4 (reproduction "
                              "studies)"),
        "dissipation_normal": Key(str, "area", choices=("area", "pair"),
                                  doc="normal of the Rusanov dissipation term: A_ij/|A_ij| (area) "
                                      "or the unit vector between the particles (pair)"),
        "self_flux": Key(bool, True,
                         doc="include the self-flux term -F_i.sum_j A_ij (thesis default; keeps "
                             "uniform states exact, conserves only up to a quadrature defect)"),
        "frame": Key(str, "eulerian", choices=("eulerian", "lagrangian", "ale_shift"),
                     doc="ALE frame velocity: eulerian (w = 0, particles fixed), lagrangian "
                         "(w = u) or ale_shift (w = u + particle-shifting drift, SPEC §9)"),
        "shift_law": Key(str, "xu", choices=("xu", "fickian"),
                         doc="drift law of the ale_shift frame: xu (repulsion C U_max sum_j (r_i/r_ij)^2 "
                             "e_ji / n_i, SPEC §9) or fickian (-C U_max h_i sum_j V_j grad W_ij, smooth where "
                             "neighbours cross the support edge)"),
        "shift_coefficient": Key(float, 0.02, minimum=0.0,
                                 doc="coefficient C of the ale_shift drift (both laws of scheme.shift_law; "
                                     "mlsph_jax.rhs.shifting_velocity)"),
        "stress": Key(str, "stokes", choices=("stokes", "incompressible"),
                      doc="viscous stress: stokes (mu (grad u + grad u^T - 2/3 div u I)) or "
                          "incompressible (no -2/3 div u term, thesis ch. 3)"),
        "position_update": Key(str, "mls", choices=("mls", "shepard", "w_i"),
                               doc="velocity that moves the particles: MLS interpolant of w, "
                                   "Shepard average of w, or the particle's own w_i"),
        "limiter": Key(str, "none", choices=("none", "mood"),
                       doc="a-posteriori limiter: none or MOOD (local reduction of the "
                           "reconstruction degree)"),
        "mood_variables": Key(list, ["rho", "p"], item_type=str, choices=("rho", "p", "vel", "e", "conservative"),
                              doc="variables checked by the MOOD NAD detector (relaxed discrete maximum "
                                  "principle, thesis eq. 3.12); vel = every velocity component, "
                                  "conservative = every component of U"),
        "mood_delta_abs": Key(float, 1e-4, minimum=0.0,
                              doc="absolute NAD tolerance floor (thesis eq. 3.13; in the variable's units)"),
        "mood_delta_floor": Key(str, "scaled", choices=("scaled", "absolute"),
                                doc="NAD floor: scaled = mood_delta_abs * max |phi| over all particles "
                                    "(default; unit-free), absolute = mood_delta_abs as printed in "
                                    "thesis eq. 3.13 (in the variable's units: Pa, kg/m^3)"),
        "mood_delta_rel": Key(float, 1e-3, minimum=0.0,
                              doc="NAD tolerance relative to the stencil range max - min (thesis eq. 3.13)"),
        "mood_pad": Key(bool, True, doc="MOOD physical-admissibility detector (finite, rho > 0; p > 0 for "
                                        "the ideal gas, p + pc > 0 for the stiffened gas)"),
        "mood_nad": Key(bool, True, doc="MOOD numerical-admissibility detector (no new extrema)"),
        "mood_max_iter": Key(int, 8, minimum=1,
                             doc="bound on the MOOD detect-and-demote iterations per Runge-Kutta stage"),
        "neighbor_headroom": Key(float, 1.3, minimum=1.0,
                                 doc="neighbour-list capacity as a multiple of the largest initial "
                                     "neighbour count"),
    },
    "time": {
        "t_end": Key(float, minimum=0.0, exclusive_minimum=True, unit="s",
                     doc="final physical time"),
        "cfl": Key(float, 0.3, minimum=0.0, maximum=1.0, exclusive_minimum=True,
                   doc="CFL number C in dt = C min_i dx_i / (|u_i - w_i| + c_i)"),
        "cfl_viscous": Key(float, 0.125, minimum=0.0, maximum=1.0, exclusive_minimum=True,
                           doc="diffusive time-step factor: dt <= cfl_viscous min_i rho_i dx_i^2 / max(mu, kappa)"),
        "dt": Key(float, 0.0, minimum=0.0, unit="s", note="0 = adaptive",
                  doc="fixed time step; 0 selects the adaptive CFL step"),
        "max_steps": Key(int, 1_000_000, minimum=1,
                         doc="maximum number of time steps before the run is stopped"),
        "chunk": Key(int, 50, minimum=1,
                     doc="time steps per jitted scan chunk (output, progress and neighbour checks "
                         "happen between chunks)"),
        "dt_min": Key(float, 1e-14, minimum=0.0, maximum=1.0, exclusive_minimum=True,
                      exclusive_maximum=True,
                      doc="time-step underflow threshold relative to t_end: the run fails if "
                          "dt < dt_min * t_end"),
    },
    "output": {
        "snapshots": Key(int, 10, minimum=1,
                         doc="number of snapshots written besides the initial one (equally spaced "
                             "in time)"),
        "plots": Key(bool, True, doc="write PNG plots at the end of the run"),
        "progress": Key(bool, True, doc="show a progress bar during the run"),
    },
    "physics": {
        "mu": Key(float, 0.0, minimum=0.0, unit="Pa s",
                  doc="dynamic viscosity (0 = inviscid Euler equations)"),
        "kappa": Key(float, 0.0, minimum=0.0, unit="kg/(m s)",
                     doc="heat conduction coefficient k/c_v of q = -kappa grad e (0 = none; must be 0 "
                         "for the Tait EOS, which has no energy equation)"),
        "body_force": Key(list, [], item_type=float, unit="m/s^2",
                          note="empty, or one component per space dimension",
                          doc="body-force acceleration vector (empty = no body force)"),
    },
}

#: The ``[eos].kind`` key (its choices are the keys of :data:`EOS_SCHEMAS`).
EOS_SCHEMAS: dict[str, dict[str, Key]] = {
    "ideal_gas": {
        "gamma": Key(float, 1.4, minimum=1.0, exclusive_minimum=True,
                     doc="ratio of specific heats, p = (gamma - 1) rho e"),
    },
    "tait": {
        "rho0": Key(float, minimum=0.0, exclusive_minimum=True, unit="kg/m^3",
                    doc="reference density"),
        "c0": Key(float, minimum=0.0, exclusive_minimum=True, unit="m/s",
                  doc="sound speed at the reference density"),
        "gamma": Key(float, 7.0, minimum=0.0, exclusive_minimum=True,
                     doc="Tait exponent, p = rho0 c0^2/gamma ((rho/rho0)^gamma - 1) + p0"),
        "p0": Key(float, 0.0, unit="Pa", doc="background pressure added to the Tait pressure"),
    },
    "stiffened_gas": {
        "gamma": Key(float, minimum=1.0, exclusive_minimum=True,
                     doc="Tammann exponent, p = (gamma - 1) rho e - gamma pc"),
        "pc": Key(float, minimum=0.0, unit="Pa", doc="stiffening pressure"),
    },
}

EOS_KIND = Key(str, "ideal_gas", choices=tuple(EOS_SCHEMAS),
               doc="equation of state; selects the other [eos] keys")

_CASE_NAME_DOC = "the test case; selects the other [case] keys"


@dataclasses.dataclass(frozen=True)
class CaseSchema:
    """A registered ``[case]`` schema (see :func:`register_case_schema`)."""

    name: str
    keys: dict[str, Key]
    defaults_override: dict[str, object]
    check: Callable[[dict], None] | None = None
    doc: str = ""
    dim: int | None = None

    def table(self) -> dict[str, Key]:
        """The full ``[case]`` schema, ``name`` first."""
        return {"name": Key(str, REQUIRED, doc=_CASE_NAME_DOC), **self.keys}


#: Registered case schemas, by case name.
CASE_SCHEMAS: Registry[CaseSchema] = Registry("case")


def register_case_schema(name: str, keys: Mapping[str, Key],
                         defaults_override: Mapping[str, object] | None = None,
                         check: Callable[[dict], None] | None = None, *, doc: str = "",
                         dim: int | None = None) -> CaseSchema:
    """Register the ``[case]`` schema of the case ``name`` and return it.

    ``keys`` are the case's own keys (``name`` is added automatically).  ``defaults_override``
    maps dotted keys of the other tables to per-case defaults, e.g.
    ``{"scheme.frame": "lagrangian", "eos.kind": "tait", "eos.rho0": 1000.0}`` (an ``eos``
    default applies only when the resolved ``eos.kind`` has that key).  ``check(cfg)`` receives
    the resolved, type-checked config and raises :class:`ConfigError` for cross-key problems;
    its docstring is shown in the reference.  ``dim`` (1, 2 or 3) fixes the space dimension:
    ``physics.body_force`` must then be empty or have ``dim`` components.
    """
    if not isinstance(name, str) or not re.fullmatch(r"[a-z][a-z0-9_]*", name):
        raise ValueError(f"case name {name!r} must be lower-case letters, digits and '_'")
    keys = dict(keys)
    if "name" in keys:
        raise ValueError(f"case {name!r}: the key 'name' is added automatically; do not define it")
    for k, key in keys.items():
        if not isinstance(key, Key):
            raise TypeError(f"case {name!r}: key {k!r} must be a Key, got {type(key).__name__}")
    if dim not in (None, 1, 2, 3):
        raise ValueError(f"case {name!r}: dim={dim!r}; allowed: None, 1, 2, 3")
    over = {}
    for dotted, value in dict(defaults_override or {}).items():
        table, _, k = dotted.partition(".")
        if table == "eos":
            cands = [EOS_KIND] if k == "kind" else [s[k] for s in EOS_SCHEMAS.values() if k in s]
        elif table in SCHEMA_COMMON:
            cands = [SCHEMA_COMMON[table][k]] if k in SCHEMA_COMMON[table] else []
        else:
            raise ValueError(f"case {name!r}: defaults_override key {dotted!r} must be in one of "
                             f"the tables {', '.join(t for t in TABLES if t != 'case')}")
        if not cands:
            raise ValueError(f"case {name!r}: defaults_override names the unknown key {dotted!r}")
        over[dotted] = cands[0].check(dotted, value)
    schema = CaseSchema(name=name, keys=keys, defaults_override=over, check=check, doc=doc, dim=dim)
    CASE_SCHEMAS.register(name)(schema)
    return schema


def _import_case_modules() -> None:
    """Import ``mlsph_jax.cases`` so that the built-in cases register their schemas."""
    try:
        importlib.import_module(f"{__package__}.cases")
    except ModuleNotFoundError as e:
        if e.name != f"{__package__}.cases":
            raise


def _case_schema(name) -> CaseSchema:
    if not (isinstance(name, str) and name in CASE_SCHEMAS):
        _import_case_modules()
    if isinstance(name, str) and name in CASE_SCHEMAS:
        return CASE_SCHEMAS.get(name)
    raise ConfigError(f"invalid case.name={_show(name)}: not a registered case; allowed: one of "
                      f"{', '.join(CASE_SCHEMAS.names()) or '(none registered)'}")


def effective_beta(scheme: Mapping) -> float:
    """Smoothing-length factor of a resolved ``[scheme]`` table (``beta = 0``: method default)."""
    return float(scheme["beta"]) or METHOD_BETA[scheme["method"]]


# --------------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------------


def _table_schema(table: str, case: CaseSchema | None, eos_kind: str | None) -> dict[str, Key]:
    if table == "case":
        if case is None:
            return {"name": Key(str, REQUIRED, doc=_CASE_NAME_DOC)}
        return case.table()
    if table == "eos":
        return {"kind": EOS_KIND, **EOS_SCHEMAS.get(eos_kind, {})}
    return SCHEMA_COMMON[table]


def _suggest(word: str, options) -> str:
    m = difflib.get_close_matches(word, list(options), n=1, cutoff=0.6)
    return m[0] if m else ""


_IN_OVERRIDE = object()


def _unknown_key_message(table: str, key: str, value, schema: Mapping[str, Key],
                         case: CaseSchema | None, eos_kind: str | None) -> str:
    given = "in override" if value is _IN_OVERRIDE else f"value {_show(value)}"
    msg = f"unknown key {table}.{key} ({given})"
    s = _suggest(key, schema)
    if s:
        msg += f"; did you mean {table}.{s}?"
    if table == "eos":
        others = [k for k, sch in EOS_SCHEMAS.items() if key in sch and k != eos_kind]
        if others:
            msg += f" ({table}.{key} belongs to eos.kind = {', '.join(map(repr, others))})"
        where = f"[eos] with kind = {eos_kind!r}"
    elif table == "case" and case is not None:
        where = f"[case] of case {case.name!r}"
    else:
        where = f"[{table}]"
    return msg + f"; valid keys of {where}: {', '.join(schema)}"


def validate(cfg: Mapping) -> dict:
    """Validate a config (nested mapping) and return it resolved: every table and every key
    present (defaults filled), ints converted for float keys, tables and keys in schema order.

    Raises :class:`ConfigError` listing every problem found.  ``validate`` is idempotent.
    """
    if not isinstance(cfg, Mapping):
        raise ConfigError(f"invalid config of type {type(cfg).__name__}; allowed: a table (dict)")
    problems: list[str] = []
    for t, v in cfg.items():
        if t not in TABLES:
            owners = [f"{tab}.{t}" for tab in TABLES[1:] if t in _all_keys(tab)]
            if not isinstance(v, Mapping):
                hint = f"; did you mean {owners[0]}?" if owners else ""
                problems.append(f"unknown top-level key {t} (value {_show(v)}): keys belong in a "
                                f"table{hint}; valid tables: {', '.join(TABLES)}")
            else:
                s = _suggest(t, TABLES)
                hint = f"; did you mean [{s}]?" if s else ""
                problems.append(f"unknown table [{t}]{hint}; valid tables: {', '.join(TABLES)}")
        elif not isinstance(v, Mapping):
            problems.append(f"invalid {t}={_show(v)}: expected a table [{t}]; "
                            f"allowed: a table of keys")

    raw = {t: cfg[t] if isinstance(cfg.get(t), Mapping) else {} for t in TABLES}
    if "name" not in raw["case"]:
        problems.append("missing required key case.name; allowed: one of "
                        f"{', '.join(_registered_cases()) or '(none registered)'}")
        raise ConfigError(_join(problems))
    try:
        case = _case_schema(raw["case"]["name"])
    except ConfigError as e:
        raise ConfigError(_join([*problems, str(e)])) from None
    try:
        eos_kind = EOS_KIND.check("eos.kind", raw["eos"].get(
            "kind", case.defaults_override.get("eos.kind", EOS_KIND.default)))
    except ConfigError as e:
        raise ConfigError(_join([*problems, str(e)])) from None

    out: dict[str, dict] = {}
    missing: list[str] = []
    for table in TABLES:
        schema = _table_schema(table, case, eos_kind)
        given = raw[table]
        res = {}
        for k, v in given.items():
            if k not in schema:
                problems.append(_unknown_key_message(table, k, v, schema, case, eos_kind))
                continue
            try:
                res[k] = schema[k].check(f"{table}.{k}", v)
            except ConfigError as e:
                problems.append(str(e))
        filled = {}
        for k, key in schema.items():
            dotted = f"{table}.{k}"
            if k in res:
                filled[k] = res[k]
            elif k in given:
                continue  # invalid, already reported
            elif dotted in case.defaults_override:
                filled[k] = _copy(case.defaults_override[dotted])
            elif key.required:
                missing.append(f"{dotted} ({key.doc}; allowed: {key.allowed()})" if key.doc
                               else f"{dotted} (allowed: {key.allowed()})")
            else:
                filled[k] = _copy(key.default)
        out[table] = filled
    if missing:
        problems.append("missing required key" + ("s" if len(missing) > 1 else "") + ": "
                        + "; ".join(missing))
    if problems:
        raise ConfigError(_join(problems))

    bf = out["physics"]["body_force"]
    if case.dim is not None and len(bf) not in (0, case.dim):
        raise ConfigError(f"invalid physics.body_force={_show(bf)}: case {case.name!r} is "
                          f"{case.dim}-D; allowed: [] or a list of {case.dim} floats")
    if out["eos"]["kind"] == "tait" and out["physics"]["kappa"] > 0:
        raise ConfigError(f"invalid physics.kappa={_show(out['physics']['kappa'])} with eos.kind = 'tait': the "
                          "Tait EOS is barotropic and has no energy equation, so heat conduction cannot act; "
                          "allowed: 0 (or an EOS with an energy equation: ideal_gas, stiffened_gas)")
    if case.check is not None:
        case.check(out)
    return out


def _registered_cases() -> list[str]:
    _import_case_modules()
    return CASE_SCHEMAS.names()


def _all_keys(table: str) -> set[str]:
    if table == "eos":
        return {"kind", *(k for s in EOS_SCHEMAS.values() for k in s)}
    if table == "case":
        return {"name", *(k for c in CASE_SCHEMAS for k in CASE_SCHEMAS.get(c).keys)}
    return set(SCHEMA_COMMON[table])


def _join(problems: list[str]) -> str:
    if len(problems) == 1:
        return problems[0]
    return f"{len(problems)} problems in the config:\n" + "\n".join(f"  - {p}" for p in problems)


def _copy(v):
    if isinstance(v, list):
        return [_copy(x) for x in v]
    if isinstance(v, dict):
        return {k: _copy(x) for k, x in v.items()}
    return v


# --------------------------------------------------------------------------------------------
# Overrides and loading
# --------------------------------------------------------------------------------------------


def _lookup_key(dotted: str, case: str | None, eos_kind: str | None) -> tuple[Key, str | None]:
    """The :class:`Key` of ``table.key`` (and the sub-key for ``table.key.sub`` on a table-valued
    key).  Without ``case``/``eos_kind`` the union of all case/EOS schemas is searched."""
    parts = dotted.split(".")
    if len(parts) not in (2, 3) or not all(parts):
        raise ConfigError(f"invalid override key {dotted!r}; allowed: TABLE.KEY (e.g. "
                          f"scheme.degree) with TABLE one of {', '.join(TABLES)}")
    table, k = parts[0], parts[1]
    if table not in TABLES:
        s = _suggest(table, TABLES)
        raise ConfigError(f"unknown table [{table}] in override key {dotted!r}"
                          + (f"; did you mean {s}.{k}?" if s else "")
                          + f"; valid tables: {', '.join(TABLES)}")
    if table == "case":
        schemas = [_case_schema(case).table()] if case is not None else (
            [CASE_SCHEMAS.get(c).table() for c in _registered_cases()]
            or [_table_schema("case", None, None)])
    elif table == "eos":
        schemas = [_table_schema("eos", None, eos_kind)] if eos_kind is not None else (
            [_table_schema("eos", None, kind) for kind in EOS_SCHEMAS])
    else:
        schemas = [SCHEMA_COMMON[table]]
    for schema in schemas:
        if k in schema:
            key = schema[k]
            if len(parts) == 3 and dict not in key.types:
                raise ConfigError(f"invalid override key {dotted!r}: {table}.{k} is a "
                                  f"{key.type_name()}, not a table")
            return key, parts[2] if len(parts) == 3 else None
    merged = {kk: vv for sch in schemas for kk, vv in sch.items()}
    c = _case_schema(case) if (table == "case" and case is not None) else None
    raise ConfigError(_unknown_key_message(table, k, _IN_OVERRIDE, merged, c, eos_kind))


def _parse_text(text: str, t) -> object:
    """Parse the right-hand side of an override for a key of type ``t``."""
    if "\n" in text or "\r" in text:
        raise ValueError("line breaks are not allowed")
    if t is str and not text.startswith(('"', "'")):
        return text  # bare strings need no quotes: scheme.method=sph_ale
    if t is bool and text.lower() in ("true", "false"):
        return text.lower() == "true"
    try:
        doc = tomllib.loads(f"v = {text}")
    except tomllib.TOMLDecodeError:
        if t is float:
            try:
                return float(text)  # Python float syntax too: ".5", "5."
            except ValueError:
                raise ValueError("not a number") from None
        raise ValueError("not a valid TOML value") from None
    if set(doc) != {"v"}:
        raise ValueError("not a single TOML value")
    return doc["v"]


def parse_override(s: str, *, case: str | None = None,
                   eos_kind: str | None = None) -> tuple[str, object]:
    """Parse a ``KEY=VALUE`` override into ``(dotted_key, typed_value)``.

    The value is typed by the key's schema: TOML syntax (``1``, ``1e-5``, ``true``,
    ``[0.0, 1.0]``, ``{rho = 1.0, u = 0.0}``); a string key also takes a bare word
    (``scheme.method=sph_ale``).  ``TABLE.KEY.SUB=VALUE`` sets one entry of a table-valued key
    (``case.left.rho=1100``).  ``case``/``eos_kind`` select the case and EOS schemas (without
    them every registered case / EOS kind is searched).  The value is validated (type and
    range); errors are :class:`ConfigError`.
    """
    if not isinstance(s, str) or "=" not in s:
        raise ConfigError(f"invalid override {s!r}; allowed: KEY=VALUE, e.g. scheme.degree=1")
    dotted, _, text = s.partition("=")
    dotted, text = dotted.strip(), text.strip()
    key, sub = _lookup_key(dotted, case, eos_kind)
    types = (key.item_type,) if sub is not None else key.types
    value, err = None, None
    for t in types:
        try:
            value = _parse_text(text, t)
            break
        except ValueError as e:
            err = e
    else:
        raise ConfigError(f"invalid override {dotted}={text!r}: {err}; allowed: {key.allowed()}")
    if sub is not None:
        return dotted, key.check_item(dotted, value)
    return dotted, key.check(dotted, value)


def _apply_overrides(raw: dict, overrides: Sequence[str], case: str | None) -> dict:
    if isinstance(overrides, str):
        raise ConfigError(f"invalid overrides={overrides!r}; allowed: a sequence of KEY=VALUE "
                          "strings")
    pre: dict[str, str] = {}
    for s in overrides:  # case.name and eos.kind first: they select the schemas
        if isinstance(s, str) and "=" in s:
            k, _, v = s.partition("=")
            if k.strip() in ("case.name", "eos.kind"):
                pre[k.strip()] = parse_override(s)[1]
    name = pre.get("case.name", _get(raw, "case", "name"))
    if case is not None:
        if name is not None and name != case:
            raise ConfigError(f"invalid case.name={_show(name)}: case={case!r} was requested; "
                              f"allowed: {case!r}")
        name = case
    if name is None:
        raise ConfigError("missing required key case.name; allowed: one of "
                          f"{', '.join(_registered_cases()) or '(none registered)'}")
    schema = _case_schema(name)
    raw.setdefault("case", {})
    if not isinstance(raw["case"], dict):
        raise ConfigError(f"invalid case={_show(raw['case'])}: expected a table [case]")
    raw["case"]["name"] = name
    kind = pre.get("eos.kind", _get(raw, "eos", "kind"))
    if kind is None:
        kind = schema.defaults_override.get("eos.kind", EOS_KIND.default)
    if kind not in EOS_SCHEMAS:
        EOS_KIND.check("eos.kind", kind)  # raises with the allowed kinds
    for s in overrides:
        dotted, value = parse_override(s, case=name, eos_kind=kind)
        parts = dotted.split(".")
        node = raw
        for p in parts[:-1]:
            child = node.setdefault(p, {})
            if not isinstance(child, dict):
                raise ConfigError(f"cannot apply override {s!r}: {'.'.join(parts[:-1])} is "
                                  f"{_show(child)}, not a table")
            node = child
        node[parts[-1]] = value
    return raw


def _get(raw: Mapping, table: str, key: str):
    t = raw.get(table)
    return t.get(key) if isinstance(t, Mapping) else None


def loads(text: str, overrides: Sequence[str] = (), case: str | None = None,
          source: str = "<string>") -> dict:
    """Like :func:`load`, for TOML text."""
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{source}: invalid TOML: {e}") from None
    return validate(_apply_overrides(raw, overrides, case))


def load(path: str | Path | None, overrides: Sequence[str] = (), case: str | None = None) -> dict:
    """Read, override, fill and validate a config; return the resolved nested dict.

    ``path=None`` builds the config from the defaults of ``case`` (required keys must then
    come from ``overrides``).  ``overrides`` are ``KEY=VALUE`` strings (see
    :func:`parse_override`), applied after the file is read and before validation; they may
    add keys absent from the file, never unknown keys.  If ``case`` is given and the file names
    another case, that is an error.
    """
    if path is None:
        if case is None and not any(isinstance(s, str) and s.split("=", 1)[0].strip() == "case.name"
                                    for s in overrides):
            raise ConfigError("invalid path=None: without a config file a case is needed; "
                              f"allowed: case= one of {', '.join(_registered_cases())}")
        return validate(_apply_overrides({}, overrides, case))
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"config file {str(p)!r} not found") from None
    except (IsADirectoryError, UnicodeDecodeError) as e:
        raise ConfigError(f"config file {str(p)!r} unreadable: {e}") from None
    return loads(text, overrides, case, source=str(p))


# --------------------------------------------------------------------------------------------
# TOML writer
# --------------------------------------------------------------------------------------------

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")
_ESCAPES = {'"': '\\"', "\\": "\\\\", "\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f",
            "\r": "\\r"}


def _toml_str(s: str) -> str:
    out = []
    for ch in s:
        if ch in _ESCAPES:
            out.append(_ESCAPES[ch])
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04X}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def _toml_key(k) -> str:
    if not isinstance(k, str):
        raise ConfigError(f"cannot write key {k!r} to TOML; allowed: string keys")
    return k if _BARE_KEY.fullmatch(k) else _toml_str(k)


def _toml_value(v, where: str = "value") -> str:
    if isinstance(v, bool | np.bool_):
        return "true" if v else "false"
    if isinstance(v, int | np.integer):
        i = int(v)
        if not -(2**63) <= i < 2**63:
            raise ConfigError(f"cannot write {where}={i}: TOML integers are 64-bit")
        return str(i)
    if isinstance(v, float | np.floating):
        f = float(v)
        if not math.isfinite(f):
            raise ConfigError(f"cannot write {where}={f}: numbers must be finite")
        return repr(f)  # shortest round-trip form: '0.3', '1e-14', '1.5e+300' are all TOML
    if isinstance(v, str):
        return _toml_str(v)
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x, f"{where}[{i}]") for i, x in enumerate(v)) + "]"
    if isinstance(v, Mapping):
        return "{" + ", ".join(f"{_toml_key(k)} = {_toml_value(x, f'{where}.{k}')}"
                               for k, x in v.items()) + "}"
    raise ConfigError(f"cannot write {where}={v!r} to TOML; allowed: str, int, float, bool, "
                      "lists and tables")


def _has_subtables(d: Mapping) -> bool:
    return any(isinstance(v, Mapping) and any(isinstance(x, Mapping) for x in v.values())
               for v in d.values())


def _dump_table(lines: list[str], path: list[str], table: Mapping) -> None:
    """Write ``table``: plain keys (scalars, lists, inline tables of non-tables), then
    sub-tables that themselves contain tables as ``[a.b]`` sections."""
    subs = []
    body = []
    for k, v in table.items():
        if isinstance(v, Mapping) and (not path or any(isinstance(x, Mapping) for x in v.values())):
            subs.append((k, v))
        else:
            body.append(f"{_toml_key(k)} = {_toml_value(v, '.'.join([*path, str(k)]))}")
    if path and (body or not subs):
        lines.append(f"[{'.'.join(_toml_key(p) for p in path)}]")
    lines.extend(body)
    if body:
        lines.append("")
    for k, v in subs:
        _dump_table(lines, [*path, k], v)


def dumps(cfg: Mapping) -> str:
    """TOML text of a (resolved) config; ``load`` of the text gives back ``cfg``.

    Writes str, int, float (shortest round-trip form; inf/nan are refused), bool, lists, inline
    tables of scalars and nested tables.
    """
    if not isinstance(cfg, Mapping):
        raise ConfigError(f"invalid cfg of type {type(cfg).__name__}; allowed: a dict")
    lines: list[str] = []
    _dump_table(lines, [], cfg)
    while lines and lines[-1] == "":
        lines.pop()
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------------------------
# Reference documentation
# --------------------------------------------------------------------------------------------


def _md(s: str) -> str:
    return s.replace("|", "\\|")


def _key_rows(table: str, schema: Mapping[str, Key]) -> list[str]:
    rows = ["| Key | Type | Default | Allowed | Description |", "|---|---|---|---|---|"]
    for k, key in schema.items():
        dotted = f"{table}.{k}"
        if key.required:
            default = "**required**"
        else:
            default = f"`{_toml_value(key.default)}`"
        doc = key.doc + (f" [{key.unit}]" if key.unit else "")
        rows.append(f"| `{dotted}` | {_md(key.type_name())} | {_md(default)} | "
                    f"{_md(key.allowed())} | {_md(doc)} |")
    return rows


def config_reference_markdown() -> str:
    """Markdown reference of every config key (table, key, type, default, allowed values,
    doc), per EOS kind and per registered case; the source of ``docs/config.md``."""
    cases = _registered_cases()
    out = [
        "# Configuration reference",
        "",
        "<!-- Generated by `python -m mlsph_jax.config > docs/config.md`; do not edit by hand. -->",
        "",
        "A config is a TOML file with the tables " + ", ".join(f"`[{t}]`" for t in TABLES)
        + ". `[case].name` selects the case and `[eos].kind` the equation of state; both decide "
        "which other keys their table accepts. Every key not given takes its default; keys "
        "marked **required** must be given.",
        "",
        "Rules:",
        "",
        "* Unknown tables or keys, wrong types and out-of-range values are errors that name the "
        "key, the value and what is allowed.",
        "* An integer is accepted for a float key (`1` means `1.0`); a float is never accepted "
        "for an int key; `true`/`false` are not numbers; numbers must be finite (no `inf`, "
        "`nan`).",
        "* Overrides `--set TABLE.KEY=VALUE` are applied after the file is read and before "
        "validation. VALUE is TOML (`1`, `1e-5`, `true`, `[0.0, -9.81]`, `{rho = 1.0, u = 0.0}`); "
        "string keys also take a bare word (`scheme.method=sph_ale`); "
        "`TABLE.KEY.SUB=VALUE` sets one entry of an inline table (`case.left.rho=1100`).",
        "* A case may change the defaults of other tables; they are listed with the case.",
        "",
    ]
    for table in ("scheme", "time", "output", "physics"):
        out += [f"## `[{table}]`", "", TABLE_DOCS[table], "",
                *_key_rows(table, SCHEMA_COMMON[table]), ""]
    out += ["## `[eos]`", "", TABLE_DOCS["eos"], "", *_key_rows("eos", {"kind": EOS_KIND}), ""]
    for kind, schema in EOS_SCHEMAS.items():
        out += [f"### `eos.kind = \"{kind}\"`", "", *_key_rows("eos", schema), ""]
    out += ["## `[case]`", "", TABLE_DOCS["case"], "",
            "Registered cases: " + (", ".join(f"`{c}`" for c in cases) or "none") + ".", ""]
    for name in cases:
        cs = CASE_SCHEMAS.get(name)
        out += [f"### `case.name = \"{name}\"`", ""]
        if cs.doc:
            out += [cs.doc, ""]
        if cs.dim is not None:
            out += [f"Space dimension: {cs.dim}.", ""]
        out += [*_key_rows("case", cs.table()), ""]
        if cs.defaults_override:
            out += ["Defaults changed by this case:", ""]
            out += [f"* `{k} = {_toml_value(v)}`" for k, v in cs.defaults_override.items()]
            out += [""]
        if cs.check is not None and cs.check.__doc__:
            out += ["Cross-checks: " + " ".join(cs.check.__doc__.split()), ""]
    return "\n".join(out).rstrip() + "\n"


# --------------------------------------------------------------------------------------------
# Built-in case schemas
# --------------------------------------------------------------------------------------------

_STATE_KEYS = ("rho", "u", "p")


def check_riemann_1d(cfg: dict) -> None:
    """`left`/`right` hold `rho` > 0 and `u`, plus `p` for the ideal_gas (p > 0) and
    stiffened_gas (p + pc > 0) EOS; for the barotropic tait EOS `p` must be absent (the
    pressure follows from rho). `domain` = [a, b] with a < b and a < `x_interface` < b."""
    c, eos = cfg["case"], cfg["eos"]
    kind = eos["kind"]
    problems = []
    for side in ("left", "right"):
        st = c[side]
        for k in st:
            if k not in _STATE_KEYS:
                s = _suggest(k, _STATE_KEYS)
                problems.append(f"unknown key case.{side}.{k} (value {_show(st[k])})"
                                + (f"; did you mean case.{side}.{s}?" if s else "")
                                + f"; valid keys: {', '.join(_STATE_KEYS)}")
        for k in ("rho", "u"):
            if k not in st:
                problems.append(f"missing required key case.{side}.{k}; allowed: a float")
        if "rho" in st and st["rho"] <= 0:
            problems.append(f"invalid case.{side}.rho={_show(st['rho'])}: out of range; "
                            "allowed: float > 0")
        if kind == "tait":
            if "p" in st:
                problems.append(f"invalid case.{side}.p={_show(st['p'])}: the pressure follows "
                                "from rho for the barotropic Tait EOS; allowed: no p "
                                "(remove it, or choose another eos.kind)")
        elif "p" not in st:
            problems.append(f"missing required key case.{side}.p: eos.kind = {kind!r} has an "
                            "energy equation and needs the pressure; allowed: a float")
        elif kind == "ideal_gas" and st["p"] <= 0:
            problems.append(f"invalid case.{side}.p={_show(st['p'])}: out of range; "
                            "allowed: float > 0 for the ideal gas")
        elif kind == "stiffened_gas" and st["p"] + eos["pc"] <= 0:
            problems.append(f"invalid case.{side}.p={_show(st['p'])}: out of range; "
                            f"allowed: p > -pc = {_show(-eos['pc'])} for the stiffened gas")
    a, b = c["domain"]
    if not a < b:
        problems.append(f"invalid case.domain={_show(c['domain'])}: out of order; "
                        "allowed: [a, b] with a < b")
    elif not a < c["x_interface"] < b:
        problems.append(f"invalid case.x_interface={_show(c['x_interface'])}: outside the domain; "
                        f"allowed: a float in ({_show(a)}, {_show(b)})")
    if problems:
        raise ConfigError(_join(problems))


_STATE_NOTE = "keys rho, u and p; no p when eos.kind = tait"

RIEMANN_1D_KEYS: dict[str, Key] = {
    "left": Key(dict, item_type=float, note=_STATE_NOTE,
                doc="state left of the interface: {rho = ..., u = ..., p = ...}"),
    "right": Key(dict, item_type=float, note=_STATE_NOTE,
                 doc="state right of the interface: {rho = ..., u = ..., p = ...}"),
    "x_interface": Key(float, unit="m", doc="position of the initial discontinuity"),
    "domain": Key(list, item_type=float, length=2, unit="m", doc="tube ends [a, b]"),
    "n": Key(int, minimum=10, doc="number of fluid particles in the tube"),
}

RIEMANN_1D = register_case_schema(
    "riemann_1d", RIEMANN_1D_KEYS, check=check_riemann_1d, dim=1,
    defaults_override={"scheme.frame": "lagrangian"},
    doc="One-dimensional Riemann problem (shock tube): two constant states separated by an "
        "interface at `x_interface`.")


BLAST_2D_LAYOUTS = ("rings", "delaunay", "perturbed")


def check_blast_2d(cfg: dict) -> None:
    """`eos.kind` must be tait (the radial reference solves the barotropic Tait equations).
    0 < `r_interface` < `radius`; `dx` <= `r_interface`/5 (at least five spacings across the
    high-density region); `perturbation` is used by the perturbed layout only. The far field
    beyond `radius` is frozen, so the waves must stay inside the disc: `r_interface` +
    s_max `time.t_end` < `radius`, with the signal-speed bound s_max = c_max (1 + ln(rho_max /
    rho_min)) (largest sound speed times one plus the largest possible |u*|/c_max of a Tait
    Riemann problem from rest)."""
    c, eos = cfg["case"], cfg["eos"]
    problems = []
    if eos["kind"] != "tait":
        problems.append(f"invalid eos.kind={_show(eos['kind'])}: case blast_2d compares with a "
                        "radial reference for the barotropic Tait EOS; allowed: \"tait\"")
    radius, r_if, dx = c["radius"], c["r_interface"], c["dx"]
    if not r_if < radius:
        problems.append(f"invalid case.r_interface={_show(r_if)}: outside the disc; allowed: a "
                        f"float in (0.0, case.radius={_show(radius)})")
    elif not dx <= r_if / 5.0:
        problems.append(f"invalid case.dx={_show(dx)}: too coarse; allowed: a float in "
                        f"(0.0, case.r_interface/5 = {_show(r_if / 5.0)}]")
    elif eos["kind"] == "tait":
        rho_max, rho_min = max(c["rho_in"], c["rho_out"]), min(c["rho_in"], c["rho_out"])
        c_max = eos["c0"] * (rho_max / eos["rho0"]) ** (0.5 * (eos["gamma"] - 1.0))
        s_max = c_max * (1.0 + math.log(rho_max / rho_min))
        t_end = cfg["time"]["t_end"]
        if r_if + s_max * t_end >= radius:
            problems.append(f"invalid time.t_end={_show(t_end)}: the waves may reach the frozen far "
                            f"field at case.radius={_show(radius)} (signal-speed bound "
                            f"{s_max:.6g} m/s); allowed: t_end < "
                            f"{_show((radius - r_if) / s_max)} s")
    if problems:
        raise ConfigError(_join(problems))


BLAST_2D_KEYS: dict[str, Key] = {
    "radius": Key(float, 0.1, minimum=0.0, exclusive_minimum=True, unit="m",
                  doc="radius R of the fluid disc (centred at the origin; frozen far field beyond)"),
    "r_interface": Key(float, 0.05, minimum=0.0, exclusive_minimum=True, unit="m",
                       doc="radius of the initial discontinuity"),
    "rho_in": Key(float, 1100.0, minimum=0.0, exclusive_minimum=True, unit="kg/m^3",
                  doc="density for r <= r_interface (fluid at rest)"),
    "rho_out": Key(float, 1000.0, minimum=0.0, exclusive_minimum=True, unit="kg/m^3",
                   doc="density for r > r_interface (fluid at rest)"),
    "layout": Key(str, "delaunay", choices=BLAST_2D_LAYOUTS,
                  doc="initial particles: concentric rings, Delaunay triangle barycentres, or "
                      "randomly perturbed Delaunay barycentres (thesis Fig. 3.5)"),
    "dx": Key(float, 2e-3, minimum=0.0, exclusive_minimum=True, unit="m",
              doc="particle spacing, N ~ pi R^2 / dx^2 (2e-3: ~7,800 particles, minutes on 2 "
                  "CPU cores); thesis resolution: 5.9e-4 (rings, ~90,000) and 6.5e-4 "
                  "(delaunay/perturbed, ~75,000)"),
    "perturbation": Key(float, 0.2, minimum=0.0, maximum=0.5,
                        doc="perturbed layout: random displacement of each particle within a "
                            "disc of radius perturbation * sqrt(V_i)"),
    "seed": Key(int, 0, minimum=0, doc="random seed of the delaunay and perturbed layouts"),
    "reference_cells": Key(int, 4000, minimum=100,
                           doc="cells of the 1-D radial finite-volume reference on [0, radius]"),
}

BLAST_2D = register_case_schema(
    "blast_2d", BLAST_2D_KEYS, check=check_blast_2d, dim=2,
    defaults_override={"scheme.frame": "lagrangian", "eos.kind": "tait", "eos.rho0": 1000.0,
                       "eos.c0": 1466.0, "time.t_end": 1e-5},
    doc="Two-dimensional blast explosion (cylindrical Tait shock tube, thesis §3.7.2): a disc "
        "of radius `radius` at rest, density `rho_in` inside `r_interface` and `rho_out` "
        "outside, compared with a 1-D radial finite-volume reference.")


TAYLOR_GREEN_2D_LAYOUTS = ("cartesian", "perturbed")


def check_taylor_green_2d(cfg: dict) -> None:
    """`eos.kind` must be tait (the initial density inverts the Tait law at the exact pressure).
    The viscosity follows from `re`: mu = eos.rho0 `u0` `length` / `re`; physics.mu must be left
    at 0 (it is then set to that value) or equal it (relative difference <= 1e-9).
    `physics.body_force` must be empty. The Tait law must be invertible at the lowest exact
    pressure -rho0 u0^2/2: eos.gamma u0^2 / (2 eos.c0^2) < 1 (Mach number u0/c0 below
    sqrt(2/gamma), 0.53 for gamma = 7)."""
    c, eos, phys = cfg["case"], cfg["eos"], cfg["physics"]
    problems = []
    if eos["kind"] != "tait":
        problems.append(f"invalid eos.kind={_show(eos['kind'])}: case taylor_green_2d sets the "
                        "initial density from the Tait law at the exact pressure; allowed: \"tait\"")
    else:
        mu = eos["rho0"] * c["u0"] * c["length"] / c["re"]
        if phys["mu"] != 0.0 and abs(phys["mu"] - mu) > 1e-9 * mu:
            problems.append(f"invalid physics.mu={_show(phys['mu'])}: case taylor_green_2d derives "
                            f"the viscosity from case.re={_show(c['re'])} (mu = eos.rho0 case.u0 "
                            f"case.length / case.re = {mu:.10g}); allowed: 0 (derived) or "
                            f"{mu:.10g} (set case.re instead)")
        if eos["gamma"] * c["u0"] ** 2 / (2.0 * eos["c0"] ** 2) >= 1.0:
            problems.append(f"invalid case.u0={_show(c['u0'])}: the Tait law cannot be inverted at "
                            f"the lowest exact pressure -rho0 u0^2/2 with eos.c0={_show(eos['c0'])}; "
                            f"allowed: u0 < c0 sqrt(2/gamma) = "
                            f"{eos['c0'] * math.sqrt(2.0 / eos['gamma']):.6g}")
    if phys["body_force"]:
        problems.append(f"invalid physics.body_force={_show(phys['body_force'])}: the Taylor-Green "
                        "vortex has no body force; allowed: []")
    if problems:
        raise ConfigError(_join(problems))


TAYLOR_GREEN_2D_KEYS: dict[str, Key] = {
    "n": Key(int, 50, minimum=8,
             doc="particles per side (n^2 in total, spacing length/n); thesis §3.7.3: 100, "
                 "§4.5.1: 50"),
    "length": Key(float, 1.0, minimum=0.0, exclusive_minimum=True, unit="m",
                  doc="side L of the periodic square [0, L]^2 (one period of the vortex pattern; "
                      "thesis §3.7.3: 1, §4.5.1: 2 pi)"),
    "u0": Key(float, 1.0, minimum=0.0, exclusive_minimum=True, unit="m/s",
              doc="velocity amplitude U0 of the exact solution"),
    "re": Key(float, 100.0, minimum=0.0, exclusive_minimum=True,
              doc="Reynolds number Re = rho0 U0 L / mu (sets physics.mu = rho0 U0 L / Re); the "
                  "kinetic energy decays as exp(-16 pi^2 t U0 / (Re L))"),
    "layout": Key(str, "cartesian", choices=TAYLOR_GREEN_2D_LAYOUTS,
                  doc="initial particles: Cartesian lattice (x = (i + 1/2) dx) or the lattice "
                      "with random displacements"),
    "perturbation": Key(float, 0.15, minimum=0.0, maximum=0.5, exclusive_maximum=True,
                        doc="perturbed layout: each coordinate is displaced by a uniform random "
                            "amount in [-perturbation dx, +perturbation dx] (volumes stay dx^2)"),
    "seed": Key(int, 0, minimum=0, doc="random seed of the perturbed layout"),
}

TAYLOR_GREEN_2D = register_case_schema(
    "taylor_green_2d", TAYLOR_GREEN_2D_KEYS, check=check_taylor_green_2d, dim=2,
    defaults_override={"eos.kind": "tait", "eos.rho0": 1.0, "eos.c0": 10.0, "time.t_end": 1.0},
    doc="Two-dimensional viscous Taylor-Green vortex (weakly compressible, Tait EOS, periodic "
        "square [0, `length`]^2; thesis §3.7.3 and §4.5.1), compared with the exact incompressible "
        "solution.")


CHANNEL_CASES = ("couette", "poiseuille")


def check_channel(cfg: dict) -> None:
    """`eos.kind` must be tait and physics.mu > 0 (the exact start-up solution has nu =
    physics.mu / eos.rho0). `physics.body_force` must be empty or [f_x, 0.0] (a force along the
    plates; a wall-normal force would need a hydrostatic wall treatment). The flow must be
    driven: `u_plate` != 0 or f_x != 0. The period `nx` dx must exceed the kernel support
    diameter 2 kappa beta dx (minimum-image neighbour search), i.e. `nx` > 2 kappa beta (6 for
    mlsph_ale with the cubic spline, 8 for sph_ale)."""
    from .kernels import get_kernel

    c, eos, phys = cfg["case"], cfg["eos"], cfg["physics"]
    name = c["name"]
    problems = []
    if eos["kind"] != "tait":
        problems.append(f"invalid eos.kind={_show(eos['kind'])}: case {name} compares with the "
                        "incompressible start-up solution for the weakly compressible Tait fluid; "
                        "allowed: \"tait\"")
    if not phys["mu"] > 0.0:
        problems.append(f"invalid physics.mu={_show(phys['mu'])}: case {name} is a viscous flow; "
                        "allowed: a float > 0 (nu = mu / eos.rho0; thesis: 0.1)")
    bf = phys["body_force"]
    fx = bf[0] if bf else 0.0
    if bf and bf[1] != 0.0:
        problems.append(f"invalid physics.body_force={_show(bf)}: case {name} takes a force along "
                        "the plates only; allowed: [] or [f_x, 0.0]")
    if c["u_plate"] == 0.0 and fx == 0.0:
        problems.append(f"invalid case.u_plate={_show(c['u_plate'])} with physics.body_force="
                        f"{_show(bf)}: nothing drives the flow; allowed: u_plate != 0 (Couette) "
                        "or physics.body_force = [f_x, 0.0] with f_x != 0 (Poiseuille)")
    reach = 2.0 * get_kernel(cfg["scheme"]["kernel"]).support * effective_beta(cfg["scheme"])
    if not c["nx"] > reach:
        problems.append(f"invalid case.nx={c['nx']}: the period nx dx must exceed the kernel "
                        f"support diameter {reach:g} dx; allowed: an int > {reach:g}")
    if problems:
        raise ConfigError(_join(problems))


def _channel_keys(u_plate: float) -> dict[str, Key]:
    return {
        "gap": Key(float, 1.0, minimum=0.0, exclusive_minimum=True, unit="m",
                   doc="distance L between the plates (walls at y = 0 and y = L); thesis: 1"),
        "ny": Key(int, 40, minimum=4,
                  doc="fluid particles across the gap (square lattice, spacing dx = gap/ny); "
                      "thesis: 40"),
        "nx": Key(int, 20, minimum=1,
                  doc="fluid particles along the plates (periodic length nx dx); thesis: 20 "
                      "(period L/2)"),
        "u_plate": Key(float, u_plate, unit="m/s",
                       doc="velocity of the top plate (y = L) along x, switched on at t = 0 "
                           "(the bottom plate is fixed); thesis Couette: 1"),
    }


COUETTE = register_case_schema(
    "couette", _channel_keys(1.0), check=check_channel, dim=2,
    defaults_override={"eos.kind": "tait", "eos.rho0": 1.0, "eos.c0": 10.0, "physics.mu": 0.1,
                       "time.t_end": 10.0, "output.snapshots": 20},
    doc="Start-up Couette flow (thesis §3.7.4): fluid at rest between two plates `gap` apart, "
        "the top plate impulsively set to `u_plate`; mirror-ghost walls, periodic along the "
        "plates, compared with the exact series solution (thesis eq. 3.20).")

POISEUILLE = register_case_schema(
    "poiseuille", _channel_keys(0.0), check=check_channel, dim=2,
    defaults_override={"eos.kind": "tait", "eos.rho0": 1.0, "eos.c0": 10.0, "physics.mu": 0.1,
                       "physics.body_force": [0.8, 0.0], "time.t_end": 10.0, "output.snapshots": 20},
    doc="Start-up Poiseuille flow (thesis §3.7.4): fluid at rest between two fixed plates "
        "`gap` apart driven by the body force `physics.body_force` = [f_x, 0] (peak velocity "
        "f_x L^2 / (8 nu)); mirror-ghost walls, periodic along the plates, compared with the "
        "exact series solution (thesis eq. 3.21 with its sign corrected, SPEC §13 item 35).")


def lid_driven_cavity_viscosity(cfg: Mapping) -> float:
    """Dynamic viscosity of a resolved ``lid_driven_cavity`` config: mu = rho0 u_lid length / re."""
    c = cfg["case"]
    return cfg["eos"]["rho0"] * c["u_lid"] * c["length"] / c["re"]


def check_lid_driven_cavity(cfg: dict) -> None:
    """`eos.kind` must be tait. The viscosity follows from `re`: mu = eos.rho0 `u_lid`
    `length` / `re`; physics.mu must be left at 0 (it is then set to that value) or equal it
    (relative difference <= 1e-9). `physics.body_force` must be empty. `scheme.frame` must be
    eulerian (the mirror ghosts are fixed at set-up, so the particles must not move)."""
    c, eos, phys = cfg["case"], cfg["eos"], cfg["physics"]
    problems = []
    if eos["kind"] != "tait":
        problems.append(f"invalid eos.kind={_show(eos['kind'])}: case lid_driven_cavity is a "
                        "weakly compressible Tait flow; allowed: \"tait\"")
    else:
        mu = lid_driven_cavity_viscosity(cfg)
        if phys["mu"] != 0.0 and abs(phys["mu"] - mu) > 1e-9 * mu:
            problems.append(f"invalid physics.mu={_show(phys['mu'])}: case lid_driven_cavity derives "
                            f"the viscosity from case.re={_show(c['re'])} (mu = eos.rho0 case.u_lid "
                            f"case.length / case.re = {mu:.10g}); allowed: 0 (derived) or "
                            f"{mu:.10g} — set case.re instead")
    if phys["body_force"]:
        problems.append(f"invalid physics.body_force={_show(phys['body_force'])}: the lid-driven "
                        "cavity has no body force; allowed: []")
    if cfg["scheme"]["frame"] != "eulerian":
        problems.append(f"invalid scheme.frame={_show(cfg['scheme']['frame'])}: the cavity's "
                        "mirror ghosts are fixed at set-up, so the particles must stay in place; "
                        "allowed: \"eulerian\"")
    if problems:
        raise ConfigError(_join(problems))


LID_DRIVEN_CAVITY_KEYS: dict[str, Key] = {
    "n": Key(int, 40, minimum=8,
             doc="fluid particles per side (n^2 in total, square lattice, spacing length/n); "
                 "thesis: 100"),
    "length": Key(float, 1.0, minimum=0.0, exclusive_minimum=True, unit="m",
                  doc="side L of the square cavity [0, L]^2"),
    "u_lid": Key(float, 1.0, minimum=0.0, exclusive_minimum=True, unit="m/s",
                 doc="velocity of the lid (top wall y = L) along +x; the other walls are fixed"),
    "re": Key(float, 100.0, minimum=0.0, exclusive_minimum=True,
              doc="Reynolds number Re = rho0 u_lid L / mu (sets physics.mu); Ghia et al. "
                  "(1982) centre-line data exist for 100, 400 and 1000"),
    "steady_tol": Key(float, 2e-3, minimum=0.0,
                      doc="stop early once max|u(t2) - u(t1)| / max|u| / (t2 - t1) between two "
                          "output times is below this (1/s; 0 = always run to time.t_end)"),
}

LID_DRIVEN_CAVITY = register_case_schema(
    "lid_driven_cavity", LID_DRIVEN_CAVITY_KEYS, check=check_lid_driven_cavity, dim=2,
    defaults_override={"eos.kind": "tait", "eos.rho0": 1.0, "eos.c0": 10.0, "time.t_end": 15.0,
                       "output.snapshots": 15},
    doc="Two-dimensional lid-driven cavity (thesis §3.7.5): fluid at rest in the square [0, "
        "`length`]^2, the lid moves at `u_lid`; mirror-ghost walls with corner ghosts, run to a "
        "steady state and compared with Ghia et al. (1982) along the centre lines.")


if __name__ == "__main__":  # pragma: no cover
    print(config_reference_markdown(), end="")
