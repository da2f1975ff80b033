"""``python -m mlsph_jax.config`` prints the configuration reference (docs/config.md)."""

from . import config_reference_markdown

print(config_reference_markdown(), end="")
