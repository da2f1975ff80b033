"""Registries of numerical components: one per component kind, holding the objects that run.

A registry maps names to the components of one kind (a flux, an EOS, a frame, a case, ...).
It is the *only* list of names: the config schema's allowed values, :class:`~mlsph_jax.scheme.Scheme`
validation, ``mlsph cases`` and docs/config.md are read from it, and the numerics call the
registered object instead of comparing names.  Each registry has a *protocol*: the attributes
(usually methods) a component must have; registering an object without them is an error that
names the kind, the name and what is missing.

A user registers a component from their own script (no edit of the package) and names it in a
TOML config::

    from mlsph_jax.flux import FLUXES, RusanovFlux
    FLUXES.register("my_flux", MyFlux())          # or as a decorator: @FLUXES.register("my_flux")

Every registry is also indexed by its kind (its config key, e.g. ``"scheme.flux"``), so that
:func:`registry` finds it by name; :func:`all_registries` lists them (docs/extending.md).
"""

from __future__ import annotations

import difflib
from collections.abc import Callable, Iterator, Sequence
from typing import Any, Generic, TypeVar

from .errors import InputError

T = TypeVar("T")

_REGISTRIES: dict[str, Registry] = {}
_MISSING = object()


class Registry(Generic[T]):
    """Named components of one kind.

    ``kind``: the config key that names a component (``"scheme.flux"``) or a short label;
    ``protocol``: attribute names every component must have (checked at registration);
    ``doc``: one line for the documentation.
    """

    def __init__(self, kind: str, protocol: Sequence[str] = (), doc: str = ""):
        if kind in _REGISTRIES:
            raise InputError(f"a registry of kind {kind!r} exists already; one registry per component kind")
        self.kind = kind
        self.protocol = tuple(protocol)
        self.doc = doc
        self._items: dict[str, T] = {}
        _REGISTRIES[kind] = self

    def register(self, name: str, obj: Any = _MISSING, *, replace: bool = False):
        """Register ``obj`` under ``name``; without ``obj``, a decorator.

        Raises :class:`InputError` if the name is taken (unless ``replace``) or the object
        lacks a protocol attribute.  Returns the object (so it can decorate a class or function).
        """
        if obj is _MISSING:
            return lambda o: self.register(name, o, replace=replace)
        if not isinstance(name, str) or not name or not name.replace("_", "a").isalnum():
            raise InputError(f"invalid {self.kind} name {name!r}; allowed: a non-empty string of letters, digits "
                             "and '_'")
        if name in self._items and not replace:
            raise InputError(f"{self.kind} {name!r} is registered already (registered: {', '.join(self.names())}); "
                             "choose another name or pass replace=True")
        missing = [a for a in self.protocol if not hasattr(obj, a)]
        if missing:
            raise InputError(f"cannot register {self.kind} {name!r}: {type(obj).__name__} lacks "
                             f"{', '.join(missing)} (the {self.kind} protocol: {', '.join(self.protocol)})")
        self._items[name] = obj
        return obj

    def unregister(self, name: str) -> None:
        """Remove a component (tests and notebooks that register temporary ones)."""
        self.get(name)
        del self._items[name]

    def get(self, name: str, argument: str | None = None) -> T:
        """The component called ``name``; an unknown name raises :class:`InputError` naming the
        argument (default: the registry's kind), the value and the registered names."""
        try:
            return self._items[name]
        except (KeyError, TypeError):
            arg = argument or self.kind
            close = difflib.get_close_matches(name, self._items, n=1) if isinstance(name, str) else []
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise InputError(f"unknown {arg}={name!r}{hint}; allowed: {', '.join(self.names()) or '(none registered)'}"
                             ) from None

    def names(self) -> list[str]:
        """Registered names, sorted."""
        return sorted(self._items)

    def items(self) -> list[tuple[str, T]]:
        return [(k, self._items[k]) for k in self.names()]

    def describe(self, name: str) -> str:
        """First line of the component's ``description`` attribute or docstring."""
        obj = self.get(name)
        text = getattr(obj, "description", None) or getattr(obj, "__doc__", None) or ""
        return " ".join(text.strip().split("\n\n")[0].split())

    def __contains__(self, name: object) -> bool:
        return name in self._items

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def __len__(self) -> int:
        return len(self._items)

    def __repr__(self) -> str:
        return f"Registry({self.kind!r}: {', '.join(self.names())})"


def registry(kind: str) -> Registry:
    """The registry of ``kind`` (e.g. ``"scheme.flux"``), after importing the package's components."""
    _import_components()
    try:
        return _REGISTRIES[kind]
    except KeyError:
        raise InputError(f"unknown component kind {kind!r}; allowed: {', '.join(sorted(_REGISTRIES))}") from None


def all_registries() -> dict[str, Registry]:
    """Every registry by kind (after importing the package's components)."""
    _import_components()
    return dict(sorted(_REGISTRIES.items()))


def _import_components() -> None:
    import importlib

    for mod in ("scheme", "cases", "boundaries", "wall_integral", "geometry"):
        importlib.import_module(f"{__package__}.{mod}")


def names_of(kind: str) -> Callable[[], list[str]]:
    """A zero-argument function returning the current names of ``kind``'s registry (for schema
    keys whose allowed values must follow what is registered, including a user's components)."""
    return lambda: registry(kind).names()
