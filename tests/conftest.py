"""Statistical checks run in float64 with fixed keys: they are deterministic."""

import jax

jax.config.update("jax_enable_x64", True)
