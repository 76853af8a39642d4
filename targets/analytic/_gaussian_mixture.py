"""Mixture of multivariate Gaussians."""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.linalg import solve_triangular
from jax.scipy.special import ndtr
from jaxtyping import Array, ArrayLike, Float, Int, PRNGKeyArray

from . import _checks
from ._base import AbstractMixture
from ._special import categorical, standard_normal


class GaussianMixture(AbstractMixture):
    """Finite mixture of multivariate normals `sum_k w_k N(mu_k, Sigma_k)`.

    The standard multimodal test target: every quantity (density, samples, moments,
    marginal CDFs, the generating component of a draw) is exact.

    Attributes:
        means: component means, shape `(k, d)`.
        covariances: component covariances, shape `(k, d, d)`.
        cholesky_factors: lower Cholesky factors of `covariances`, shape `(k, d, d)`.
        inverse_cholesky_factors: their inverses (whitening matrices), `(k, d, d)`.
        weights: normalised weights, shape `(k,)`.
        dim: the dimension `d` (static).
    """

    means: Float[Array, "k d"]
    covariances: Float[Array, "k d d"]
    cholesky_factors: Float[Array, "k d d"]
    inverse_cholesky_factors: Float[Array, "k d d"]
    weights: Float[Array, " k"]
    dim: int = eqx.field(static=True)

    def __init__(
        self,
        means: ArrayLike,
        covariances: ArrayLike,
        weights: ArrayLike | None = None,
    ):
        """Arguments:
            means: component means, shape `(k, d)`; fixes `k` and `d`.
            covariances: component covariances, as a scalar (`s * I` for all), `(k,)`
                (`s_k * I` per component), `(k, d)` (diagonal variances) or
                `(k, d, d)` (symmetric positive-definite matrices).
            weights: positive component weights of shape `(k,)`, normalised here so
                they need not sum to one. `None` means equal weights.

        Raises:
            ValueError: on wrong shapes, non-finite values, covariances that are not
                positive definite or weights that are not strictly positive.
        """
        means = _checks.mixture_means(means)
        k, d = means.shape
        covs = _checks.float_array(covariances, "covariances")
        dtype = jnp.result_type(means, covs)
        if weights is not None:
            dtype = jnp.result_type(dtype, _checks.float_array(weights, "weights"))
        self.means = means.astype(dtype)
        self.covariances = _checks.matrix_stack(covs, k, d, "covariances", dtype)
        self.cholesky_factors = _checks.cholesky_stack(self.covariances, "covariances")
        # Inverted once here: a batched matrix product per evaluation is much faster on
        # the CPU than batched triangular solves inside vmap.
        eye = jnp.broadcast_to(jnp.eye(d, dtype=dtype), (k, d, d))
        self.inverse_cholesky_factors = jax.vmap(lambda c, e: solve_triangular(c, e, lower=True))(self.cholesky_factors, eye)
        self.weights = _checks.mixture_weights(weights, k, dtype)
        self.dim = d

    def component_logdensities(self, x: Float[Array, " d"]) -> Float[Array, " k"]:
        x = _checks.point(x, self.dim)
        diff = x - self.means
        z = jnp.einsum("kij,kj->ki", self.inverse_cholesky_factors, diff)
        half_logdet = jnp.sum(
            jnp.log(jnp.diagonal(self.cholesky_factors, axis1=-2, axis2=-1)), axis=-1
        )
        return -0.5 * jnp.sum(z * z, axis=-1) - half_logdet - 0.5 * self.dim * math.log(2 * math.pi)

    def smoothed(self, covariance: ArrayLike) -> GaussianMixture:
        """The mixture convolved with `N(0, C)`: `C` added to every component covariance.

        Its `logdensity(y)` is exactly `log ∫ p(x) N(y; x, C) dx` for this (normalised)
        mixture `p`, which is what a non-invariant Gaussian jump kernel needs, e.g.
        `UnadjustedJump(s, log_convolution=mixture.smoothed(s**2).logdensity)`.

        Arguments:
            covariance: `C`, a non-negative scalar (`C = c I`), non-negative diagonal
                variances `(d,)`, or a symmetric positive semi-definite matrix `(d, d)`.

        Raises:
            ValueError: on a wrong shape, non-finite values, or a `C` that is not
                positive semi-definite.
        """
        d = self.dim
        arr = _checks.float_array(covariance, "covariance")
        _checks.check_finite(arr, "covariance")
        values = _checks.concrete(arr)
        if arr.ndim == 0 or arr.shape == (d,):
            if values is not None and not np.all(values >= 0):
                raise ValueError(f"covariance must be non-negative, got {values}")
            extra = jnp.broadcast_to(arr, (d,)) * jnp.eye(d, dtype=arr.dtype)
        elif arr.shape == (d, d):
            if values is not None:
                values = np.asarray(values, dtype=np.float64)
                asym = np.max(np.abs(values - values.T))
                if asym > 100 * np.finfo(np.float64).eps * max(np.max(np.abs(values)), 1e-300):
                    raise ValueError(f"covariance must be symmetric (max asymmetry {asym:.3g})")
                eigenvalues = np.linalg.eigvalsh(values)
                if eigenvalues.min() < -100 * np.finfo(np.float64).eps * max(np.abs(eigenvalues).max(), 1e-300):
                    raise ValueError(f"covariance must be positive semi-definite (eigenvalues {eigenvalues})")
            extra = 0.5 * (arr + arr.T)
        else:
            raise ValueError(
                f"covariance must be a scalar, or have shape ({d},) (diagonal variances) or ({d}, {d}); "
                f"got shape {arr.shape}"
            )
        return GaussianMixture(self.means, self.covariances + extra.astype(self.covariances.dtype), self.weights)

    def component_marginal_cdfs(self, i: int, t: Float[Array, "*t"]) -> Float[Array, "*t k"]:
        sd = jnp.sqrt(self.covariances[:, i, i])
        return ndtr((t[..., None] - self.means[:, i]) / sd)

    @property
    def component_means(self) -> Float[Array, "k d"]:
        return self.means

    @property
    def component_covariances(self) -> Float[Array, "k d d"]:
        return self.covariances

    def _sample_with_modes(
        self, key: PRNGKeyArray, n: int
    ) -> tuple[Float[Array, "n d"], Int[Array, " n"]]:
        key_mode, key_noise = jax.random.split(key)
        modes = categorical(key_mode, self.weights, n)
        z = standard_normal(key_noise, (n, self.dim), self.means.dtype)
        x = self.means[modes] + jnp.einsum("nij,nj->ni", self.cholesky_factors[modes], z)
        return x, modes
