"""The starting information every sampler gets: broad random starts and the Laplace mixture built from them."""

from __future__ import annotations

from typing import NamedTuple

import jax
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray

from ..regeneration import AbstractRegeneration, laplace_mixture
from ._problems import Problem


class StartingInformation(NamedTuple):
    """What every sampler is given before it starts.

    `starts` are `problem.num_starts` points from the broad distribution
    `start_scale * N(0, I)`. `regeneration` is the equal-weight mixture of Student-t
    (df 5) Laplace approximations at the modes optimistix finds from those starts: it
    is jump Restore's regeneration distribution, the MH baselines' large-step
    distribution, and the distribution every lane, walker and chain starts from.
    Equal weights mean that no sampler is told the mode weights.
    """

    starts: Float[Array, "n d"]
    regeneration: AbstractRegeneration
    num_modes_found: int

    def initial_points(self, key: PRNGKeyArray, n: int) -> np.ndarray:
        """`n` independent draws of the regeneration distribution, as numpy (n, d)."""
        keys = jax.random.split(key, int(n))
        return np.asarray(jax.vmap(self.regeneration.sample)(keys), np.float64)


def starting_information(problem: Problem, key: PRNGKeyArray) -> StartingInformation:
    """Draw the broad starts for `problem` and build the Laplace mixture from them."""
    starts = problem.start_scale * jax.random.normal(key, (problem.num_starts, problem.dim))
    nu = laplace_mixture(problem.logdensity, starts, tails="student_t", df=5.0, weights="equal")
    return StartingInformation(starts, nu, len(nu.components))
