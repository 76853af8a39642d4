"""Mixtures of axis-aligned Gaussian or Student-t components, evaluated in `O(K d)`."""

from __future__ import annotations

import math
from typing import final

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import gammaln
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from .._threefry import loggamma
from .._validation import as_float_array, check_point, check_shape
from ._base import AbstractRegeneration
from ._utils import component_indices


def _positive_weights(weights: ArrayLike, shape: tuple[int, ...], name: str) -> np.ndarray:
    w = np.asarray(as_float_array(weights, name), np.float64)
    if w.shape != shape:
        raise ValueError(f"`{name}` must have shape {shape}, got {w.shape}.")
    if not (np.all(np.isfinite(w)) and np.all(w > 0)):
        raise ValueError(f"`{name}` must be finite and strictly positive.")
    return w


def check_df(df) -> float | None:
    """`None` (Gaussian) or a finite degrees of freedom of at least 1."""
    if df is None:
        return None
    if isinstance(df, bool) or not isinstance(df, (int, float, np.integer, np.floating)):
        raise TypeError(f"`df` must be None or a number, got {df!r}")
    if not (math.isfinite(float(df)) and float(df) >= 1.0):
        raise ValueError(f"`df` must be None (Gaussian components) or a finite number >= 1, got {df!r}")
    return float(df)


def log_chi2_over_df(key: PRNGKeyArray, df: float, shape: tuple[int, ...], dtype) -> Array:
    """`log(w)` with `w ~ chi2(df) / df`: a sum of squared normals for small integer `df`."""
    if df == round(df) and df <= 64:
        normals = jax.random.normal(key, shape + (int(df),), dtype=dtype)
        return jnp.log(jnp.sum(normals**2, axis=-1)) - math.log(df)
    return loggamma(key, 0.5 * df, shape, dtype) - math.log(0.5 * df)


@final
class DiagonalMixture(AbstractRegeneration):
    """Mixture of `K` components with diagonal covariance (or scale) matrices.

    Component `k` is `N(means[k], diag(scales[k]^2))`, or with `df` the multivariate
    Student-t with that location and scale matrix and `df` degrees of freedom. A log
    density costs `O(K d)` instead of the `O(K d^2)` of full matrices, which is what a
    Restore run pays at every step.

    Attributes:
        log_weights: `(K,)` normalised log weights.
        means: `(K, d)` component locations.
        scales: `(K, d)` component standard deviations (scale-matrix square roots).
        df: `None` for Gaussian components, else the Student-t degrees of freedom.
        dim: the dimension `d` (static).
    """

    log_weights: Float[Array, " K"]
    means: Float[Array, "K d"]
    scales: Float[Array, "K d"]
    df: float | None = eqx.field(static=True)
    dim: int = eqx.field(static=True)

    def __init__(self, weights: ArrayLike, means: ArrayLike, scales: ArrayLike, df: float | None = None):
        """Arguments:
            weights: `(K,)` positive weights, normalised here.
            means: `(K, d)` locations.
            scales: `(K, d)` positive standard deviations.
            df: `None` (Gaussian components) or degrees of freedom >= 1.
        """
        means = as_float_array(means, "means")
        if means.ndim != 2 or 0 in means.shape:
            raise ValueError(f"`means` must have shape (K, d), got {means.shape}.")
        k, d = means.shape
        w = _positive_weights(weights, (k,), "weights")
        s = _positive_weights(scales, (k, d), "scales")
        if not np.all(np.isfinite(np.asarray(means))):
            raise ValueError("`means` must be finite.")
        dtype = means.dtype
        self.log_weights = jnp.asarray(np.log(w) - np.log(w.sum()), dtype)
        self.means = means
        self.scales = jnp.asarray(s, dtype)
        self.df = check_df(df)
        self.dim = d

    @property
    def num_components(self) -> int:
        return int(self.means.shape[0])

    def component_log_probs(self, x: Float[Array, " d"]) -> Float[Array, " K"]:
        """`log p_k(x)` of every component at one point (no weights)."""
        x = check_point(x, self.dim, "x")
        z2 = jnp.sum(((x - self.means) / self.scales) ** 2, axis=1)
        log_det = jnp.sum(jnp.log(self.scales), axis=1)
        d = self.dim
        if self.df is None:
            return -0.5 * z2 - log_det - 0.5 * d * math.log(2 * math.pi)
        nu = self.df
        const = gammaln(0.5 * (nu + d)) - gammaln(0.5 * nu) - 0.5 * d * math.log(nu * math.pi)
        return const - log_det - 0.5 * (nu + d) * jnp.log1p(z2 / nu)

    def log_prob(self, x: Float[Array, " d"]) -> Float[Array, ""]:
        return jax.scipy.special.logsumexp(self.log_weights + self.component_log_probs(x))

    def sample(self, key: PRNGKeyArray, shape: tuple[int, ...] = ()) -> Float[Array, "*shape d"]:
        shape = check_shape(shape)
        k_idx, k_z, k_w = jax.random.split(key, 3)
        idx = component_indices(k_idx, self.log_weights, shape, self.means.dtype)
        z = jax.random.normal(k_z, shape + (self.dim,), dtype=self.means.dtype)
        if self.df is not None:
            z = z * jnp.exp(-0.5 * log_chi2_over_df(k_w, self.df, shape, self.means.dtype))[..., None]
        return self.means[idx] + self.scales[idx] * z
