"""Mixture of multivariate Student-t distributions."""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.linalg import solve_triangular
from jax.scipy.special import gammaln
from jaxtyping import Array, ArrayLike, Float, Int, PRNGKeyArray

from . import _checks
from ._base import AbstractMixture
from ._special import categorical, log_gamma_variates, standard_normal, student_t_cdf


class StudentTMixture(AbstractMixture):
    """Finite mixture of multivariate Student-t distributions `sum_k w_k t_{nu_k}(mu_k, Sigma_k)`.

    Component `k` has density proportional to
    `(1 + (x - mu_k)^T Sigma_k^{-1} (x - mu_k) / nu_k)^{-(nu_k + d) / 2}`: polynomial
    tails, which stress samplers (and Restore regeneration rates) more than Gaussians.
    Its mean exists only for `nu_k > 1` and its covariance `nu_k / (nu_k - 2) Sigma_k`
    only for `nu_k > 2`.

    Attributes:
        means: component locations, shape `(k, d)`.
        scales: component scale matrices `Sigma_k`, shape `(k, d, d)`.
        cholesky_factors: lower Cholesky factors of `scales`, shape `(k, d, d)`.
        dfs: degrees of freedom per component, shape `(k,)`.
        weights: normalised weights, shape `(k,)`.
        dim: the dimension `d` (static).
        min_df: the smallest degree of freedom, recorded at construction for the
            existence checks of `mean` and `covariance` (static; `None` when the
            module was built from traced values, then undefined moments are NaN).
    """

    means: Float[Array, "k d"]
    scales: Float[Array, "k d d"]
    cholesky_factors: Float[Array, "k d d"]
    dfs: Float[Array, " k"]
    weights: Float[Array, " k"]
    dim: int = eqx.field(static=True)
    min_df: float | None = eqx.field(static=True)

    def __init__(
        self,
        means: ArrayLike,
        scales: ArrayLike,
        dfs: ArrayLike,
        weights: ArrayLike | None = None,
    ):
        """Arguments:
            means: component locations, shape `(k, d)`; fixes `k` and `d`.
            scales: component scale matrices, as a scalar, `(k,)`, `(k, d)` diagonals
                or `(k, d, d)` symmetric positive-definite matrices (same forms as
                `GaussianMixture` covariances). They are not the covariances.
            dfs: degrees of freedom, a positive scalar shared by all components or
                shape `(k,)`; smaller means heavier tails.
            weights: positive component weights of shape `(k,)`, normalised here.
                `None` means equal weights.

        Raises:
            ValueError: on wrong shapes, non-finite values, scales that are not
                positive definite, `dfs <= 0` or weights that are not positive.
        """
        means = _checks.mixture_means(means)
        k, d = means.shape
        scales = _checks.float_array(scales, "scales")
        dfs = _checks.float_array(dfs, "dfs")
        dtype = jnp.result_type(means, scales, dfs)
        if weights is not None:
            dtype = jnp.result_type(dtype, _checks.float_array(weights, "weights"))
        if dfs.ndim == 0:
            dfs = jnp.broadcast_to(dfs, (k,))
        if dfs.shape != (k,):
            raise ValueError(f"dfs must be a scalar or have shape ({k},), got shape {dfs.shape}")
        df_values = _checks.concrete(dfs)
        if df_values is not None and not (np.all(np.isfinite(df_values)) and np.all(df_values > 0)):
            raise ValueError(f"dfs (degrees of freedom) must be finite and > 0, got {df_values}")
        self.means = means.astype(dtype)
        self.scales = _checks.matrix_stack(scales, k, d, "scales", dtype)
        self.cholesky_factors = _checks.cholesky_stack(self.scales, "scales")
        self.dfs = dfs.astype(dtype)
        self.weights = _checks.mixture_weights(weights, k, dtype)
        self.dim = d
        self.min_df = None if df_values is None else float(np.min(df_values))

    def component_logdensities(self, x: Float[Array, " d"]) -> Float[Array, " k"]:
        x = _checks.point(x, self.dim)
        d = self.dim
        diff = x - self.means
        z = jax.vmap(lambda chol, r: solve_triangular(chol, r, lower=True))(
            self.cholesky_factors, diff
        )
        maha = jnp.sum(z * z, axis=-1)
        half_logdet = jnp.sum(
            jnp.log(jnp.diagonal(self.cholesky_factors, axis1=-2, axis2=-1)), axis=-1
        )
        nu = self.dfs
        log_norm = (
            gammaln(0.5 * (nu + d))
            - gammaln(0.5 * nu)
            - 0.5 * d * (jnp.log(nu) + math.log(math.pi))
            - half_logdet
        )
        return log_norm - 0.5 * (nu + d) * jnp.log1p(maha / nu)

    def component_marginal_cdfs(self, i: int, t: Float[Array, "*t"]) -> Float[Array, "*t k"]:
        sd = jnp.sqrt(self.scales[:, i, i])
        return student_t_cdf((t[..., None] - self.means[:, i]) / sd, self.dfs)

    def _require_df_above(self, bound: float, what: str) -> None:
        if self.min_df is not None and self.min_df <= bound:
            raise ValueError(
                f"the {what} of a Student-t mixture exists only if every df > {bound:g}; "
                f"the smallest df is {self.min_df:g}"
            )

    @property
    def component_means(self) -> Float[Array, "k d"]:
        self._require_df_above(1.0, "mean")
        return jnp.where((self.dfs > 1)[:, None], self.means, jnp.nan)

    @property
    def component_covariances(self) -> Float[Array, "k d d"]:
        self._require_df_above(2.0, "covariance")
        factor = jnp.where(self.dfs > 2, self.dfs / (self.dfs - 2), jnp.nan)
        return factor[:, None, None] * self.scales

    def _sample_with_modes(
        self, key: PRNGKeyArray, n: int
    ) -> tuple[Float[Array, "n d"], Int[Array, " n"]]:
        key_mode, key_normal, key_gamma = jax.random.split(key, 3)
        modes = categorical(key_mode, self.weights, n)
        z = standard_normal(key_normal, (n, self.dim), self.means.dtype)
        nu = self.dfs[modes]
        # chi^2_nu / nu = 2 Gamma(nu / 2) / nu, drawn in log space so tiny draws cannot underflow.
        log_gamma = log_gamma_variates(key_gamma, 0.5 * nu)
        inv_sqrt_mixing = jnp.exp(0.5 * (jnp.log(0.5 * nu) - log_gamma))
        x = self.means[modes] + inv_sqrt_mixing[:, None] * jnp.einsum(
            "nij,nj->ni", self.cholesky_factors[modes], z
        )
        return x, modes
