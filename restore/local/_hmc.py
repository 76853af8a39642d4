"""Hamiltonian Monte Carlo with a leapfrog integrator and a diagonal mass matrix."""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from .._point import Point, evaluate
from .._validation import as_scale, check_integer, check_vector_dim
from ._base import AbstractLocalKernel, LocalInfo, gradient_of, metropolis_accept


class _Trajectory(NamedTuple):
    initial_momentum: Array
    momentum: Array  # after the last full momentum update, before the final half step
    invalid: Array  # an evaluation inside the trajectory was NaN or +inf: reject the move


class HMC(AbstractLocalKernel):
    """Hamiltonian Monte Carlo kernel (fixed trajectory length, leapfrog integrator).

    One move costs `num_integration_steps` gradient evaluations: `L - 1` inside the
    trajectory and one at its end, which is the evaluation a sampler shares with its
    regeneration draw.

    Arguments:
        step_size: leapfrog step size (positive).
        num_integration_steps: number of leapfrog steps `L >= 1`.
        inverse_mass_matrix: diagonal of the inverse mass matrix, scalar or `(d,)`.
    """

    step_size: Float[Array, ""]
    num_integration_steps: int
    inverse_mass_matrix: Float[Array, "*d"]
    uses_gradient = True

    def __init__(self, step_size: float = 0.1, num_integration_steps: int = 10, inverse_mass_matrix=1.0):
        self.step_size = as_scale(step_size, "step_size")
        if self.step_size.ndim != 0:
            raise ValueError("HMC step_size must be a scalar; use inverse_mass_matrix to precondition")
        self.num_integration_steps = check_integer(num_integration_steps, "num_integration_steps", minimum=1)
        self.inverse_mass_matrix = as_scale(inverse_mass_matrix, "inverse_mass_matrix")

    def check_dim(self, dim: int) -> None:
        check_vector_dim(self.inverse_mass_matrix, dim, "HMC inverse_mass_matrix")

    def _kinetic(self, momentum: Array) -> Array:
        return 0.5 * jnp.sum(self.inverse_mass_matrix * momentum**2)

    def propose(self, key: PRNGKeyArray, point: Point, logdensity_fn: Callable) -> tuple[Array, _Trajectory]:
        x = point.position
        eps = self.step_size.astype(x.dtype)
        p0 = jax.random.normal(key, x.shape, x.dtype) / jnp.sqrt(self.inverse_mass_matrix)
        p = p0 + 0.5 * eps * gradient_of(point)
        q = x + eps * self.inverse_mass_matrix * p

        def inner(carry, _):
            q, p, invalid = carry
            inner_point, bad = evaluate(logdensity_fn, q, with_grad=True)
            p = p + eps * gradient_of(inner_point)
            q = q + eps * self.inverse_mass_matrix * p
            return (q, p, invalid | bad), None

        init = (q, p, jnp.zeros((), bool))
        (q, p, invalid), _ = jax.lax.scan(inner, init, None, length=self.num_integration_steps - 1)
        return q, _Trajectory(p0, p, invalid)

    def accept(self, key: PRNGKeyArray, point: Point, candidate: Point, aux: _Trajectory) -> tuple[Point, LocalInfo]:
        final_momentum = aux.momentum + 0.5 * self.step_size * gradient_of(candidate)
        log_ratio = (
            candidate.logdensity
            - self._kinetic(final_momentum)
            - point.logdensity
            + self._kinetic(aux.initial_momentum)
        )
        log_ratio = jnp.where(aux.invalid, -jnp.inf, log_ratio)
        return metropolis_accept(key, point, candidate, log_ratio)
