"""Random numbers the samplers share: the log of a uniform, exact far into the tail."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray


def log_uniform(key: PRNGKeyArray, dtype) -> Float[Array, ""]:
    """`log U` for `U` uniform on `[0, 1)`, for the tests `log U < log p` of kills and acceptances.

    In float64 it is `log(jax.random.uniform(key))` (resolution `2^-52`). A float32 uniform
    is a multiple of `2^-23`, so `U < p` would succeed with probability `2^-23` even for a
    much smaller `p` (a kill in a bright region of an image, a move far down a slope): a
    bias of the process. Below float64, a second uniform fills in the bits under that grid,
    which makes `P(log U < log p) = p` exact for `p >= 2^-46`.
    """
    dtype = jnp.dtype(dtype)
    if dtype.itemsize >= 8:
        return jnp.log(jax.random.uniform(key, dtype=dtype))
    coarse, fine = jax.random.uniform(key, (2,), jnp.float32)
    return jnp.log(coarse + fine * jnp.float32(2.0**-23)).astype(dtype)
