"""Uniform regeneration distributions on a box and on the unit torus."""

from __future__ import annotations

from typing import Any, final

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from .._validation import check_integer, check_point, check_shape, check_vector, is_concrete
from ._base import AbstractRegeneration


@final
class UniformBox(AbstractRegeneration):
    """Uniform distribution on the closed box `[low_1, high_1] x ... x [low_d, high_d]`.

    Only suitable as a regeneration distribution for targets supported inside
    the box (otherwise the kill rate is zero where the target lives).

    Attributes:
        low: lower corner, shape `(d,)`.
        high: upper corner, shape `(d,)`.
        dim: the dimension `d` (static).
    """

    low: Float[Array, " d"]
    high: Float[Array, " d"]
    dim: int = eqx.field(static=True)

    def __init__(self, low: ArrayLike, high: ArrayLike):
        """Arguments:
            low: lower corner of the box, a 1-D array of shape `(d,)`.
            high: upper corner of the box, same shape as `low`, with
                `low < high` elementwise.

        Raises:
            ValueError: for shapes that are not `(d,)` or differ, non-finite
                bounds, or `low >= high` in some coordinate.
        """
        low = check_vector(low, "low")
        high = check_vector(high, "high")
        if low.shape != high.shape:
            raise ValueError(
                f"`low` and `high` must have the same shape, got {low.shape} and "
                f"{high.shape}."
            )
        if is_concrete(low, high):
            lo, hi = np.asarray(low), np.asarray(high)
            if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
                raise ValueError("`low` and `high` must be finite.")
            bad = np.nonzero(~(lo < hi))[0]
            if bad.size:
                raise ValueError(
                    f"Need low < high in every coordinate; violated at indices "
                    f"{bad.tolist()}."
                )
        dtype = jnp.result_type(low.dtype, high.dtype)
        self.low = low.astype(dtype)
        self.high = high.astype(dtype)
        self.dim = low.shape[0]

    def sample(
        self, key: PRNGKeyArray, shape: tuple[int, ...] = ()
    ) -> Float[Array, "*shape d"]:
        """Exact uniform draws in the box.

        Arguments:
            key: a JAX PRNG key.
            shape: batch shape; the result has shape `(*shape, d)`.
        """
        shape = check_shape(shape)
        return jax.random.uniform(
            key,
            shape + (self.dim,),
            dtype=self.low.dtype,
            minval=self.low,
            maxval=self.high,
        )

    def log_prob(self, x: Float[Array, " d"]) -> Float[Array, ""]:
        """`-sum(log(high - low))` inside the box, exactly `-inf` outside (also for NaN)."""
        x = check_point(x, self.dim, "x")
        inside = jnp.all((x >= self.low) & (x <= self.high))
        value = -jnp.sum(jnp.log(self.high - self.low))
        return jnp.where(inside, value, -jnp.inf)


@final
class UniformTorus(AbstractRegeneration):
    """Uniform distribution on the unit torus, represented as `[0, 1)^dim`.

    The density is w.r.t. Lebesgue measure on `[0, 1)^dim`, hence `log_prob` is
    0 inside and exactly `-inf` outside. It is the regeneration of light transport
    (PSSMLT's large step): a float32 one makes the whole run float32.

    Attributes:
        dim: the dimension (static).
        dtype: the floating dtype of the draws (static; `None`: JAX's default float).
    """

    dim: int = eqx.field(static=True)
    dtype: Any = eqx.field(static=True)

    def __init__(self, dim: int, dtype: Any = None):
        """Arguments:
            dim: the dimension of the torus, a positive int.
            dtype: the floating dtype of the draws, e.g. `jnp.float32`; default JAX's default float.

        Raises:
            TypeError: if `dim` is not a number (a boolean is not), or `dtype` is not a floating dtype.
            ValueError: if `dim` is not a positive integer.
        """
        self.dim = check_integer(dim, "dim")
        if dtype is not None:
            try:
                dtype = jnp.dtype(dtype)
            except TypeError as err:
                raise TypeError(f"dtype must be a floating dtype, got {dtype!r}") from err
            if not jnp.issubdtype(dtype, jnp.floating):
                raise TypeError(f"dtype must be a floating dtype, got {dtype}")
        self.dtype = dtype

    def sample(
        self, key: PRNGKeyArray, shape: tuple[int, ...] = ()
    ) -> Float[Array, "*shape d"]:
        """Exact uniform draws in `[0, 1)^dim`.

        Arguments:
            key: a JAX PRNG key.
            shape: batch shape; the result has shape `(*shape, dim)`.
        """
        shape = check_shape(shape)
        if self.dtype is None:
            return jax.random.uniform(key, shape + (self.dim,))
        return jax.random.uniform(key, shape + (self.dim,), self.dtype)

    def log_prob(self, x: Float[Array, " d"]) -> Float[Array, ""]:
        """0 on `[0, 1)^dim`, exactly `-inf` outside (also for NaN)."""
        x = check_point(x, self.dim, "x")
        inside = jnp.all((x >= 0) & (x < 1))
        return jnp.where(inside, jnp.zeros((), x.dtype), -jnp.inf)
