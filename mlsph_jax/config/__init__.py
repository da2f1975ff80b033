"""Schema-validated TOML configurations.

A config is a TOML file with the tables ``[case]``, ``[scheme]``, ``[eos]``, ``[physics]``,
``[time]``, ``[output]`` and ``[run]``.  Every key is described by a :class:`~mlsph_jax.schema.Key`: its
type, default (or :data:`REQUIRED`), allowed values or range, unit and a one-line doc.
:func:`load` reads a file, applies ``--set`` style overrides, fills every default and validates
everything; the result is a plain nested ``dict`` holding every table and every key.

* ``[case]`` — ``name`` selects a case registered in :data:`mlsph_jax.cases.CASES` (with
  :func:`mlsph_jax.cases.register_case`); the case declares the other ``[case]`` keys, may
  change the defaults of the other tables, cross-checks keys and fixes the space dimension.
* ``[eos]`` — ``kind`` selects the EOS; its keys are :data:`EOS_SCHEMAS` (built-in EOS) or derived
  from the registered EOS (:func:`eos_keys`).
* ``[scheme]``, ``[time]``, ``[output]``, ``[physics]``, ``[run]`` — :data:`SCHEMA_COMMON`.

An unknown table or key, a wrong type or an out-of-range value raises
:class:`~mlsph_jax.errors.ConfigError` naming the dotted key, the value given and what is
allowed; all problems of a file are reported together.  ``python -m mlsph_jax.config`` prints
the reference (:func:`config_reference_markdown`, the source of ``docs/config.md``).

Layout: :mod:`mlsph_jax.schema` (the engine: keys, checking, TOML text), :mod:`.tables` (the
keys of the shared tables), :mod:`.resolve` (overrides, validation, loading) and
:mod:`.reference` (the Markdown reference).  No numerics module imports this package.
"""

from __future__ import annotations

from ..errors import ConfigError
from ..schema import REQUIRED, Key, dumps
from .reference import config_reference_markdown
from .resolve import check_defaults_override, get_case, load, loads, parse_override, registered_cases, validate
from .tables import CASE_NAME, EOS_KIND, EOS_SCHEMAS, SCHEMA_COMMON, TABLE_DOCS, TABLES, effective_beta, eos_keys

__all__ = [
    "CASE_NAME",
    "EOS_KIND",
    "EOS_SCHEMAS",
    "REQUIRED",
    "SCHEMA_COMMON",
    "TABLES",
    "TABLE_DOCS",
    "ConfigError",
    "Key",
    "check_defaults_override",
    "config_reference_markdown",
    "dumps",
    "effective_beta",
    "eos_keys",
    "get_case",
    "load",
    "loads",
    "parse_override",
    "registered_cases",
    "validate",
]
