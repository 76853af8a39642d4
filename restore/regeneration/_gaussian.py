"""Multivariate Gaussian regeneration distribution."""

from __future__ import annotations

import math
from typing import final

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from .._linalg import half_log_det, inverse_tril, mahalanobis_sq
from .._validation import check_point, check_shape, check_vector
from ._base import AbstractRegeneration
from ._utils import scale_tril


@final
class Gaussian(AbstractRegeneration):
    """Multivariate normal distribution `N(mean, cov)`.

    The covariance is stored through its lower Cholesky factor `L`, and `log_prob`
    multiplies by `L^{-1}`, solved for once when the distribution is built.

    Attributes:
        mean: the mean, shape `(d,)`.
        scale_tril: lower-triangular `L` with `L @ L.T == cov`, shape `(d, d)`.
        inverse_tril: `L^{-1}`, shape `(d, d)` (kept with `L`: replace both together).
        dim: the dimension `d` (static).
    """

    mean: Float[Array, " d"]
    scale_tril: Float[Array, "d d"]
    inverse_tril: Float[Array, "d d"]
    dim: int = eqx.field(static=True)

    def __init__(self, mean: ArrayLike, cov: ArrayLike = 1.0):
        """Arguments:
            mean: the mean, a 1-D array of shape `(d,)`; fixes the dimension.
            cov: the covariance, as a scalar variance (isotropic), a `(d,)`
                vector of variances (diagonal) or a symmetric positive-definite
                `(d, d)` matrix. Defaults to the identity.

        Raises:
            ValueError: for a mean that is not 1-D, a covariance of the wrong
                shape, or one that is not positive definite.
        """
        mean = check_vector(mean, "mean")
        self.dim = mean.shape[0]
        tril = scale_tril(cov, self.dim, "cov")
        dtype = jnp.result_type(mean.dtype, tril.dtype)
        self.mean = mean.astype(dtype)
        self.scale_tril = tril.astype(dtype)
        self.inverse_tril = inverse_tril(self.scale_tril)

    @property
    def cov(self) -> Float[Array, "d d"]:
        """The covariance matrix `L @ L.T`."""
        return self.scale_tril @ self.scale_tril.T

    def sample(
        self, key: PRNGKeyArray, shape: tuple[int, ...] = ()
    ) -> Float[Array, "*shape d"]:
        """Exact draws `mean + L z`, `z ~ N(0, I)`.

        Arguments:
            key: a JAX PRNG key.
            shape: batch shape; the result has shape `(*shape, d)`.
        """
        shape = check_shape(shape)
        z = jax.random.normal(key, shape + (self.dim,), dtype=self.mean.dtype)
        return self.mean + z @ self.scale_tril.T

    def log_prob(self, x: Float[Array, " d"]) -> Float[Array, ""]:
        """Normalised log density of one point `x` of shape `(d,)`."""
        x = check_point(x, self.dim, "x")
        maha = mahalanobis_sq(self.scale_tril, x - self.mean, self.inverse_tril)
        return (
            -0.5 * maha
            - half_log_det(self.scale_tril)
            - 0.5 * self.dim * math.log(2 * math.pi)
        )
