"""Metropolis-adjusted Langevin: gradient-informed local dynamics."""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from .._point import Point
from .._validation import as_scale, check_vector_dim
from ._base import AbstractLocalKernel, LocalInfo, gradient_of, hastings_accept


class MALA(AbstractLocalKernel):
    """Metropolis-adjusted Langevin kernel.

    Proposes `y = x + h * grad log p(x) + sqrt(2 h) * N(0, I)` and corrects it with a
    Metropolis-Hastings test, so one move needs one value-and-gradient evaluation.

    Arguments:
        step_size: `h`, a positive scalar or one per coordinate `(d,)` (a diagonal
            preconditioner).
    """

    step_size: Float[Array, "*d"]
    uses_gradient = True

    def __init__(self, step_size: float | Array = 0.1):
        self.step_size = as_scale(step_size, "step_size")

    def check_dim(self, dim: int) -> None:
        check_vector_dim(self.step_size, dim, "MALA step_size")

    def _log_q(self, to: Array, start: Point) -> Array:
        """Log density (up to a constant) of proposing `to` from `start`."""
        mean = start.position + self.step_size * gradient_of(start)
        return -jnp.sum((to - mean) ** 2 / (4.0 * self.step_size))

    def propose(self, key: PRNGKeyArray, point: Point, logdensity_fn: Callable) -> tuple[Array, None]:
        x = point.position
        noise = jax.random.normal(key, x.shape, x.dtype)
        return x + self.step_size * gradient_of(point) + jnp.sqrt(2.0 * self.step_size) * noise, None

    def accept(self, key: PRNGKeyArray, point: Point, candidate: Point, aux: None) -> tuple[Point, LocalInfo]:
        return hastings_accept(key, point, candidate, self._log_q)
