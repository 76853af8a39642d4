"""The interface of local dynamics: a pi-invariant Markov kernel split at its one evaluation."""

from __future__ import annotations

import abc
from collections.abc import Callable
from typing import Any, ClassVar, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, PRNGKeyArray

from .._point import Point, evaluate
from .._random import log_uniform


class LocalInfo(NamedTuple):
    """What one local move did."""

    accepted: Bool[Array, ""]
    acceptance_probability: Float[Array, ""]


class AbstractLocalKernel(eqx.Module):
    """A Markov kernel `zeta` that leaves the target invariant, used as local dynamics.

    A move is split in two so that a sampler can share the move's one new density
    evaluation with a regeneration draw: `propose` returns the candidate position (it may
    evaluate the density elsewhere, as HMC does along its trajectory); the caller
    evaluates the candidate once; `accept` decides from that evaluation.

    Subclasses set the class variables `uses_gradient` and `proposes_from_position`
    (the candidate depends on the position and the key alone, not on the log density or
    its gradient: then candidates can be drawn ahead of their evaluation, along a path of
    not yet evaluated points, as `restore.speculative_steps` does) and implement both methods.
    A kernel that needs more than the gradient at a point (`TorusH2MC`: a Hessian) sets
    `keeps_geometry` and overrides `evaluate_point`, which samplers call for every point
    they evaluate: what it derives there travels with the point (`Point.geometry`), so it
    is computed once per point, not once per move from it.
    """

    uses_gradient: ClassVar[bool] = False
    proposes_from_position: ClassVar[bool] = False
    keeps_geometry: ClassVar[bool] = False

    def evaluate_point(
        self, logdensity_fn: Callable[[Array], Any], position: Array, has_aux: bool = False
    ) -> tuple[Point, Bool[Array, ""]]:
        """The point at `position`, evaluated with what this kernel needs there: the value, the
        gradient for a gradient-based kernel, and the kernel's `geometry` where it keeps one;
        and whether the evaluation was invalid (as `restore.Point`'s evaluation says)."""
        return evaluate(logdensity_fn, position, self.uses_gradient, has_aux)

    @abc.abstractmethod
    def propose(
        self, key: PRNGKeyArray, point: Point, logdensity_fn: Callable[[Array], Array]
    ) -> tuple[Float[Array, " d"], Any]:
        """Return the candidate position and any data `accept` needs."""

    @abc.abstractmethod
    def accept(
        self, key: PRNGKeyArray, point: Point, candidate: Point, aux: Any
    ) -> tuple[Point, LocalInfo]:
        """Return the next point (the candidate, or `point` if rejected) and move info."""

    def check_dim(self, dim: int) -> None:
        """Raise a clear `ValueError` if the kernel's parameters do not fit dimension `dim`."""


def gradient_of(point: Point) -> Array:
    """The gradient a gradient-based kernel needs (`Point.grad`), with a clear error where it was not evaluated."""
    if point.grad is None:
        raise ValueError("this local kernel needs the log density's gradient, and the point was evaluated without it")
    return point.grad


def metropolis_accept(
    key: PRNGKeyArray, point: Point, candidate: Point, log_ratio: Array
) -> tuple[Point, LocalInfo]:
    """Accept `candidate` with probability `min(1, exp(log_ratio))`, NaN-safe.

    A candidate of zero (or invalid) density is always rejected; a NaN ratio counts as
    a rejection.
    """
    log_ratio = jnp.where(jnp.isnan(log_ratio), -jnp.inf, log_ratio)
    log_ratio = jnp.where(candidate.logdensity == -jnp.inf, -jnp.inf, log_ratio)
    log_alpha = jnp.minimum(log_ratio, 0.0)
    accepted = log_uniform(key, point.logdensity.dtype) < log_alpha
    chosen = jax.tree.map(lambda c, p: jnp.where(accepted, c, p), candidate, point)
    return chosen, LocalInfo(accepted, jnp.exp(log_alpha))


def hastings_accept(
    key: PRNGKeyArray, point: Point, candidate: Point, log_q: Callable[[Array, Point], Array]
) -> tuple[Point, LocalInfo]:
    """Metropolis-Hastings: accept with `min(1, p(y) q(y -> x) / (p(x) q(x -> y)))`, with
    `log_q(to, start)` the log proposal density (up to a constant) of moving from `start` to `to`."""
    log_ratio = (
        candidate.logdensity - point.logdensity + log_q(point.position, candidate) - log_q(candidate.position, point)
    )
    return metropolis_accept(key, point, candidate, log_ratio)
