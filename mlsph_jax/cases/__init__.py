"""Built-in cases: one builder per case name, ``builder(cfg) -> Problem``.

Each case module registers its ``[case]`` schema with :func:`mlsph_jax.config.register_case_schema`
and its builder here with ``@CASES.register(name)``.  ``build_problem(cfg)`` dispatches on
``cfg["case"]["name"]``.
"""

from __future__ import annotations

from collections.abc import Mapping

from ..registry import Registry

CASES: Registry = Registry("case.name")


def build_problem(cfg: Mapping):
    """Problem for a resolved, validated config."""
    return CASES.get(cfg["case"]["name"], "case.name")(cfg)


from . import blast_2d  # noqa: E402,F401,I001  (registers the case)
from . import riemann_1d  # noqa: E402,F401  (registers the case)
from . import taylor_green_2d  # noqa: E402,F401,I001  (registers the case)
from . import channel_flows  # noqa: E402,F401,I001  (registers the cases couette and poiseuille)
from . import lid_driven_cavity  # noqa: E402,F401,I001  (registers the case)
