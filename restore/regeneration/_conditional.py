"""A Gaussian for each coordinate given the ones before it: a regeneration that bends.

Mixtures of fixed ellipsoids approximate a curved target (a banana's ridge, a funnel's
neck) only with many components, and none of them reaches further than the draws they
were fitted to. Here the coordinates are standardised, `y = (x - loc) / scale`, and

    y_i | y_<i  ~  N(m_i, exp(v_i)),   m_i = a_i . [1, y_<i, y_<i^2],   v_i = c_i . [1, y_<i],

so a mean that follows a parabola (Haario's banana) and a spread that grows or shrinks
exponentially along earlier coordinates (Neal's funnel, hierarchical scales) are exact
members, and the log-linear spread extends a funnel's neck beyond the fitted draws. It is
an affine autoregressive flow with polynomial conditioners: draws coordinate by
coordinate, an exact normalised density in `O(d^2)`.
"""

from __future__ import annotations

import math
from typing import final

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from .._validation import as_float_array, check_point, check_shape
from ._base import AbstractRegeneration
from ._diagonal_mixture import check_df, log_chi2_over_df

#: The conditional log variances (standardised coordinates) are clipped to this range, in
#: the density and the draws alike, so that far from the fitted draws the spread stays finite.
LOG_VARIANCE_RANGE = (-40.0, 12.0)


def mean_features(y):
    """`[1, y, y^2]` along the last axis (`(..., 2 d + 1)`), NumPy or JAX."""
    xp = jnp if isinstance(y, jax.Array) else np
    return xp.concatenate([xp.ones_like(y[..., :1]), y, y**2], axis=-1)


def variance_features(y):
    """`[1, y]` along the last axis (`(..., d + 1)`), NumPy or JAX."""
    xp = jnp if isinstance(y, jax.Array) else np
    return xp.concatenate([xp.ones_like(y[..., :1]), y], axis=-1)


def conditional_log_density(z2, v, df: float | None):
    """The conditionals' log densities at squared standardised residuals `z2` with log variances
    `v` (Gaussian, or Student-t with `df`), NumPy or JAX: the density's and the fit's one formula."""
    if df is None:
        return -0.5 * (z2 + v) - 0.5 * math.log(2 * math.pi)
    xp = jnp if isinstance(z2, jax.Array) else np
    const = math.lgamma(0.5 * (df + 1)) - math.lgamma(0.5 * df) - 0.5 * math.log(df * math.pi)
    return const - 0.5 * v - 0.5 * (df + 1) * xp.log1p(z2 / df)


def coefficient_masks(d: int) -> tuple[np.ndarray, np.ndarray]:
    """Which coefficients may be non-zero: row `i` of the mean's `(d, 2d + 1)` and the log
    variance's `(d, d + 1)` sees the intercept and the coordinates before `i` only."""
    before = np.tri(d, d, -1, dtype=bool)
    ones = np.ones((d, 1), bool)
    return np.concatenate([ones, before, before], axis=1), np.concatenate([ones, before], axis=1)


@final
class ConditionalGaussian(AbstractRegeneration):
    """Each standardised coordinate Gaussian (or Student-t) given the earlier ones (mean quadratic, log variance linear in them).

    Attributes:
        loc: `(d,)` centre of the standardisation.
        scale: `(d,)` its scales.
        mean_coefficients: `(d, 2 d + 1)`: row `i` gives `m_i` from `[1, y, y^2]` (zero at
            and after `i`).
        log_variance_coefficients: `(d, d + 1)`: row `i` gives `v_i` from `[1, y]` (zero at
            and after `i`).
        df: `None` (Gaussian conditionals) or Student-t degrees of freedom (static).
        dim: the dimension `d` (static).
    """

    loc: Float[Array, " d"]
    scale: Float[Array, " d"]
    mean_coefficients: Float[Array, "d m"]
    log_variance_coefficients: Float[Array, "d v"]
    df: float | None = eqx.field(static=True)
    dim: int = eqx.field(static=True)

    def __init__(
        self, loc: ArrayLike, scale: ArrayLike, mean_coefficients: ArrayLike, log_variance_coefficients: ArrayLike, df: float | None = None
    ):
        """Arguments:
            loc: `(d,)` centre.
            scale: `(d,)` positive scales.
            mean_coefficients: `(d, 2 d + 1)`; entries for coordinates at or after the row's
                own are ignored (set to zero).
            log_variance_coefficients: `(d, d + 1)`; the same.
            df: `None` (Gaussian conditionals) or the degrees of freedom of Student-t
                conditionals (location `m_i`, scale `exp(v_i / 2)`), whose heavier tails
                cover what the fitted draws under-represent.
        """
        loc = as_float_array(loc, "loc")
        if loc.ndim != 1 or loc.shape[0] == 0:
            raise ValueError(f"`loc` must have shape (d,), got {loc.shape}.")
        d, dtype = loc.shape[0], loc.dtype
        scale = np.asarray(as_float_array(scale, "scale"), np.float64)
        a = np.asarray(as_float_array(mean_coefficients, "mean_coefficients"), np.float64)
        c = np.asarray(as_float_array(log_variance_coefficients, "log_variance_coefficients"), np.float64)
        for name, value, shape in (("scale", scale, (d,)), ("mean_coefficients", a, (d, 2 * d + 1)), ("log_variance_coefficients", c, (d, d + 1))):
            if value.shape != shape:
                raise ValueError(f"`{name}` must have shape {shape}, got {value.shape}.")
            if not np.all(np.isfinite(value)):
                raise ValueError(f"`{name}` must be finite.")
        if not np.all(scale > 0):
            raise ValueError("`scale` must be strictly positive.")
        if not np.all(np.isfinite(np.asarray(loc))):
            raise ValueError("`loc` must be finite.")
        mean_mask, variance_mask = coefficient_masks(d)
        self.loc = loc
        self.scale = jnp.asarray(scale, dtype)
        self.mean_coefficients = jnp.asarray(np.where(mean_mask, a, 0.0), dtype)
        self.log_variance_coefficients = jnp.asarray(np.where(variance_mask, c, 0.0), dtype)
        self.df = check_df(df)
        self.dim = d

    def _moments(self, y: Array) -> tuple[Array, Array]:
        """Every coordinate's conditional mean and log variance given `y` `(d,)`."""
        low, high = LOG_VARIANCE_RANGE
        v = jnp.clip(self.log_variance_coefficients @ variance_features(y), low, high)
        return self.mean_coefficients @ mean_features(y), v

    def log_prob(self, x: Float[Array, " d"]) -> Float[Array, ""]:
        x = check_point(x, self.dim, "x")
        y = (x - self.loc) / self.scale
        m, v = self._moments(y)
        z2 = (y - m) ** 2 * jnp.exp(-v)
        return jnp.sum(conditional_log_density(z2, v, self.df)) - jnp.sum(jnp.log(self.scale))

    def sample(self, key: PRNGKeyArray, shape: tuple[int, ...] = ()) -> Float[Array, "*shape d"]:
        shape = check_shape(shape)
        k_z, k_w = jax.random.split(key)
        z = jax.random.normal(k_z, shape + (self.dim,), dtype=self.loc.dtype).reshape(-1, self.dim)
        if self.df is not None:  # one chi-square scale per coordinate: independent Student-t noise
            z = z * jnp.exp(-0.5 * log_chi2_over_df(k_w, self.df, z.shape, z.dtype))

        def one(noise):
            def coordinate(i, y):  # y_i from the coordinates before it (the later ones are still 0)
                m, v = self._moments(y)
                return y.at[i].set(m[i] + jnp.exp(0.5 * v[i]) * noise[i])

            return jax.lax.fori_loop(0, self.dim, coordinate, jnp.zeros_like(noise))

        y = jax.vmap(one)(z)
        return (self.loc + self.scale * y).reshape(shape + (self.dim,))

    def conditional_scales(self, x: Float[Array, "n d"]) -> Float[Array, "n d"]:
        """Each coordinate's conditional standard deviation at points `x` `(n, d)`."""
        y = (jnp.asarray(x, self.loc.dtype) - self.loc) / self.scale
        v = jax.vmap(lambda row: self._moments(row)[1])(y)
        return self.scale * jnp.exp(0.5 * v)
