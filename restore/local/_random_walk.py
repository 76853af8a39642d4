"""Random-walk Metropolis: the simplest local dynamics."""

from __future__ import annotations

from collections.abc import Callable
from typing import ClassVar

import jax
from jaxtyping import Array, Float, PRNGKeyArray

from .._point import Point
from .._validation import as_scale, check_vector_dim
from ._base import AbstractLocalKernel, LocalInfo, metropolis_accept


class RandomWalk(AbstractLocalKernel):
    """Gaussian random-walk Metropolis kernel, `y = x + scale * N(0, I)`.

    Arguments:
        scale: proposal standard deviation, a positive scalar or one per coordinate `(d,)`.
    """

    scale: Float[Array, "*d"]
    proposes_from_position: ClassVar[bool] = True

    def __init__(self, scale: float | Array = 1.0):
        self.scale = as_scale(scale, "scale")

    def check_dim(self, dim: int) -> None:
        check_vector_dim(self.scale, dim, "RandomWalk scale")

    def propose(self, key: PRNGKeyArray, point: Point, logdensity_fn: Callable) -> tuple[Array, None]:
        x = point.position
        return x + self.scale * jax.random.normal(key, x.shape, x.dtype), None

    def accept(self, key: PRNGKeyArray, point: Point, candidate: Point, aux: None) -> tuple[Point, LocalInfo]:
        return metropolis_accept(key, point, candidate, candidate.logdensity - point.logdensity)
