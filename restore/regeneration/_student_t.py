"""Multivariate Student-t regeneration distribution."""

from __future__ import annotations

import math
from typing import final

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import betaln, gammaln
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from .._linalg import half_log_det, inverse_tril, mahalanobis_sq
from .._threefry import loggamma
from .._validation import as_float_array, check_point, check_shape, check_vector, is_concrete
from ._base import AbstractRegeneration
from ._utils import scale_tril

#: Integer degrees of freedom up to this use the sum-of-squares chi-square draw.
_MAX_INTEGER_DF = 64


def _log_gamma_ratio(a: Array, h: float) -> Array:
    """`log Gamma(a + h) - log Gamma(a)`, accurate for every `a > 0`.

    The plain difference is exact to rounding for moderate `a` but cancels two huge terms
    for large `a` (it is 0 instead of about `h log a` at `a = 1e20`); `betaln` is accurate
    there. (Both branches are kept finite, so gradients stay clean.)
    """
    small = a < _LARGE_HALF_DF
    plain = jnp.where(small, a, 1.0)
    large = jnp.where(small, _LARGE_HALF_DF, a)
    return jnp.where(small, gammaln(plain + h) - gammaln(plain), gammaln(h) - betaln(large, h))


_LARGE_HALF_DF = 1e4


def min_df(dtype) -> float:
    """The smallest degrees of freedom whose draws stay finite in `dtype`.

    A draw is `z / sqrt(w)` with `w ~ Gamma(df / 2) / (df / 2)`, and `P(w < t)` behaves like
    `t^(df / 2)`: below these values a run of billions of draws meets values beyond the
    largest float (about 1e38 in float32, 1e308 in float64) with a probability that is
    no longer negligible.
    """
    return 0.1 if jnp.finfo(dtype).bits >= 64 else 0.5


@final
class StudentT(AbstractRegeneration):
    """Multivariate Student-t distribution `t_df(loc, scale)`.

    Density proportional to `(1 + (x - loc)^T scale^{-1} (x - loc) / df)^{-(df + d)/2}`.
    Its polynomial tails make it a safer regeneration distribution than a
    Gaussian: the kill rate `u(x) / p(x)` stays bounded for a wider class of
    targets. For `df > 2` the covariance is `scale * df / (df - 2)`.

    Attributes:
        loc: the location (the mode), shape `(d,)`.
        scale_tril: lower-triangular `L` with `L @ L.T == scale`, shape `(d, d)`.
        inverse_tril: `L^{-1}`, shape `(d, d)` (kept with `L`: replace both together).
        df: the degrees of freedom, a positive scalar.
        dim: the dimension `d` (static).
    """

    loc: Float[Array, " d"]
    scale_tril: Float[Array, "d d"]
    inverse_tril: Float[Array, "d d"]
    df: Float[Array, ""]
    integer_df: int | None = eqx.field(static=True)
    dim: int = eqx.field(static=True)

    def __init__(self, loc: ArrayLike, scale: ArrayLike = 1.0, df: ArrayLike = 4.0):
        """Arguments:
            loc: the location, a 1-D array of shape `(d,)`; fixes the dimension.
            scale: the scale matrix `Sigma`, as a scalar (isotropic), a `(d,)`
                diagonal or a symmetric positive-definite `(d, d)` matrix.
                Defaults to the identity.
            df: degrees of freedom, a positive scalar; smaller means heavier
                tails. Defaults to 4. At least 0.1 in float64 (0.5 in float32):
                with fewer, draws overflow to infinity.

        Raises:
            ValueError: for a location that is not 1-D, a scale of the wrong shape
                or not positive definite, or a non-positive / non-finite `df`.
        """
        loc = check_vector(loc, "loc")
        self.dim = loc.shape[0]
        tril = scale_tril(scale, self.dim, "scale")
        df = as_float_array(df, "df")
        if df.ndim != 0:
            raise ValueError(f"`df` must be a scalar, got shape {df.shape}.")
        if is_concrete(df):
            v = float(np.asarray(df))
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"`df` must be finite and strictly positive, got {v}.")
        dtype = jnp.result_type(loc.dtype, tril.dtype)
        if is_concrete(df):
            smallest = min_df(dtype)
            if float(np.asarray(df)) < smallest:
                raise ValueError(
                    f"`df` = {float(np.asarray(df)):.3g} is too small for {jnp.dtype(dtype).name}: a Student-t with "
                    f"fewer than {smallest} degrees of freedom has draws beyond the largest {jnp.dtype(dtype).name} "
                    f"(they overflow to infinity); use df >= {smallest}"
                )
        self.loc = loc.astype(dtype)
        self.scale_tril = tril.astype(dtype)
        self.inverse_tril = inverse_tril(self.scale_tril)
        self.df = df.astype(dtype)
        # A small integer df draws chi2(df) as a sum of squared normals: exact, and much
        # cheaper to compile and run than the rejection sampler behind loggamma.
        self.integer_df = None
        if is_concrete(df):
            v = float(np.asarray(df))
            if v == round(v) and 1 <= v <= _MAX_INTEGER_DF:
                self.integer_df = int(v)

    @property
    def scale(self) -> Float[Array, "d d"]:
        """The scale matrix `L @ L.T`."""
        return self.scale_tril @ self.scale_tril.T

    def sample(
        self, key: PRNGKeyArray, shape: tuple[int, ...] = ()
    ) -> Float[Array, "*shape d"]:
        """Exact draws `loc + L z / sqrt(w)`, `z ~ N(0, I)`, `w ~ chi2(df) / df`.

        The chi-square variable is a sum of `df` squared normals when `df` is a
        small integer, else drawn in log space (`jax.random.loggamma`), so small
        `df` cannot produce a division by zero.

        Arguments:
            key: a JAX PRNG key.
            shape: batch shape; the result has shape `(*shape, d)`.
        """
        shape = check_shape(shape)
        dtype = self.loc.dtype
        key_z, key_w = jax.random.split(key)
        z = jax.random.normal(key_z, shape + (self.dim,), dtype=dtype)
        if self.integer_df is not None:
            normals = jax.random.normal(key_w, shape + (self.integer_df,), dtype=dtype)
            log_w = jnp.log(jnp.sum(normals**2, axis=-1)) - jnp.log(self.df)
        else:
            half_df = 0.5 * self.df
            log_w = loggamma(key_w, half_df, shape, dtype) - jnp.log(half_df)
        return self.loc + (z @ self.scale_tril.T) * jnp.exp(-0.5 * log_w)[..., None]

    def log_prob(self, x: Float[Array, " d"]) -> Float[Array, ""]:
        """Normalised log density of one point `x` of shape `(d,)`."""
        x = check_point(x, self.dim, "x")
        d = self.dim
        # Beyond 1/eps^2 degrees of freedom the density equals the Gaussian limit to working
        # precision; capping df keeps `maha / df` from underflowing (XLA flushes subnormals).
        df = jnp.minimum(self.df, 1.0 / jnp.finfo(self.df.dtype).eps ** 2)
        maha = mahalanobis_sq(self.scale_tril, x - self.loc, self.inverse_tril)
        log_gamma_ratio = _log_gamma_ratio(0.5 * df, 0.5 * d)
        return (
            log_gamma_ratio
            - 0.5 * d * (jnp.log(df) + math.log(math.pi))
            - half_log_det(self.scale_tril)
            - 0.5 * (df + d) * jnp.log1p(maha / df)
        )
