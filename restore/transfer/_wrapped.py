"""A wrapped Gaussian jump on the unit torus: the uniform distribution is invariant."""

from __future__ import annotations

import math
from typing import ClassVar, final

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from .._validation import as_scale, check_point, check_vector_dim
from ..regeneration import UniformTorus
from ._base import AbstractTransfer


@final
class WrappedGaussianJump(AbstractTransfer):
    """A Gaussian jump on the unit torus `[0, 1)^d`: `y = (x_exit + scale * N(0, I)) mod 1`.

    The jump density depends only on `y - x_exit` (mod 1), so the kernel is doubly
    stochastic and leaves the uniform distribution `UniformTorus(dim)` invariant, whatever
    the scale; the next tour starts near the exit point when `scale` is small.

    Arguments:
        scale: the standard deviation of the jump before wrapping, a positive scalar or
            one per coordinate `(d,)`; how far from the exit point the next tour starts.
            Sampling is exact for any scale; `log_transition_density` is accurate to
            double precision for `scale <= 0.5` (see there).
        dim: the dimension `d` of the torus, a positive int (static).

    Raises:
        TypeError: for a `dim` or a scale that is not a number.
        ValueError: for a `dim` that is not a positive integer, or a scale that is not
            positive and finite or has the wrong shape.
    """

    reference: UniformTorus
    scale: Float[Array, "*d"]
    is_independent: ClassVar[bool] = False
    num_images: ClassVar[int] = 4  # images on each side of the nearest one in the wrapped normal sum

    def __init__(self, scale: ArrayLike, dim: int):
        self.reference = UniformTorus(dim)
        self.scale = as_scale(scale, "WrappedGaussianJump scale")
        check_vector_dim(self.scale, self.reference.dim, "WrappedGaussianJump scale")

    def sample(self, key: PRNGKeyArray, exit_position: Float[Array, " d"]) -> Float[Array, " d"]:
        """A start point `(x_exit + scale * eps) mod 1` in `[0, 1)^d`, in the dtype of `exit_position`."""
        x = check_point(exit_position, self.dim, "exit_position")
        y = jnp.mod(x + self.scale * jax.random.normal(key, x.shape, x.dtype), 1).astype(x.dtype)
        # `mod` of a tiny negative number rounds to exactly 1, outside [0, 1).
        return jnp.where(y >= 1, jnp.zeros_like(y), y)

    def log_transition_density(
        self, exit_position: Float[Array, " d"], position: Float[Array, " d"]
    ) -> Float[Array, ""]:
        """The log wrapped-normal density of `position` given `exit_position`, w.r.t. Lebesgue on `[0, 1)^d`.

        Per coordinate, `log sum_k N(y - x + k; 0, scale^2)` over the image `k` nearest to
        `y - x` and `num_images = 4` images on each side of it. Relative to the infinite sum
        the omitted terms are below `exp(-10 / scale^2)`: `4e-18` at `scale = 0.5` (exact in
        double precision), `5e-5` at `scale = 1`. Exactly `-inf` for a `position` outside
        `[0, 1)^d`.
        """
        x = check_point(exit_position, self.dim, "exit_position")
        y = check_point(position, self.dim, "position")
        inside = jnp.all((y >= 0) & (y < 1))
        diff = y - x
        nearest = diff - jnp.round(diff)  # in [-1/2, 1/2]
        images = jnp.arange(-self.num_images, self.num_images + 1, dtype=nearest.dtype)
        scale = jnp.broadcast_to(self.scale, nearest.shape)[:, None]
        z = (nearest[:, None] + images[None, :]) / scale
        log_terms = -0.5 * z**2 - jnp.log(scale) - 0.5 * math.log(2 * math.pi)
        value = jnp.sum(jax.scipy.special.logsumexp(log_terms, axis=1))
        return jnp.where(inside, value, -jnp.inf)
