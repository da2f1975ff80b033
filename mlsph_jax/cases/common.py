"""Helpers shared by the case builders: parameters and scheme from a resolved config."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

import jax.numpy as jnp

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


def scheme_from_config(cfg: Mapping) -> Scheme:
    """The static scheme; viscous / heat fluxes are switched on by physics.mu / physics.kappa > 0."""
    s = Scheme.from_config(cfg["scheme"], cfg["eos"]["kind"])
    phys = cfg.get("physics", {})
    return dataclasses.replace(s, viscous=float(phys.get("mu", 0.0)) > 0,
                               heat_conduction=float(phys.get("kappa", 0.0)) > 0)
