"""Brownian motion: exact Gaussian increments, the partial-regeneration killing rate."""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from .._point import Point
from .._validation import as_scale, check_vector_dim
from ._base import AbstractDiffusion
from ._diffusion import log_derivatives, sanitize_ratio, second_order_term


class BrownianMotion(AbstractDiffusion):
    """Brownian motion `dY = scale dW`: zero drift, diffusion matrix `a = scale^2 I`.

    Moves exactly (`Y_t = Y_0 + scale sqrt(t) N(0, I)`). It does not leave the target
    invariant; its adjoint is `L* p / p = scale^2 / 2 (|grad log p|^2 + Laplacian log p)`,
    computed from `logdensity_fn` by autodiff (the Hessian trace costs `d` Jacobian-vector
    products). This is the killing rate of Wang et al.'s partial regeneration; it is negative
    where `log p` is strongly concave, near the modes.

    Arguments:
        scale: the volatility, a positive scalar or one per coordinate `(d,)` (then
            `a = diag(scale^2)`).
    """

    scale: Float[Array, "*d"]

    def __init__(self, scale: float | Array = 1.0):
        self.scale = as_scale(scale, "scale")

    def check_dim(self, dim: int) -> None:
        check_vector_dim(self.scale, dim, "BrownianMotion scale")

    def adjoint_ratio(self, logdensity_fn: Callable[[Array], Array], point: Point) -> Float[Array, ""]:
        logp, grad, hessian = log_derivatives(logdensity_fn, point.position)
        value = second_order_term(grad, hessian, (self.scale**2).astype(hessian.dtype))
        return sanitize_ratio(sanitize_ratio(value, logp), point.logdensity)

    def advance(
        self,
        key: PRNGKeyArray,
        position: Float[Array, " d"],
        duration: Float[Array, ""],
        logdensity_fn: Callable[[Array], Array],
    ) -> Float[Array, " d"]:
        dtype = position.dtype
        sd = self.scale.astype(dtype) * jnp.sqrt(jnp.asarray(duration, dtype))
        return position + sd * jax.random.normal(key, position.shape, dtype)
