"""The Many Well problem: a product of independent double-well pairs."""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.scipy.special import ndtr
from jaxtyping import Array, Float, Int, PRNGKeyArray

from . import _checks, _double_well
from ._base import AbstractTarget
from ._special import standard_normal


class ManyWell(AbstractTarget):
    """The Many Well problem of Midgley et al. (2023), flow annealed importance sampling bootstrap.

    `d / 2` independent pairs `(a_i, b_i) = (x_{2i}, x_{2i+1})`, each with the unnormalised
    log density `-a^4 + 6 a^2 + a / 2 - b^2 / 2`: a double well in `a` (wells near -1.71
    and 1.75, the right one holding `positive_probability` ~ 0.844 of the mass) times a
    standard normal in `b`. There are `2^(d/2)` modes (65,536 at the default `d = 32`),
    far too many for any sampler to visit one by one.

    `logdensity` is the literature's *unnormalised* form: it integrates to
    `exp(log_normalising_constant)` with `log_normalising_constant = (d/2) log Z_pair`,
    `Z_pair = sqrt(2 pi) ∫ exp(-a^4 + 6 a^2 + a / 2) da` (about 164.70 for `d = 32`),
    computed by adaptive quadrature to about 1e-13 relative accuracy. Draws are exact
    (rejection sampling for every `a`, see `_double_well`), and so are the mean, the
    (diagonal) covariance and every marginal CDF.

    Attributes:
        dim: the dimension `d`, even and at least 2 (static).
    """

    dim: int = eqx.field(static=True)

    def __init__(self, dim: int = 32):
        """Arguments:
            dim: the dimension, an even integer `>= 2` (`d / 2` double-well pairs).

        Raises:
            ValueError: for an odd dimension or one below 2.
        """
        dim = _checks.integer(dim, "dim", 2)
        if dim % 2:
            raise ValueError(f"dim must be even (the coordinates come in double-well pairs), got {dim}")
        self.dim = dim

    @property
    def num_pairs(self) -> int:
        """The number of double-well pairs, `d / 2`."""
        return self.dim // 2

    @property
    def num_modes(self) -> int:
        """The number of modes, `2^(d/2)`: one per sign pattern of the double-well coordinates."""
        return 2**self.num_pairs

    @property
    def log_normalising_constant(self) -> float:
        """`(d/2) log Z_pair`, the exact `log ∫ exp(logdensity)`."""
        return self.num_pairs * (_double_well.constants().log_normaliser + 0.5 * math.log(2.0 * math.pi))

    @property
    def positive_probability(self) -> float:
        """`P(x_{2i} > 0)`, the mass of the right well of every pair (about 0.844)."""
        return _double_well.constants().positive_probability

    def logdensity(self, x: Float[Array, " d"]) -> Float[Array, ""]:
        x = _checks.point(x, self.dim)
        a, b = x[0::2], x[1::2]
        return jnp.sum(_double_well.log_unnormalised(a)) - 0.5 * jnp.sum(b * b)

    def assign_mode(self, x: Float[Array, " d"]) -> Int[Array, ""]:
        """The mode of one point: the integer whose bit `i` is `x_{2i} > 0`.

        Arguments:
            x: a single point of shape `(d,)`; `jax.vmap` for batches.

        Raises:
            ValueError: for more than 31 pairs (the index would not fit an `int32`).
        """
        if self.num_pairs > 31:
            raise ValueError(f"assign_mode needs at most 31 pairs (an int32 index), this target has {self.num_pairs}")
        x = _checks.point(x, self.dim)
        bits = (x[0::2] > 0).astype(jnp.int32)
        return jnp.sum(bits << jnp.arange(self.num_pairs, dtype=jnp.int32))

    def _sample(self, key: PRNGKeyArray, n: int) -> Float[Array, "n d"]:
        key_a, key_b = jax.random.split(key)
        dtype = jnp.result_type(float)
        a = _double_well.sample(key_a, n * self.num_pairs, dtype).reshape(n, self.num_pairs)
        b = standard_normal(key_b, (n, self.num_pairs), dtype)
        return jnp.stack([a, b], axis=-1).reshape(n, self.dim)

    @property
    def mean(self) -> Float[Array, " d"]:
        pair = jnp.array([_double_well.constants().mean, 0.0])
        return jnp.tile(pair, self.num_pairs)

    @property
    def covariance(self) -> Float[Array, "d d"]:
        c = _double_well.constants()
        pair = jnp.array([c.second_moment - c.mean**2, 1.0])
        return jnp.diag(jnp.tile(pair, self.num_pairs))

    def _marginal_cdf(self, i: int, t: Float[Array, ...]) -> Float[Array, ...]:
        return ndtr(t) if i % 2 else _double_well.cdf(t)
