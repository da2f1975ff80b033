"""Helpers shared by the case builders: parameters and scheme from a resolved config."""

from __future__ import annotations

from collections.abc import Mapping

import jax.numpy as jnp

from ..scheme import Scheme
from ..state import Params


def params_from_config(cfg: Mapping) -> Params:
    """Differentiable parameters: every EOS constant (``eos.*``) and the physics constants."""
    vals = {f"eos.{k}": float(v) for k, v in cfg["eos"].items() if k != "kind"}
    phys = cfg.get("physics", {})
    vals["physics.mu"] = float(phys.get("mu", 0.0))
    if phys.get("body_force"):
        vals["physics.body_force"] = jnp.asarray(phys["body_force"], jnp.float64)
    return Params(vals)


def scheme_from_config(cfg: Mapping) -> Scheme:
    return Scheme.from_config(cfg["scheme"], cfg["eos"]["kind"])
