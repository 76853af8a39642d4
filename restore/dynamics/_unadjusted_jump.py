"""Unadjusted Gaussian jumps: always-accepted random-walk moves, with their adjoint from a known convolution."""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from .._point import Point
from .._validation import as_scale, check_positive, check_vector_dim
from ..local import LocalInfo
from ._base import AbstractJumpDynamics
from ._diffusion import sanitize_ratio


class UnadjustedJump(AbstractJumpDynamics):
    """Gaussian random-walk jumps `y = x + scale N(0, I)`, always accepted, at rate `rate`.

    With no Metropolis correction the kernel `zeta(x, y) = N(y; x, scale^2 I)` does not
    leave the target invariant, so the killing rate needs
    `L* p / p = rate (∫ p(x) N(y; x, scale^2 I) dx / p(y) - 1)`. The convolution must be
    known: pass it as `log_convolution`. For a Gaussian mixture target it is the mixture
    widened by `scale^2`, e.g.
    `UnadjustedJump(s, log_convolution=mixture.smoothed(s**2).logdensity)`.

    Arguments:
        scale: jump standard deviation, a positive scalar or one per coordinate `(d,)`
            (then the kernel is `N(y; x, diag(scale^2))`).
        log_convolution: `y -> log ∫ p(x) N(y; x, diag(scale^2)) dx` for one point `(d,)`,
            in the same normalisation as the `logdensity_fn` the sampler uses (a wrong
            constant biases the killing rate).
        rate: rate `r > 0` of the jumps (mean holding time `1/r`).
    """

    scale: Float[Array, "*d"]
    log_convolution_fn: Callable[[Array], Array]
    rate: float = eqx.field(static=True)

    def __init__(self, scale: float | Array, log_convolution: Callable[[Array], Array], rate: float = 1.0):
        if not callable(log_convolution):
            raise TypeError(
                "log_convolution must be a callable y -> log ∫ p(x) N(y; x, scale^2 I) dx, "
                f"got {type(log_convolution).__name__}"
            )
        self.scale = as_scale(scale, "scale")
        self.log_convolution_fn = log_convolution
        self.rate = check_positive(rate, "rate")

    def check_dim(self, dim: int) -> None:
        check_vector_dim(self.scale, dim, "UnadjustedJump scale")

    def log_convolution(self, position: Float[Array, " d"]) -> Float[Array, ""]:
        return self.log_convolution_fn(position)

    def adjoint_ratio(self, logdensity_fn: Callable[[Array], Array], point: Point) -> Float[Array, ""]:
        """`rate (exp(log_convolution(y) - log p(y)) - 1)`; `+inf` where `p(y)` is zero or the value is NaN."""
        return sanitize_ratio(super().adjoint_ratio(logdensity_fn, point), point.logdensity)

    def propose(self, key: PRNGKeyArray, point: Point, logdensity_fn: Callable[[Array], Array]) -> tuple[Array, None]:
        x = point.position
        return x + self.scale.astype(x.dtype) * jax.random.normal(key, x.shape, x.dtype), None

    def accept(self, key: PRNGKeyArray, point: Point, candidate: Point, aux: None) -> tuple[Point, LocalInfo]:
        dtype = point.logdensity.dtype
        return candidate, LocalInfo(jnp.asarray(True), jnp.ones((), dtype))
