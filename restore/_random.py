"""Random numbers the samplers share: the log of a uniform, exact far into the tail; and
draws made outside the samplers' programs, compiled as restore compiles its programs."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from ._compile import jit


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


# Drawn eagerly, `jax.random.normal` and `uniform` go through JAX's own sampling programs,
# compiled at XLA's default optimisation level, which is slow to compile even for the
# demo's 64 starts. These compile them as restore compiles its programs (`_compile`), with
# the same bits.
@jit(static_argnums=(1, 2), once=True)
def normal_draws(key: PRNGKeyArray, shape: tuple[int, ...], dtype) -> Array:
    """`jax.random.normal(key, shape, dtype)`, compiled as restore's programs are."""
    return jax.random.normal(key, shape, dtype)


@jit(static_argnums=(1, 2), once=True)
def uniform_draws(key: PRNGKeyArray, shape: tuple[int, ...], dtype) -> Array:
    """`jax.random.uniform(key, shape, dtype)`, compiled as restore's programs are."""
    return jax.random.uniform(key, shape, dtype)


@jit(filtered=True, once=True)
def distribution_draws(distribution, key: PRNGKeyArray, num: int) -> Array:
    """`num` draws of a regeneration distribution (`distribution.sample(key, (num,))`),
    compiled as restore's programs are."""
    return distribution.sample(key, (num,))
