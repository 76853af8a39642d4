"""Neal's funnel."""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
from jax.scipy.special import ndtr
from jaxtyping import Array, Float, PRNGKeyArray

from . import _checks
from ._base import AbstractTarget
from ._special import standard_normal


class Funnel(AbstractTarget):
    """Neal's funnel: `v = x_0 ~ N(0, scale^2)` and `x_j | v ~ N(0, exp(v))` for `j >= 1`.

    The conditional scale of `x_1, ..., x_{d-1}` changes by orders of magnitude with
    `v`, so no single step size fits: a narrow neck (`v << 0`) next to a wide mouth.
    Mean zero; covariance `diag(scale^2, exp(scale^2 / 2), ..., exp(scale^2 / 2))`.
    `marginal_cdf` exists only for coordinate 0 (the others are scale mixtures of
    normals without a closed-form CDF).

    Attributes:
        dim: the dimension `d >= 2` (static).
        scale: standard deviation of `v = x_0` (static).
    """

    dim: int = eqx.field(static=True)
    scale: float = eqx.field(static=True)

    def __init__(self, dim: int = 10, scale: float = 3.0):
        """Arguments:
            dim: the dimension, at least 2 (`v` plus at least one funnel coordinate).
            scale: standard deviation of `v`, positive; larger makes the neck narrower
                and the mouth wider (Neal used 3).

        Raises:
            ValueError: for `dim < 2` or a non-positive scale.
        """
        self.dim = _checks.integer(dim, "dim", 2)
        self.scale = _checks.positive_float(scale, "scale")

    def logdensity(self, x: Float[Array, " d"]) -> Float[Array, ""]:
        x = _checks.point(x, self.dim)
        v = x[0]
        rest = x[1:]
        q = jnp.sum(rest * rest)
        # q * exp(-v) computed as exp(log q - v): no inf * 0 = NaN deep in the neck.
        positive = q > 0
        quad = jnp.where(positive, jnp.exp(jnp.log(jnp.where(positive, q, 1.0)) - v), 0.0)
        k = self.dim - 1
        return (
            -0.5 * (v / self.scale) ** 2
            - math.log(self.scale)
            - 0.5 * k * v
            - 0.5 * quad
            - 0.5 * self.dim * math.log(2 * math.pi)
        )

    def _sample(self, key: PRNGKeyArray, n: int) -> Float[Array, "n d"]:
        z = standard_normal(key, (n, self.dim))
        v = self.scale * z[:, :1]
        return jnp.concatenate([v, jnp.exp(0.5 * v) * z[:, 1:]], axis=1)

    @property
    def mean(self) -> Float[Array, " d"]:
        return jnp.zeros((self.dim,))

    @property
    def covariance(self) -> Float[Array, "d d"]:
        # Var(x_j) = E[exp(v)] = exp(scale^2 / 2); all cross-covariances vanish.
        var = jnp.full((self.dim,), jnp.exp(0.5 * self.scale**2))
        return jnp.diag(var.at[0].set(self.scale**2))

    def _marginal_cdf(self, i: int, t: Float[Array, ...]) -> Float[Array, ...]:
        if i != 0:
            raise NotImplementedError(
                "Funnel: only coordinate 0 (v ~ N(0, scale^2)) has a closed-form marginal "
                f"CDF; coordinate {i} is a scale mixture of normals without one"
            )
        return ndtr(t / self.scale)
