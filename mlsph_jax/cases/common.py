"""Helpers shared by the case builders: parameters and scheme from a resolved config, and the
``case.walls`` choice of the wall-bounded cases (couette, poiseuille, lid_driven_cavity)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping

import jax.numpy as jnp

from ..boundaries import BOUNDARIES
from ..registry import names_of
from ..schema import Key, show
from ..scheme import Scheme
from ..state import Params


def params_from_config(cfg: Mapping) -> Params:
    """Differentiable parameters: every EOS constant (``eos.*``) and the physics constants."""
    vals = {f"eos.{k}": float(v) for k, v in cfg["eos"].items() if k != "kind"}
    phys = cfg.get("physics", {})
    vals["physics.mu"] = float(phys.get("mu", 0.0))
    vals["physics.kappa"] = float(phys.get("kappa", 0.0))
    if phys.get("body_force"):
        vals["physics.body_force"] = jnp.asarray(phys["body_force"], jnp.float64)
    return Params(vals)


def support_layers(cfg: Mapping) -> int:
    """Particle layers within the support radius kappa beta dx of a lattice of spacing dx (the
    mirror-ghost layers of a wall, the frozen columns of an end): ceil(kappa beta)."""
    s = scheme_from_config(cfg)
    return math.ceil(s.support * s.beta)


def scheme_from_config(cfg: Mapping) -> Scheme:
    """The static scheme; viscous / heat fluxes are switched on by physics.mu / physics.kappa > 0."""
    s = Scheme.from_config(cfg["scheme"], cfg["eos"]["kind"])
    phys = cfg.get("physics", {})
    return dataclasses.replace(s, viscous=float(phys.get("mu", 0.0)) > 0,
                               heat_conduction=float(phys.get("kappa", 0.0)) > 0)


def walls_key(which: str) -> Key:
    """The ``case.walls`` key (the choices are the ``boundary`` registry's names); ``which``: the
    walls it sets, e.g. "both plates"."""
    return Key(str, "mirror_ghosts", choices=names_of("boundary"),
               doc=f"wall treatment of {which}: mirror ghosts (thesis eq. 3.22) or the "
                   "boundary integral of thesis eq. 4.24 (no ghosts; needs scheme.method = "
                   "\"mlsph_ale\"; docs/architecture.md decision 54)")


def steady_tol_key(default: float) -> Key:
    """``case.steady_tol``: the residual-based stop of steady cases (:class:`~mlsph_jax.simulation.Problem`
    ``steady_tol``), one definition for the cavity and the cylinder."""
    return Key(float, default, minimum=0.0,
               doc="stop early once max|u(t2) - u(t1)| / max|u| / (t2 - t1) between two output "
                   "times is below this (1/s; 0 = always run to time.t_end)")


def walls_problems(cfg: Mapping) -> list[str]:
    """Cross-check of ``case.walls``: the boundary integral needs MLS shape functions."""
    walls, method = cfg["case"]["walls"], cfg["scheme"]["method"]
    if walls == "boundary_integral" and method != "mlsph_ale":
        return [f"invalid case.walls={show(walls)} with scheme.method={show(method)}: the boundary term "
                "of thesis eq. 4.24 is derived for MLS shape functions; allowed: scheme.method = "
                "\"mlsph_ale\" or case.walls = \"mirror_ghosts\""]
    return []


def setup_walls(cfg: Mapping, p_fluid, walls, band: float, params, scheme, domain):
    """``(particles, boundary)`` of the ``case.walls`` treatment for the axis-aligned ``walls``
    (:class:`~mlsph_jax.boundaries.Wall`; boundary-integral segments span ``domain`` along each
    wall, velocities ``boundary.wall_velocity`` of ``params``)."""
    return BOUNDARIES.get(cfg["case"]["walls"], "case.walls").setup(p_fluid, walls, band, params, scheme.eos,
                                                                    scheme=scheme, domain=domain)
