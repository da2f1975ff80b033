"""The config schema engine: typed keys, checking, override values, TOML text and Markdown rows.

Nothing here knows about cases, equations of state or the numerics: :mod:`mlsph_jax.config`
declares the tables with :class:`Key` and the case modules declare their ``[case]`` keys.

* :class:`Key` — one key: type, default (or :data:`REQUIRED`), allowed values (``choices``, a
  tuple or a zero-argument callable such as :func:`mlsph_jax.registry.names_of` resolved when a
  value is checked or the docs are written), range, unit, doc.  :meth:`Key.check` returns the
  value normalised or raises :class:`~mlsph_jax.errors.ConfigError` naming the dotted key, the
  value and what is allowed.
* :func:`suggest` — the "did you mean" of an unknown name; :func:`join_problems` — one message
  for several problems; :func:`show` — a value as it would be written in TOML.
* :func:`parse_value` — the typed value of the right-hand side of a ``--set KEY=VALUE``.
* :func:`dumps` — TOML text of a nested dict (via ``tomli_w``; reading is ``tomllib``).
* :func:`markdown_rows` — the Markdown table of a set of keys (docs/config.md).

Typing rules: an int is accepted for a float key (and converted to float); a float is never
accepted for an int key; bools are not numbers; every number must be finite.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import tomllib
from collections.abc import Callable, Mapping, Sequence

import numpy as np
import tomli_w

from .errors import ConfigError

__all__ = ["REQUIRED", "Key", "dumps", "join_problems", "markdown_rows", "parse_value", "show", "suggest",
           "toml_inline"]


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


#: Default of a key that must be given.
REQUIRED = _Required()

_TYPE_NAMES = {float: "float", int: "int", str: "str", bool: "bool", list: "list", dict: "table"}
_SCALARS = (float, int, str, bool)

#: Allowed values of a key: a tuple, or a zero-argument callable returning the names (a registry).
Choices = tuple | Callable[[], Sequence]


# --------------------------------------------------------------------------------------------
# Keys
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Key:
    """Schema of one config key.

    ``type`` is one of ``float, int, str, bool, list, dict`` (or a tuple of them: the first
    that accepts the value wins).  ``item_type`` is the scalar type of the items of a list or
    the values of a dict (inline table); ``length`` fixes the length of a list; ``item_length``
    makes every item of a list itself a list of that many ``item_type`` values (points
    ``[[x, y], ...]``).  ``choices``
    (a tuple, or a zero-argument callable returning the allowed names, e.g.
    ``names_of("scheme.flux")``, called each time a value is checked or the docs are written),
    ``minimum`` and ``maximum`` (inclusive unless ``exclusive_minimum``/``exclusive_maximum``)
    apply to a scalar value or to every item of a list/dict.  ``note`` is extra text appended
    to the "allowed" description (e.g. "0 = method default").

    A default is checked when the key is made, except against callable choices (a registry may
    still be filling up at import time): those defaults are checked by the test suite.
    """

    type: type | tuple
    default: object = REQUIRED
    doc: str = ""
    choices: Choices | None = None
    minimum: float | None = None
    maximum: float | None = None
    exclusive_minimum: bool = False
    exclusive_maximum: bool = False
    item_type: type | None = None
    length: int | None = None
    item_length: int | None = None
    unit: str = ""
    note: str = ""

    def __post_init__(self):
        for t in self.types:
            if t not in _TYPE_NAMES:
                raise TypeError(f"Key type {t!r} is not one of {sorted(_TYPE_NAMES.values())}")
        if self.item_type is not None and self.item_type not in _SCALARS:
            raise TypeError(f"Key item_type {self.item_type!r} is not a scalar type")
        if self.item_length is not None and (self.types != (list,) or self.item_type is None or self.item_length < 1):
            raise TypeError("Key item_length needs type list, an item_type and a length >= 1")
        if self.choices is not None and not callable(self.choices):
            object.__setattr__(self, "choices", tuple(self.choices))
        if self.default is not REQUIRED:  # a schema with a bad default is a bug
            self._check("<default>", self.default, None if self.registered else self.choices)

    @property
    def types(self) -> tuple:
        return self.type if isinstance(self.type, tuple) else (self.type,)

    @property
    def required(self) -> bool:
        return self.default is REQUIRED

    @property
    def registered(self) -> bool:
        """Whether the allowed values come from a callable (a registry) rather than a fixed tuple."""
        return callable(self.choices)

    def choice_names(self) -> tuple | None:
        """The allowed values now (a callable ``choices`` is called), or ``None`` if any value goes."""
        if self.choices is None:
            return None
        return tuple(self.choices()) if callable(self.choices) else self.choices

    def type_name(self) -> str:
        names = []
        for t in self.types:
            if t in (list, dict) and self.item_type is not None:
                kind = "list" if t is list else "table"
                n = f" (length {self.length})" if t is list and self.length is not None else ""
                item = _TYPE_NAMES[self.item_type]
                if t is list and self.item_length is not None:
                    item = f"[{', '.join([item] * self.item_length)}]"
                names.append(f"{kind} of {item}{n}")
            else:
                names.append(_TYPE_NAMES[t])
        return " or ".join(names)

    def allowed(self, names: tuple | None = None) -> str:
        """Human-readable description of the allowed values (``names``: the resolved choices)."""
        names = self.choice_names() if names is None else names
        if names is not None:
            text = "one of " + (", ".join(toml_inline(c) for c in names) or "(none registered)")
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
        return self._check(dotted, value, self.choice_names())

    def check_item(self, dotted: str, value):
        """Check one item of a list/dict key (used for ``case.left.rho=...`` overrides)."""
        t = self.item_type
        if t is None:
            raise ConfigError(f"invalid {dotted}: {dotted.rsplit('.', 1)[0]} has no typed items")
        names = self.choice_names()
        ok, out, why = self._scalar(t, value)
        if ok:
            why = self._range_error(out, names)
            if why is None:
                return out
        raise ConfigError(f"invalid {dotted}={show(value)}: {why}; allowed: {self.allowed(names)}")

    def _check(self, dotted: str, value, names: tuple | None):
        reason = None
        for t in self.types:
            ok, out, why = self._check_as(t, value, names)
            if ok:
                return out
            reason = reason or why
        raise ConfigError(f"invalid {dotted}={show(value)}: {reason}; allowed: {self.allowed(names)}")

    def _check_as(self, t, value, names):
        if t in _SCALARS:
            ok, out, why = self._scalar(t, value)
            if not ok:
                return False, None, why
            why = self._range_error(out, names)
            return why is None, out, why
        if t is list:
            if not isinstance(value, list | tuple):
                return False, None, f"expected {self.type_name()}, got {_kind(value)}"
            if self.length is not None and len(value) != self.length:
                return False, None, f"expected {self.length} items, got {len(value)}"
            out = []
            for i, v in enumerate(value):
                ok, o, why = self._item(v, names)
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
            ok, o, why = self._item(v, names)
            if not ok:
                return False, None, f"entry {k!r}: {why}"
            out[k] = o
        return True, out, None

    def _item(self, v, names):
        if self.item_length is not None:
            if not isinstance(v, list | tuple) or len(v) != self.item_length:
                return False, None, f"expected a list of {self.item_length} numbers, got {show(v)}"
            out = []
            for x in v:
                ok, o, why = self._scalar(self.item_type, x)
                if ok:
                    why = self._range_error(o, names)
                if why is not None:
                    return False, None, why
                out.append(o)
            return True, out, None
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
            why = self._range_error(o, names)
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

    def _range_error(self, v, names) -> str | None:
        if names is not None and v not in names:
            close = suggest(v, names) if isinstance(v, str) else ""
            hint = f" (did you mean {toml_inline(close)}?)" if close else ""
            return ("not a registered name" if self.registered else "not an allowed choice") + hint
        if isinstance(v, int | float) and not isinstance(v, bool):
            lo, hi = self.minimum, self.maximum
            if lo is not None and (v < lo or (self.exclusive_minimum and v == lo)):
                return "out of range"
            if hi is not None and (v > hi or (self.exclusive_maximum and v == hi)):
                return "out of range"
        return None


# --------------------------------------------------------------------------------------------
# Messages
# --------------------------------------------------------------------------------------------


def suggest(word: str, options) -> str:
    """The closest of ``options`` to ``word`` ("did you mean"), or ``""``."""
    m = difflib.get_close_matches(word, [str(o) for o in options], n=1, cutoff=0.6)
    return m[0] if m else ""


def join_problems(problems: Sequence[str]) -> str:
    """One error message for one or several problems."""
    if len(problems) == 1:
        return problems[0]
    return f"{len(problems)} problems in the config:\n" + "\n".join(f"  - {p}" for p in problems)


def show(v) -> str:
    """``v`` as written in TOML (``inf``/``nan`` included), or its ``repr`` if TOML cannot write it."""
    try:
        return toml_inline(v)
    except TypeError:
        return repr(v)


def _num(x) -> str:
    return toml_inline(x) if isinstance(x, int | float) else str(x)


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


# --------------------------------------------------------------------------------------------
# Override values
# --------------------------------------------------------------------------------------------


def parse_value(text: str, t) -> object:
    """Parse the right-hand side of an override for a key of type ``t`` (raises ``ValueError``).

    TOML syntax (``1``, ``1e-5``, ``true``, ``[0.0, 1.0]``, ``{rho = 1.0}``); a str key also takes
    a bare word, a bool key ``True``/``False``, a float key Python's ``.5`` and ``5.``.
    """
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
                return float(text)
            except ValueError:
                raise ValueError("not a number") from None
        raise ValueError("not a valid TOML value") from None
    if set(doc) != {"v"}:
        raise ValueError("not a single TOML value")
    return doc["v"]


# --------------------------------------------------------------------------------------------
# TOML text
# --------------------------------------------------------------------------------------------


def _plain(v, where: str):
    """``v`` with numpy scalars turned into Python ones; refuses what TOML cannot hold."""
    if isinstance(v, bool | np.bool_):
        return bool(v)
    if isinstance(v, int | np.integer):
        i = int(v)
        if not -(2**63) <= i < 2**63:
            raise ConfigError(f"cannot write {where}={i}: TOML integers are 64-bit")
        return i
    if isinstance(v, float | np.floating):
        f = float(v)
        if not math.isfinite(f):
            raise ConfigError(f"cannot write {where}={f}: numbers must be finite")
        return f
    if isinstance(v, str):
        return v
    if isinstance(v, list | tuple):
        return [_plain(x, f"{where}[{i}]") for i, x in enumerate(v)]
    if isinstance(v, Mapping):
        for k in v:
            if not isinstance(k, str):
                raise ConfigError(f"cannot write key {k!r} of {where} to TOML; allowed: string keys")
        return {k: _plain(x, f"{where}.{k}" if where else k) for k, x in v.items()}
    raise ConfigError(f"cannot write {where}={v!r} to TOML; allowed: str, int, float, bool, lists and tables")


def dumps(doc: Mapping) -> str:
    """TOML text of a nested dict (``tomllib.loads`` of the text gives back ``doc``).

    Writes str, int, float, bool, lists and tables; numpy scalars are written as Python ones;
    inf/nan, integers beyond 64 bits and other types raise :class:`ConfigError` naming the key.
    """
    if not isinstance(doc, Mapping):
        raise ConfigError(f"invalid cfg of type {type(doc).__name__}; allowed: a dict")
    return tomli_w.dumps(_plain(doc, ""))


def toml_inline(v) -> str:
    """One value as single-line TOML (inline tables and arrays; ``inf``/``nan`` allowed), for
    messages and docs.  Raises ``TypeError`` for what TOML cannot hold."""
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, list | tuple):
        return "[" + ", ".join(toml_inline(x) for x in v) + "]"
    if isinstance(v, Mapping):
        return "{" + ", ".join(f"{toml_inline_key(k)} = {toml_inline(x)}" for k, x in v.items()) + "}"
    return tomli_w.dumps({"v": v})[len("v = "):-1]


def toml_inline_key(k) -> str:
    """A key as written in TOML (bare if possible, quoted otherwise)."""
    if not isinstance(k, str):
        raise TypeError(f"TOML keys are strings, got {k!r}")
    return tomli_w.dumps({k: 0})[:-len(" = 0\n")]


# --------------------------------------------------------------------------------------------
# Markdown reference
# --------------------------------------------------------------------------------------------


def _md(s: str) -> str:
    return s.replace("|", "\\|")


def markdown_rows(table: str, keys: Mapping[str, Key]) -> list[str]:
    """Markdown table of ``keys`` of ``[table]``: key, type, default, allowed values, doc [unit]."""
    rows = ["| Key | Type | Default | Allowed | Description |", "|---|---|---|---|---|"]
    for k, key in keys.items():
        default = "**required**" if key.required else f"`{toml_inline(key.default)}`"
        doc = key.doc + (f" [{key.unit}]" if key.unit else "")
        rows.append(f"| `{table}.{k}` | {_md(key.type_name())} | {_md(default)} | "
                    f"{_md(key.allowed())} | {_md(doc)} |")
    return rows
