"""The autoregressive (Crank-Nicolson-type) Gaussian transfer: a partial refresh of the exit point."""

from __future__ import annotations

import math
from typing import ClassVar, final

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from .._linalg import mahalanobis_sq
from .._validation import as_float_array, check_point, is_concrete
from ..regeneration import Gaussian
from ._base import AbstractTransfer


@final
class AutoregressiveGaussian(AbstractTransfer):
    """Autoregressive Gaussian transfer `y = m + rho (x_exit - m) + sqrt(1 - rho^2) L eps`.

    Here `eps ~ N(0, I)` and `L L^T = S`. If `x_exit ~ N(m, S)` then `y ~ N(m, S)`, so the
    kernel leaves the reference `Gaussian(m, S)` invariant, while the next tour starts
    near the exit point: the correlation between `x_exit` and `y` is `rho` in every
    coordinate (`Cov(x_exit, y) = rho S`). `rho = 0` is independent regeneration from
    `N(m, S)`; `rho -> 1` keeps the process where it was killed.

    Arguments:
        mean: the reference mean `m`, shape `(d,)`; fixes the dimension.
        covariance: the reference covariance `S`: a scalar variance, a `(d,)` diagonal or
            a symmetric positive-definite `(d, d)` matrix (as for `regeneration.Gaussian`).
        correlation: the autoregression coefficient `rho`, a scalar in `[0, 1)`; how much
            of the exit point the next start keeps.

    Raises:
        ValueError: for a bad mean or covariance (see `regeneration.Gaussian`), or a
            correlation that is not a scalar in `[0, 1)`.
    """

    reference: Gaussian
    correlation: Float[Array, ""]
    is_independent: ClassVar[bool] = False

    def __init__(self, mean: ArrayLike, covariance: ArrayLike, correlation: ArrayLike):
        self.reference = Gaussian(mean, covariance)
        rho = as_float_array(correlation, "correlation")
        if rho.ndim != 0:
            raise ValueError(f"`correlation` must be a scalar, got shape {rho.shape}.")
        if is_concrete(rho):
            value = float(np.asarray(rho))
            if not 0.0 <= value < 1.0:  # also False for NaN
                raise ValueError(f"`correlation` must lie in [0, 1), got {value!r}.")
        self.correlation = rho

    @property
    def mean(self) -> Float[Array, " d"]:
        """The reference mean `m`."""
        return self.reference.mean

    @property
    def scale_tril(self) -> Float[Array, "d d"]:
        """The lower Cholesky factor `L` of the reference covariance."""
        return self.reference.scale_tril

    def sample(self, key: PRNGKeyArray, exit_position: Float[Array, " d"]) -> Float[Array, " d"]:
        """A start point `m + rho (x_exit - m) + sqrt(1 - rho^2) L eps`, in the dtype of `exit_position`."""
        x = check_point(exit_position, self.dim, "exit_position")
        eps = jax.random.normal(key, x.shape, x.dtype)
        rho = self.correlation
        y = self.mean + rho * (x - self.mean) + jnp.sqrt(1 - rho**2) * (self.scale_tril @ eps)
        return y.astype(x.dtype)

    def log_transition_density(
        self, exit_position: Float[Array, " d"], position: Float[Array, " d"]
    ) -> Float[Array, ""]:
        """`log N(y; m + rho (x_exit - m), (1 - rho^2) S)`, the normalised log density of a start point."""
        x = check_point(exit_position, self.dim, "exit_position")
        y = check_point(position, self.dim, "position")
        rho = self.correlation
        one_minus_rho_sq = 1 - rho**2
        r = y - (self.mean + rho * (x - self.mean))
        maha = mahalanobis_sq(self.scale_tril, r) / one_minus_rho_sq
        log_det_half = jnp.sum(jnp.log(jnp.diag(self.scale_tril))) + 0.5 * self.dim * jnp.log(one_minus_rho_sq)
        return -0.5 * maha - log_det_half - 0.5 * self.dim * math.log(2 * math.pi)
