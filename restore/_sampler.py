"""The sampler contract: what `restore.sample`, the results and the testing module rely on.

A sampler is an `eqx.Module` with `init(key, position) -> state` and
`step(key, state) -> (state, StepInfo)`, one lane at a time (the driver `vmap`s it), over
NamedTuple states that carry at least a `position`. Every sampler fills the same
`StepInfo`, so the run driver reads its fields without asking which sampler it drives.
Class-level flags and a few facts with defaults for samplers without tours
(`run_facts`, `expected_tour_times`, `advance_position`) complete the contract.
"""

from __future__ import annotations

import abc
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, PRNGKeyArray


class StepInfo(NamedTuple):
    """What one step of one lane did: the record every sampler fills.

    Attributes:
        position: the state the weights below refer to (jump dynamics and discrete-time
            chains: the state held before the step; diffusions: the state at the
            candidate event).
        holding_time: time elapsed in this step (a sampled exponential; 1 for a
            discrete-time chain).
        expected_holding_time: the Rao-Blackwellised weight: `1 / (r + gamma(x))` for
            jump dynamics, `1 / Gamma` for thinning (each candidate event stands for
            `1/Gamma` time units of the path), 1 for a discrete-time chain.
        regenerated: the tour ended at this step.
        accepted: a local move was made (and accepted, for Metropolis kernels).
        acceptance_probability: of the local move.
        invalid: the new evaluation returned NaN or `+inf` (treated as zero density).
        uncovered: the new state has positive target density but zero reference density.
        log_importance_weight: `log p(y) - log q(y)` at a freshly drawn tour start `y`
            (`-inf` when no start was drawn).
        start_drawn: this step drew the start of a tour.
        negative_rate: the kill rate was negative at the state tested: `c_tilde` is too
            small for these dynamics (`restore.minimal_log_rate` searches for a safe one).
        bound_ratio: `gamma / Gamma` at a thinning candidate (zero for jump dynamics);
            above 1 the bound was violated.
        aux: the log density's extra output at `position` (samplers built with
            `has_aux`), else `None`: what a renderer splats.
    """

    position: Float[Array, " d"]
    holding_time: Float[Array, ""]
    expected_holding_time: Float[Array, ""]
    regenerated: Bool[Array, ""]
    accepted: Bool[Array, ""]
    acceptance_probability: Float[Array, ""]
    invalid: Bool[Array, ""]
    uncovered: Bool[Array, ""]
    log_importance_weight: Float[Array, ""]
    start_drawn: Bool[Array, ""]
    negative_rate: Bool[Array, ""]
    bound_ratio: Float[Array, ""]
    aux: Any = None


class RunFacts(NamedTuple):
    """The sampler's constants a result needs to turn sums into estimates.

    Attributes:
        log_rate: `log c` with the mean tour duration `Z / c` (`None` without tours).
        tour_length: the mean tour duration the rate was calibrated for, if it was.
    """

    log_rate: float | None = None
    tour_length: tuple[float, ...] | None = None


class AbstractSampler(eqx.Module):
    """A sampler `restore.sample` can run: `init` and `step` over NamedTuple states.

    Subclasses set the class-level flag `has_tours` and implement `dim`, `dtype`, `init`
    and `step`; the other members have the defaults of a sampler without tours.
    """

    has_tours: eqx.AbstractClassVar[bool]

    @property
    @abc.abstractmethod
    def dim(self) -> int:
        """The dimension `d` of a state's position."""

    @property
    @abc.abstractmethod
    def dtype(self) -> jnp.dtype:
        """The floating dtype of the positions and weights of a run."""

    @abc.abstractmethod
    def init(self, key: PRNGKeyArray, position: Array | None = None) -> Any:
        """The state of one lane, started at `position` or at a draw of the sampler's own start law."""

    @abc.abstractmethod
    def step(self, key: PRNGKeyArray, state: Any) -> tuple[Any, StepInfo]:
        """One step of one lane."""

    def step_lanes(self, keys: PRNGKeyArray, states: Any) -> tuple[Any, StepInfo]:
        """One step of every lane (`keys` and `states` with a leading lane axis).

        `vmap(step)`; a sampler may batch work that only some lanes need, with results
        equal to `vmap(step)` lane by lane.
        """
        return jax.vmap(self.step)(keys, states)

    def tour_end_fraction(self) -> float | None:
        """The expected share of lanes that end a tour (or draw a tour's start) at a step, if
        known: the run loop sizes the batches it gathers those lanes in by it (`None`:
        unknown, a quarter is assumed). Any value gives the same results."""
        return None

    @property
    def is_diffusion(self) -> bool:
        """Steps are thinning candidates of a diffusion (their weights are `1 / Gamma`)."""
        return False

    @property
    def is_regenerative(self) -> bool:
        """Tours start independently of the past: tour-based standard errors are valid."""
        return False

    def run_facts(self) -> RunFacts:
        """The constants a result needs (none for a sampler without tours)."""
        return RunFacts()

    def expected_tour_times(self, last_tour, num_tours) -> np.ndarray | None:
        """Per lane, the complete tours' expected total duration over `Z` when it is not
        `num_tours / c` (several phases); `None` otherwise."""
        return None

    def advance_position(self, key: PRNGKeyArray, state: Any, duration: Array) -> Array:
        """The position `duration` time units after `state`, given that no event happens before
        (a jump process or chain holds still)."""
        return state.position


def check_sampler(sampler: object) -> AbstractSampler:
    """`sampler`, if it fulfils the contract; a `TypeError` that says what is missing otherwise."""
    if not isinstance(sampler, AbstractSampler):
        raise TypeError(
            f"sampler must be a restore sampler (a subclass of restore.AbstractSampler with init and step), "
            f"got {type(sampler).__name__}"
        )
    return sampler
