"""The interface of local dynamics: a pi-invariant Markov kernel split at its one evaluation."""

from __future__ import annotations

import abc
from collections.abc import Callable
from typing import Any, ClassVar, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, PRNGKeyArray

from .._point import Point


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

    Subclasses set the class variable `uses_gradient` and implement both methods.
    """

    uses_gradient: ClassVar[bool] = False

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
    accepted = jnp.log(jax.random.uniform(key, dtype=point.logdensity.dtype)) < log_alpha
    chosen = jax.tree.map(lambda c, p: jnp.where(accepted, c, p), candidate, point)
    return chosen, LocalInfo(accepted, jnp.exp(log_alpha))


def as_scale(value: Any, name: str) -> Array:
    """Check a step-size-like argument: positive and finite, scalar or a vector."""
    try:
        arr = jnp.asarray(value)
    except (TypeError, ValueError) as err:
        raise TypeError(f"{name} must be a positive number or a vector of them, got {value!r}") from err
    if arr.dtype == bool or not (jnp.issubdtype(arr.dtype, jnp.floating) or jnp.issubdtype(arr.dtype, jnp.integer)):
        raise TypeError(f"{name} must be a positive number or a vector of them, got dtype {arr.dtype}")
    if not jnp.issubdtype(arr.dtype, jnp.floating):
        arr = arr.astype(float)
    if arr.ndim > 1:
        raise ValueError(f"{name} must be a scalar or a vector of shape (d,), got shape {arr.shape}")
    if not isinstance(arr, jax.core.Tracer) and not bool(jnp.all(jnp.isfinite(arr) & (arr > 0))):
        raise ValueError(f"{name} must be positive and finite, got {value!r}")
    return arr


def check_vector_dim(arr: Array, dim: int, name: str) -> None:
    """Raise if a per-coordinate parameter has the wrong length."""
    if arr.ndim == 1 and arr.shape[0] != dim:
        raise ValueError(f"{name} has length {arr.shape[0]} but the target has dimension {dim}")
