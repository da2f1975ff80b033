"""Built-in cases, and the one registry of cases (:data:`CASES`, kind ``"case.name"``).

Each case module declares its ``[case]`` keys and cross-checks next to its builder and
registers them with :func:`register_case`; ``build_problem(cfg)`` dispatches on
``cfg["case"]["name"]`` through the registry.  A user's script registers its own case the same
way and selects it with ``case.name`` in a TOML config.
"""

from __future__ import annotations

from .base import CASES, Case, build_problem, register_case

__all__ = ["CASES", "Case", "build_problem", "register_case"]

from . import blast_2d  # noqa: E402,F401,I001  (registers the case)
from . import riemann_1d  # noqa: E402,F401  (registers the case)
from . import taylor_green_2d  # noqa: E402,F401,I001  (registers the case)
from . import channel_flows  # noqa: E402,F401,I001  (registers the cases couette and poiseuille)
from . import lid_driven_cavity  # noqa: E402,F401,I001  (registers the case)
from . import cylinder  # noqa: E402,F401,I001  (registers the case)
