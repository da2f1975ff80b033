"""Reading a config: ``--set`` overrides, validation and defaults, giving the resolved nested dict.

The schema of a config depends on two selector keys: ``case.name`` (a case registered in
:data:`mlsph_jax.cases.CASES`, which brings its own ``[case]`` keys, per-case defaults of the
other tables, a cross-check and its space dimension) and ``eos.kind`` (the ``[eos]`` keys of
:func:`~mlsph_jax.config.tables.eos_keys`).  Cases are found through the registry by kind
(``registry("case.name")``), which imports the built-in case modules on first use.
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path

from ..errors import ConfigError, InputError
from ..registry import registry
from ..schema import Key, join_problems, parse_value, show, suggest
from .tables import (
    CASE_NAME,
    EOS_KIND,
    LOCAL_TIME_STEPPING_ALLOWED,
    SCHEMA_COMMON,
    TABLES,
    all_eos_keys,
    eos_keys,
    local_time_stepping_conflict,
    series_allowed,
    series_per_output,
)

__all__ = ["case_table", "check_defaults_override", "check_particle_limit", "get_case", "load", "loads",
           "parse_override", "registered_cases", "validate"]


# --------------------------------------------------------------------------------------------
# Cases and table schemas
# --------------------------------------------------------------------------------------------


def registered_cases() -> list[str]:
    """Names of the registered cases (the built-in ones are imported on first use)."""
    return registry("case.name").names()


def get_case(name):
    """The registered case ``name``; otherwise :class:`ConfigError` naming case.name, the value
    and the registered cases."""
    CASE_NAME.check("case.name", name)
    return registry("case.name").get(name)


def case_table(case) -> dict[str, Key]:
    """The full ``[case]`` schema of a registered case: ``name`` first, then the case's keys."""
    return {"name": CASE_NAME, **case.keys}


def _table_schema(table: str, case, eos_kind: str | None) -> dict[str, Key]:
    if table == "case":
        return {"name": CASE_NAME} if case is None else case_table(case)
    if table == "eos":
        return {"kind": EOS_KIND, **(eos_keys(eos_kind) if eos_kind is not None else {})}
    return SCHEMA_COMMON[table]


def check_defaults_override(case_name: str, defaults: Mapping[str, object]) -> dict[str, object]:
    """Check the per-case defaults of a case being registered and return them normalised.

    ``defaults`` maps dotted keys of the tables other than ``[case]`` to values, e.g.
    ``{"scheme.frame": "lagrangian", "eos.kind": "tait", "eos.rho0": 1000.0}`` (an ``eos``
    default applies only when the resolved ``eos.kind`` has that key).  An unknown key is an
    :class:`InputError`, a bad value a :class:`ConfigError`.
    """
    out = {}
    for dotted, value in dict(defaults).items():
        table, _, k = dotted.partition(".")
        if table == "eos":
            cands = [EOS_KIND] if k == "kind" else [s[k] for s in all_eos_keys().values() if k in s]
        elif table in SCHEMA_COMMON:
            cands = [SCHEMA_COMMON[table][k]] if k in SCHEMA_COMMON[table] else []
        else:
            raise InputError(f"case {case_name!r}: defaults_override key {dotted!r} must be in one of the tables "
                             f"{', '.join(t for t in TABLES if t != 'case')}")
        if not cands:
            raise InputError(f"case {case_name!r}: defaults_override names the unknown key {dotted!r}")
        out[dotted] = cands[0].check(dotted, value)
    return out


_IN_OVERRIDE = object()


def _unknown_key_message(table: str, key: str, value, schema: Mapping[str, Key], case,
                         eos_kind: str | None) -> str:
    given = "in override" if value is _IN_OVERRIDE else f"value {show(value)}"
    msg = f"unknown key {table}.{key} ({given})"
    s = suggest(key, schema)
    if s:
        msg += f"; did you mean {table}.{s}?"
    if table == "eos":
        others = [k for k, sch in all_eos_keys().items() if key in sch and k != eos_kind]
        if others:
            msg += f" ({table}.{key} belongs to eos.kind = {', '.join(map(repr, others))})"
        where = f"[eos] with kind = {eos_kind!r}"
    elif table == "case" and case is not None:
        where = f"[case] of case {case.name!r}"
    else:
        where = f"[{table}]"
    return msg + f"; valid keys of {where}: {', '.join(schema)}"


def _all_keys(table: str) -> set[str]:
    if table == "eos":
        return {"kind", *(k for s in all_eos_keys().values() for k in s)}
    if table == "case":
        return {"name", *(k for _, c in registry("case.name").items() for k in c.keys)}
    return set(SCHEMA_COMMON[table])


def _eos_kind(kind) -> str:
    """A checked ``eos.kind`` (a registered EOS)."""
    return EOS_KIND.check("eos.kind", kind)


# --------------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------------


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
                problems.append(f"unknown top-level key {t} (value {show(v)}): keys belong in a "
                                f"table{hint}; valid tables: {', '.join(TABLES)}")
            else:
                s = suggest(t, TABLES)
                hint = f"; did you mean [{s}]?" if s else ""
                problems.append(f"unknown table [{t}]{hint}; valid tables: {', '.join(TABLES)}")
        elif not isinstance(v, Mapping):
            problems.append(f"invalid {t}={show(v)}: expected a table [{t}]; allowed: a table of keys")

    raw = {t: cfg[t] if isinstance(cfg.get(t), Mapping) else {} for t in TABLES}
    if "name" not in raw["case"]:
        problems.append(f"missing required key case.name; allowed: {CASE_NAME.allowed()}")
        raise ConfigError(join_problems(problems))
    try:
        case = get_case(raw["case"]["name"])
        eos_kind = _eos_kind(raw["eos"].get("kind", case.defaults_override.get("eos.kind", EOS_KIND.default)))
    except ConfigError as e:
        raise ConfigError(join_problems([*problems, str(e)])) from None

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
        problems.append("missing required key" + ("s" if len(missing) > 1 else "") + ": " + "; ".join(missing))
    if problems:
        raise ConfigError(join_problems(problems))

    bf = out["physics"]["body_force"]
    if case.dim is not None and len(bf) not in (0, case.dim):
        raise ConfigError(f"invalid physics.body_force={show(bf)}: case {case.name!r} is "
                          f"{case.dim}-D; allowed: [] or a list of {case.dim} floats")
    if out["eos"]["kind"] == "tait" and out["physics"]["kappa"] > 0:
        raise ConfigError(f"invalid physics.kappa={show(out['physics']['kappa'])} with eos.kind = 'tait': the "
                          "Tait EOS is barotropic and has no energy equation, so heat conduction cannot act; "
                          "allowed: 0 (or an EOS with an energy equation: ideal_gas, stiffened_gas)")
    why = local_time_stepping_conflict(out["time"]["dt"], out["scheme"]["frame"])
    if out["time"]["local_time_stepping"] and why:
        raise ConfigError(f"invalid time.local_time_stepping=true: {why}; allowed: {LOCAL_TIME_STEPPING_ALLOWED}")
    interval, t_end, snaps = out["output"]["series_interval"], out["time"]["t_end"], out["output"]["snapshots"]
    why = series_per_output(t_end, snaps, interval)[1]
    if why:
        raise ConfigError(f"invalid output.series_interval={show(interval)}: {why}; allowed: "
                          f"{series_allowed(t_end, snaps, interval)}")
    if case.check is not None:
        case.check(out)
    estimate = None if case.particle_count is None else case.particle_count(out)
    if estimate is not None:   # before anything is built
        check_particle_limit(out, *estimate)
    return out


def _copy(v):
    if isinstance(v, list):
        return [_copy(x) for x in v]
    if isinstance(v, dict):
        return {k: _copy(x) for k, x in v.items()}
    return v


# --------------------------------------------------------------------------------------------
# Overrides
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
        s = suggest(table, TABLES)
        raise ConfigError(f"unknown table [{table}] in override key {dotted!r}"
                          + (f"; did you mean {s}.{k}?" if s else "")
                          + f"; valid tables: {', '.join(TABLES)}")
    if table == "case":
        schemas = ([case_table(get_case(case))] if case is not None else
                   [case_table(c) for _, c in registry("case.name").items()] or [_table_schema("case", None, None)])
    elif table == "eos":
        kinds = [eos_kind] if eos_kind is not None else list(all_eos_keys())
        schemas = [_table_schema("eos", None, kind) for kind in kinds]
    else:
        schemas = [SCHEMA_COMMON[table]]
    for schema in schemas:
        if k in schema:
            key = schema[k]
            if len(parts) == 3 and dict not in key.types:
                raise ConfigError(f"invalid override key {dotted!r}: {table}.{k} is a {key.type_name()}, not a table")
            return key, parts[2] if len(parts) == 3 else None
    merged = {kk: vv for sch in schemas for kk, vv in sch.items()}
    c = get_case(case) if (table == "case" and case is not None) else None
    raise ConfigError(_unknown_key_message(table, k, _IN_OVERRIDE, merged, c, eos_kind))


def parse_override(s: str, *, case: str | None = None, eos_kind: str | None = None) -> tuple[str, object]:
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
            value = parse_value(text, t)
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
        raise ConfigError(f"invalid overrides={overrides!r}; allowed: a sequence of KEY=VALUE strings")
    pre: dict[str, str] = {}
    for s in overrides:  # case.name and eos.kind first: they select the schemas
        if isinstance(s, str) and "=" in s:
            k, _, v = s.partition("=")
            if k.strip() in ("case.name", "eos.kind"):
                pre[k.strip()] = parse_override(s)[1]
    name = pre.get("case.name", _get(raw, "case", "name"))
    if case is not None:
        if name is not None and name != case:
            raise ConfigError(f"invalid case.name={show(name)}: case={case!r} was requested; allowed: {case!r}")
        name = case
    if name is None:
        raise ConfigError(f"missing required key case.name; allowed: {CASE_NAME.allowed()}")
    schema = get_case(name)
    raw.setdefault("case", {})
    if not isinstance(raw["case"], dict):
        raise ConfigError(f"invalid case={show(raw['case'])}: expected a table [case]")
    raw["case"]["name"] = name
    kind = pre.get("eos.kind", _get(raw, "eos", "kind"))
    if kind is None:
        kind = schema.defaults_override.get("eos.kind", EOS_KIND.default)
    kind = _eos_kind(kind)
    for s in overrides:
        dotted, value = parse_override(s, case=name, eos_kind=kind)
        parts = dotted.split(".")
        node = raw
        for p in parts[:-1]:
            child = node.setdefault(p, {})
            if not isinstance(child, dict):
                raise ConfigError(f"cannot apply override {s!r}: {'.'.join(parts[:-1])} is "
                                  f"{show(child)}, not a table")
            node = child
        node[parts[-1]] = value
    return raw


def _get(raw: Mapping, table: str, key: str):
    t = raw.get(table)
    return t.get(key) if isinstance(t, Mapping) else None


# --------------------------------------------------------------------------------------------
# Loading
# --------------------------------------------------------------------------------------------


def loads(text: str, overrides: Sequence[str] = (), case: str | None = None, source: str = "<string>") -> dict:
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
                              f"allowed: case= one of {', '.join(registered_cases())}")
        return validate(_apply_overrides({}, overrides, case))
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"config file {str(p)!r} not found") from None
    except (IsADirectoryError, UnicodeDecodeError) as e:
        raise ConfigError(f"config file {str(p)!r} unreadable: {e}") from None
    return loads(text, overrides, case, source=str(p))


def check_particle_limit(cfg: Mapping, count: int, keys, estimated: bool = True) -> None:
    """Refuse (:class:`~mlsph_jax.errors.ConfigError`) a run of more than ``run.max_particles``
    particles, naming the config ``keys`` that set the count (with their values), the count
    and the limit, and how to raise the limit."""
    limit = cfg.get("run", {}).get("max_particles")
    if limit is None or count <= limit:
        return
    name = cfg["case"]["name"]
    how = "would build ~" if estimated else "built "
    what = (f"{how}{count:,} particles (fluid, walls and far field"
            f"{', estimated before building them' if estimated else ''}), above run.max_particles = {limit:,}")
    raise_limit = (f"raise the limit with --set run.max_particles={_round_up(count)} (or [run] max_particles in "
                   "the config)")
    if not keys:   # a case without an estimate: only its built count is known, not the keys that set it
        raise ConfigError(f"case {name!r} {what}; allowed: reduce the case's resolution keys (case.*), or "
                          f"{raise_limit}")
    vals = " / ".join(f"{k}={show(_lookup(cfg, k))}" for k in keys)
    raise ConfigError(f"invalid {vals}: case {name!r} {what}; allowed: a config with fewer particles (the keys "
                      f"above), or {raise_limit}")


def _lookup(cfg: Mapping, dotted: str):
    table, key = dotted.split(".", 1)
    return cfg[table][key]


def _round_up(n: int) -> int:
    """n rounded up to two significant digits (a limit to suggest)."""
    e = 10 ** max(len(str(int(n))) - 2, 0)
    return -(-int(n) // e) * e
