"""The case registry: one :class:`Case` per ``case.name``, with its keys, checks and builder.

A case is registered by its module (or by a user's script) with :func:`register_case`; the
config (:mod:`mlsph_jax.config`) reads its ``[case]`` keys, per-case defaults, cross-check and
space dimension from here, ``build_problem`` calls its builder and ``mlsph cases`` lists its
doc.  A user's case::

    from mlsph_jax.cases import register_case
    from mlsph_jax.schema import Key

    register_case("my_case", {"n": Key(int, 100, minimum=10, doc="particles")}, build_my_case,
                  doc="My case (thesis §x.y): ...", dim=1)

and a TOML config naming ``case.name = "my_case"`` then loads and runs like a built-in one.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Callable, Mapping

from ..config import check_defaults_override
from ..config.resolve import check_particle_limit
from ..errors import InputError
from ..registry import Registry
from ..schema import Key

__all__ = ["CASES", "Case", "build_problem", "register_case"]


@dataclasses.dataclass(frozen=True)
class Case:
    """A registered case.

    ``name``: the ``case.name`` that selects it; ``doc``: one sentence for ``mlsph cases`` and
    docs/config.md; ``keys``: its own ``[case]`` keys (``name`` excluded); ``defaults_override``:
    per-case defaults of the other tables (dotted keys, checked at registration); ``check(cfg)``:
    cross-checks of the resolved config, raising :class:`~mlsph_jax.errors.ConfigError` (its
    docstring is shown in the reference); ``dim``: the space dimension (``None``: any);
    ``build(cfg) -> Problem``: the builder; ``particle_count(cfg) -> (estimate, keys)``: the
    number of particles ``build`` would make, from the config alone, and the config keys that
    set it, or None when it cannot tell (the ``run.max_particles`` guard; without an estimate the
    count is checked after building).
    """

    name: str
    build: Callable = dataclasses.field(repr=False)
    keys: Mapping[str, Key] = dataclasses.field(default_factory=dict, repr=False)
    check: Callable[[dict], None] | None = dataclasses.field(default=None, repr=False)
    defaults_override: Mapping[str, object] = dataclasses.field(default_factory=dict, repr=False)
    doc: str = ""
    dim: int | None = None
    particle_count: Callable[[dict], tuple[int, tuple[str, ...]]] | None = dataclasses.field(default=None,
                                                                                             repr=False)

    @property
    def description(self) -> str:
        """The doc line (what :meth:`Registry.describe` shows)."""
        return self.doc


#: The registered cases, by ``case.name``.
CASES: Registry[Case] = Registry("case.name", protocol=("build", "keys", "check", "doc", "defaults_override", "dim"),
                                 doc="test cases (thesis ch. 3 and 4), selected by case.name")


def register_case(name: str, keys: Mapping[str, Key], build: Callable, *, check: Callable[[dict], None] | None = None,
                  defaults_override: Mapping[str, object] | None = None, doc: str = "",
                  dim: int | None = None, particle_count: Callable | None = None, replace: bool = False) -> Case:
    """Register the case ``name`` and return its :class:`Case`.

    ``keys`` are the case's own ``[case]`` keys (``name`` is added by the config).
    ``defaults_override`` maps dotted keys of the other tables to per-case defaults, e.g.
    ``{"scheme.frame": "lagrangian", "eos.kind": "tait", "eos.rho0": 1000.0}`` (an ``eos``
    default applies only when the resolved ``eos.kind`` has that key).  ``check(cfg)`` receives
    the resolved, type-checked config and raises :class:`~mlsph_jax.errors.ConfigError` for
    cross-key problems.  ``dim`` (1, 2 or 3) fixes the space dimension: ``physics.body_force``
    must then be empty or have ``dim`` components.  ``build(cfg)`` returns the
    :class:`~mlsph_jax.simulation.Problem` of a resolved config.  ``particle_count(cfg) ->
    (estimate, keys)``: the number of particles (fluid, walls, far field) ``build`` would make,
    computed from the resolved config without building them, and the config keys that set it (or
    None when it cannot tell): a config whose estimate exceeds ``run.max_particles`` is refused before anything is built
    (without it, the built problem's count is checked).  ``replace=True`` replaces a case
    registered under the same name (a notebook cell run again).

    Raises :class:`~mlsph_jax.errors.InputError` for a bad name, a taken name (naming the
    registered ones; see ``replace``), a key that is not a :class:`Key` or an unknown ``defaults_override`` key,
    and :class:`~mlsph_jax.errors.ConfigError` for a bad ``defaults_override`` value.
    """
    if not isinstance(name, str) or not re.fullmatch(r"[a-z][a-z0-9_]*", name):
        raise InputError(f"invalid case.name {name!r}; allowed: lower-case letters, digits and '_', starting with a "
                         "letter")
    if name in CASES and not replace:
        raise InputError(f"case.name {name!r} is registered already (registered: {', '.join(CASES.names())}); "
                         "choose another name")
    if not callable(build):
        raise InputError(f"case {name!r}: build={build!r}; allowed: a function build(cfg) -> Problem")
    if check is not None and not callable(check):
        raise InputError(f"case {name!r}: check={check!r}; allowed: None or a function check(cfg)")
    keys = dict(keys)
    if "name" in keys:
        raise InputError(f"case {name!r}: the key 'name' is added automatically; do not define it")
    for k, key in keys.items():
        if not isinstance(key, Key):
            raise InputError(f"case {name!r}: key {k!r} must be a Key, got {type(key).__name__}")
    if dim not in (None, 1, 2, 3):
        raise InputError(f"case {name!r}: dim={dim!r}; allowed: None, 1, 2, 3")
    if particle_count is not None and not callable(particle_count):
        raise InputError(f"case {name!r}: particle_count={particle_count!r}; allowed: None or a function "
                         "particle_count(cfg) -> (estimate, keys)")
    case = Case(name=name, build=build, keys=keys, check=check,
                defaults_override=check_defaults_override(name, defaults_override or {}), doc=doc, dim=dim,
                particle_count=particle_count)
    return CASES.register(name, case, replace=replace)


def build_problem(cfg: Mapping):
    """The :class:`~mlsph_jax.simulation.Problem` of a resolved, validated config.  The built
    particle count is held to ``run.max_particles`` once more (a case without ``particle_count``
    is checked only here; an estimate may be a little off)."""
    case = CASES.get(cfg["case"]["name"], "case.name")
    problem = case.build(cfg)
    estimate = None if case.particle_count is None else case.particle_count(cfg)
    keys = () if estimate is None else estimate[1]
    check_particle_limit(cfg, problem.particles.n, keys, estimated=False)
    return problem

