"""Products of one-dimensional Gaussian mixtures: `K^d` modes from `K d` parameters."""

from __future__ import annotations

import math
from typing import final

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from .._validation import as_float_array, check_point, check_shape
from ._base import AbstractRegeneration
from ._diagonal_mixture import _positive_weights
from ._utils import component_indices


@final
class ProductMixture(AbstractRegeneration):
    """Independent coordinates, each a one-dimensional Gaussian mixture.

    `u(x) = prod_j sum_k w_jk N(x_j; m_jk, s_jk^2)`. A target whose modes come in
    product form (each coordinate, or each block, choosing one of a few wells
    independently) has exponentially many modes, which no mixture of a few components
    covers; this family represents all of them with `K d` numbers and costs `O(K d)` per
    evaluation.

    Attributes:
        log_weights: `(d, K)` normalised log weights of each coordinate's components.
        means: `(d, K)` component means.
        scales: `(d, K)` component standard deviations.
        dim: the dimension `d` (static).
    """

    log_weights: Float[Array, "d K"]
    means: Float[Array, "d K"]
    scales: Float[Array, "d K"]
    dim: int = eqx.field(static=True)

    def __init__(self, weights: ArrayLike, means: ArrayLike, scales: ArrayLike):
        """Arguments:
            weights: `(d, K)` positive weights, normalised per coordinate.
            means: `(d, K)` means.
            scales: `(d, K)` positive standard deviations.
        """
        means = as_float_array(means, "means")
        if means.ndim != 2 or 0 in means.shape:
            raise ValueError(f"`means` must have shape (d, K), got {means.shape}.")
        w = _positive_weights(weights, means.shape, "weights")
        s = _positive_weights(scales, means.shape, "scales")
        if not bool(jnp.all(jnp.isfinite(means))):
            raise ValueError("`means` must be finite.")
        dtype = means.dtype
        self.log_weights = jnp.asarray(jnp.log(w) - jnp.log(w.sum(axis=1, keepdims=True)), dtype)
        self.means = means
        self.scales = jnp.asarray(s, dtype)
        self.dim = int(means.shape[0])

    def log_prob(self, x: Float[Array, " d"]) -> Float[Array, ""]:
        x = check_point(x, self.dim, "x")
        z = (x[:, None] - self.means) / self.scales
        terms = self.log_weights - 0.5 * z**2 - jnp.log(self.scales) - 0.5 * math.log(2 * math.pi)
        return jnp.sum(jax.scipy.special.logsumexp(terms, axis=1))

    def sample(self, key: PRNGKeyArray, shape: tuple[int, ...] = ()) -> Float[Array, "*shape d"]:
        shape = check_shape(shape)
        k_idx, k_z = jax.random.split(key)
        dtype = self.means.dtype
        idx = component_indices(k_idx, self.log_weights, shape, dtype)  # (*shape, d): each coordinate's component
        coords = jnp.arange(self.dim)
        z = jax.random.normal(k_z, shape + (self.dim,), dtype=dtype)
        return self.means[coords, idx] + self.scales[coords, idx] * z
