"""Overdamped Langevin diffusion: target-invariant, simulated by Euler-Maruyama."""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from .._point import Point
from .._validation import as_scale, check_vector_dim
from ._base import AbstractDiffusion
from ._diffusion import as_step_size, euler_maruyama


class OverdampedLangevin(AbstractDiffusion):
    """The overdamped Langevin diffusion `dY = scale^2 / 2 grad log p(Y) dt + scale dW`.

    It leaves the target invariant, so `L* p = 0` (`is_invariant = True`) and a Restore
    process kills only through regeneration. The exact process has no closed-form
    transition: `advance` runs Euler-Maruyama sub-steps of length at most `step_size`
    (the unadjusted Langevin algorithm), so the simulated path is **approximate**
    (`is_exact = False`); its bias in distribution shrinks like `step_size`. Each sub-step
    costs one gradient of `log p`.

    Arguments:
        scale: the volatility, a positive scalar or one per coordinate `(d,)` (a diagonal
            preconditioner; the drift uses the same `scale^2`, which keeps the target invariant).
        step_size: the largest Euler-Maruyama sub-step, positive (keyword only: it has
            no default, as a good value depends on the target's length scales).
    """

    scale: Float[Array, "*d"]
    step_size: Float[Array, ""]

    is_invariant = True
    is_exact = False

    def __init__(self, scale: float | Array = 1.0, *, step_size: float | Array):
        self.scale = as_scale(scale, "scale")
        self.step_size = as_step_size(step_size)

    def check_dim(self, dim: int) -> None:
        check_vector_dim(self.scale, dim, "OverdampedLangevin scale")

    def adjoint_ratio(self, logdensity_fn: Callable[[Array], Array], point: Point) -> Float[Array, ""]:
        return jnp.zeros((), point.logdensity.dtype)

    def advance(
        self,
        key: PRNGKeyArray,
        position: Float[Array, " d"],
        duration: Float[Array, ""],
        logdensity_fn: Callable[[Array], Array],
    ) -> Float[Array, " d"]:
        scale = self.scale.astype(position.dtype)
        grad_fn = jax.grad(logdensity_fn)

        def drift(x):
            return 0.5 * scale**2 * grad_fn(x)

        return euler_maruyama(key, position, duration, self.step_size, drift, lambda z: scale * z)
