"""The Ornstein-Uhlenbeck process: a mean-reverting diffusion with an exact Gaussian transition."""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray

from .._point import Point
from .._validation import as_float_array, as_scale, check_vector_dim
from ._base import AbstractDiffusion
from ._diffusion import log_derivatives, sanitize_ratio, second_order_term


def _check_mean(value, name: str) -> Array:
    """A finite scalar or vector `(d,)`, kept as a float array."""
    arr = as_float_array(value, name)
    if arr.ndim > 1:
        raise ValueError(f"{name} must be a scalar or a vector of shape (d,), got shape {arr.shape}")
    if not isinstance(arr, jax.core.Tracer) and not np.all(np.isfinite(np.asarray(arr))):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return arr


class OrnsteinUhlenbeck(AbstractDiffusion):
    """The Ornstein-Uhlenbeck process `dY = -rate (Y - mean) dt + scale dW`.

    Moves exactly: `Y_t = mean + e^{-rate t} (Y_0 - mean) + sqrt(scale^2 (1 - e^{-2 rate t}) / (2 rate)) N(0, I)`,
    coordinate by coordinate. It leaves `N(mean, scale^2 / (2 rate) I)` invariant, not the
    target; its adjoint is
    `L* p / p = sum_i rate_i + sum_i rate_i (x_i - mean_i) g_i + sum_i scale_i^2 / 2 (H_ii + g_i^2)`
    with `g`, `H` the gradient and Hessian of `log p` (autodiff). Pulling towards `mean`
    keeps tours near the bulk of the target, which Brownian motion does not.

    Arguments:
        mean: the centre of attraction, a scalar or a vector `(d,)`, finite.
        rate: the mean-reversion rate `theta > 0` (`1 / rate` is the relaxation time), a
            scalar or one per coordinate `(d,)`.
        scale: the volatility, positive, a scalar or one per coordinate `(d,)`.
    """

    mean: Float[Array, "*d"]
    rate: Float[Array, "*d"]
    scale: Float[Array, "*d"]

    def __init__(self, mean: float | Array = 0.0, rate: float | Array = 1.0, scale: float | Array = 1.0):
        self.mean = _check_mean(mean, "mean")
        self.rate = as_scale(rate, "rate")
        self.scale = as_scale(scale, "scale")

    def check_dim(self, dim: int) -> None:
        check_vector_dim(self.mean, dim, "OrnsteinUhlenbeck mean")
        check_vector_dim(self.rate, dim, "OrnsteinUhlenbeck rate")
        check_vector_dim(self.scale, dim, "OrnsteinUhlenbeck scale")

    def drift(self, x: Float[Array, " d"]) -> Float[Array, " d"]:
        """`b(x) = -rate (x - mean)`."""
        return -self.rate.astype(x.dtype) * (x - self.mean.astype(x.dtype))

    def adjoint_ratio(self, logdensity_fn: Callable[[Array], Array], point: Point) -> Float[Array, ""]:
        x = point.position
        logp, grad, hessian = log_derivatives(logdensity_fn, x)
        dtype = hessian.dtype
        rate = jnp.broadcast_to(self.rate.astype(dtype), x.shape)
        value = (
            jnp.sum(rate)
            + jnp.sum(rate * (x - self.mean.astype(dtype)) * grad)
            + second_order_term(grad, hessian, (self.scale**2).astype(dtype))
        )
        return sanitize_ratio(sanitize_ratio(value, logp), point.logdensity)

    def advance(
        self,
        key: PRNGKeyArray,
        position: Float[Array, " d"],
        duration: Float[Array, ""],
        logdensity_fn: Callable[[Array], Array],
    ) -> Float[Array, " d"]:
        dtype = position.dtype
        t = jnp.asarray(duration, dtype)
        rate, mean, scale = (v.astype(dtype) for v in (self.rate, self.mean, self.scale))
        decay = jnp.exp(-rate * t)
        # -expm1 keeps the variance accurate for short durations.
        variance = scale**2 * -jnp.expm1(-2.0 * rate * t) / (2.0 * rate)
        return mean + decay * (position - mean) + jnp.sqrt(variance) * jax.random.normal(key, position.shape, dtype)
