"""Haario's twisted Gaussian ("banana")."""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
from jax.scipy.special import ndtr
from jaxtyping import Array, Float, PRNGKeyArray

from . import _checks
from ._base import AbstractTarget
from ._special import standard_normal


class Banana(AbstractTarget):
    """Haario et al.'s twisted Gaussian: a curved, strongly non-elliptical ridge.

    Draw `x ~ N(0, diag(scale^2, 1, ..., 1))` and bend the second coordinate,
    `y_1 = x_1 + b (x_0^2 - scale^2)` (0-based), leaving the others unchanged. The
    map has unit Jacobian, so `log p(y) = log N(x(y); 0, diag(scale^2, 1, ..., 1))`.
    Exact moments: mean zero and covariance `diag(scale^2, 1 + 2 b^2 scale^4, 1, ..., 1)`.
    `marginal_cdf` is normal for every coordinate except the bent one (1), which has
    no closed form and raises `NotImplementedError`.

    Attributes:
        dim: the dimension `d >= 2` (static).
        curvature: the twist `b` (static); `0` gives a Gaussian.
        scale: standard deviation of coordinate 0 (static).
    """

    dim: int = eqx.field(static=True)
    curvature: float = eqx.field(static=True)
    scale: float = eqx.field(static=True)

    def __init__(self, dim: int = 2, curvature: float = 0.1, scale: float = 10.0):
        """Arguments:
            dim: the dimension, at least 2 (coordinate 1 is bent by coordinate 0).
            curvature: the twist `b`, any finite real; larger `|b|` gives a thinner,
                more curved banana.
            scale: standard deviation of the first coordinate, positive; it sets the
                length of the banana.

        Raises:
            ValueError: for `dim < 2`, a non-finite curvature or a non-positive scale.
        """
        self.dim = _checks.integer(dim, "dim", 2)
        self.curvature = _checks.finite_float(curvature, "curvature")
        self.scale = _checks.positive_float(scale, "scale")

    def _untwist(self, y: Float[Array, "... d"]) -> Float[Array, "... d"]:
        y0 = y[..., 0]
        x1 = y[..., 1] - self.curvature * (y0 * y0 - self.scale**2)
        return y.at[..., 1].set(x1)

    def logdensity(self, x: Float[Array, " d"]) -> Float[Array, ""]:
        y = _checks.point(x, self.dim)
        u = self._untwist(y)
        u = u.at[0].divide(self.scale)
        return (
            -0.5 * jnp.sum(u * u)
            - math.log(self.scale)
            - 0.5 * self.dim * math.log(2 * math.pi)
        )

    def _sample(self, key: PRNGKeyArray, n: int) -> Float[Array, "n d"]:
        x = standard_normal(key, (n, self.dim))
        x0 = self.scale * x[:, 0]
        x = x.at[:, 0].set(x0)
        return x.at[:, 1].add(self.curvature * (x0 * x0 - self.scale**2))

    @property
    def mean(self) -> Float[Array, " d"]:
        return jnp.zeros((self.dim,))

    @property
    def covariance(self) -> Float[Array, "d d"]:
        # Var(x_1 + b (x_0^2 - s^2)) = 1 + b^2 Var(x_0^2) = 1 + 2 b^2 s^4, and
        # Cov(x_0, b x_0^2) = b E[x_0^3] = 0.
        var = jnp.ones((self.dim,))
        var = var.at[0].set(self.scale**2)
        var = var.at[1].set(1.0 + 2.0 * self.curvature**2 * self.scale**4)
        return jnp.diag(var)

    def _marginal_cdf(self, i: int, t: Float[Array, ...]) -> Float[Array, ...]:
        if i == 1:
            raise NotImplementedError(
                "Banana: coordinate 1 (the bent one) has no closed-form marginal CDF; "
                "coordinate 0 is N(0, scale^2) and coordinates >= 2 are N(0, 1)"
            )
        sd = self.scale if i == 0 else 1.0
        return ndtr(t / sd)
