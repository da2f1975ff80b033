"""String-keyed registries of numerical components.

One registry per component kind (approximation, kernel, flux, reconstruction, limiter, frame,
boundary, EOS, case).  Configs and function arguments name components by string; an unknown
name raises an :class:`~mlsph_jax.errors.InputError` listing the valid names.  Adding a
component is one function plus one ``@REGISTRY.register("name")`` line.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Generic, TypeVar

from .errors import InputError

T = TypeVar("T")


class Registry(Generic[T]):
    """A named mapping from strings to components of one kind."""

    def __init__(self, kind: str):
        self.kind = kind
        self._items: dict[str, T] = {}

    def register(self, name: str) -> Callable[[T], T]:
        def deco(obj: T) -> T:
            if name in self._items:
                raise ValueError(f"{self.kind} {name!r} is registered twice")
            self._items[name] = obj
            return obj

        return deco

    def get(self, name: str, argument: str | None = None) -> T:
        try:
            return self._items[name]
        except (KeyError, TypeError):
            arg = argument or self.kind
            raise InputError(
                f"unknown {arg}={name!r}; allowed: {', '.join(sorted(self._items))}"
            ) from None

    def names(self) -> list[str]:
        return sorted(self._items)

    def __contains__(self, name: object) -> bool:
        return name in self._items

    def __iter__(self) -> Iterator[str]:
        return iter(sorted(self._items))
