"""Simulate a continuous-time sampler up to a fixed time and return the state held then."""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, PRNGKeyArray

from .._sampler import check_sampler


@eqx.filter_jit
def _run(sampler, keys: Array, positions: Array, time: float, max_steps: int):
    def one_lane(key, position):
        state = sampler.init(key, position)

        def cond(loop):
            _, _, done, steps, _ = loop
            return ~done & (steps < max_steps)

        def body(loop):
            state, elapsed, _, steps, flaws = loop
            new_state, info = sampler.step(jax.random.fold_in(key, steps), state)
            ends_later = elapsed + info.holding_time > time
            state = jax.tree.map(lambda old, new: jnp.where(ends_later, old, new), state, new_state)
            elapsed = jnp.where(ends_later, elapsed, elapsed + info.holding_time)
            return state, elapsed, ends_later, steps + 1, flaws + _flaws(info, ~ends_later)

        zero, count = jnp.zeros((), positions.dtype), jnp.zeros((), jnp.int32)
        loop = (state, zero, jnp.zeros((), bool), count, jnp.zeros((2,), jnp.int32))
        state, elapsed, done, steps, flaws = jax.lax.while_loop(cond, body, loop)
        # Jump processes hold still between events. Diffusions move on between events: the event that would end the wait comes after
        # `time`, and (memoryless, independent of the path) the path to `time` is a fresh one.
        return sampler.advance_position(jax.random.fold_in(key, 2**31 - 1), state, time - elapsed), done, steps, flaws

    return jax.vmap(one_lane)(keys, positions)


def _flaws(info, counted: Array) -> Array:
    """Counts of the step's departures from the exact process: `(bound exceeded, negative rate)`."""
    exceeded = info.bound_ratio > 1
    negative = info.negative_rate
    return jnp.stack([exceeded & counted, negative & counted]).astype(jnp.int32)


class FixedTimeRun(NamedTuple):
    """The states at a fixed time, with what the simulation did to get there.

    Attributes:
        states: `(n, d)`, the states at the fixed time.
        steps: steps each lane took.
        num_bound_exceeded: thinning candidates, over all lanes, where the kill rate
            exceeded the bound `Gamma` (the kill was too rare there: not the exact process).
        num_negative_rate: states where the kill rate was negative (`c_tilde` too small).
    """

    states: Array
    steps: Array
    num_bound_exceeded: int
    num_negative_rate: int


def simulate_to_time(sampler, key: PRNGKeyArray, positions: Array, time: float, max_steps: int = 100_000) -> FixedTimeRun:
    """`fixed_time_states`, also counting the steps where the simulation was not exact."""
    sampler = check_sampler(sampler)
    if not time > 0:
        raise ValueError(f"time must be positive, got {time!r}")
    positions = jnp.asarray(positions)
    keys = jax.vmap(lambda i: jax.random.fold_in(key, i))(jnp.arange(positions.shape[0]))
    states, done, steps, flaws = _run(sampler, keys, positions, float(time), int(max_steps))
    if not bool(jnp.all(done)):
        raise RuntimeError(f"{int(jnp.sum(~done))} lanes did not reach time {time} within {max_steps} steps")
    exceeded, negative = (int(n) for n in jnp.sum(flaws, axis=0))
    return FixedTimeRun(states, steps, exceeded, negative)


def fixed_time_states(sampler, key: PRNGKeyArray, positions: Array, time: float, max_steps: int = 100_000) -> tuple[Array, Array]:
    """Run each lane from `positions` with real exponential holding times up to `time`.

    The state held at `time` is returned (the move that would end its holding is
    discarded: holding times are independent of what happens next). For diffusion
    dynamics the process moves between events, so the state at `time` is the last
    event's state moved on by the remaining time (`sampler.advance_position`). If the initial
    positions are exact draws of the target and the sampler is correct, the returned
    states are exact draws of the target too; the jump chain itself (state after `k`
    steps) is *not* target-distributed, because short holding times are over-counted.

    Arguments:
        sampler: a `restore.AbstractSampler` (its steps' `StepInfo.holding_time` are the
            real holding times).
        key: PRNG key.
        positions: `(n, d)` starting points.
        time: the fixed time `t > 0`.
        max_steps: safety cap on steps per lane.

    Returns:
        States at time `t`, `(n, d)`, and the number of steps each lane used. A lane that
        hit `max_steps` raises a `RuntimeError`.
    """
    run = simulate_to_time(sampler, key, positions, time, max_steps)
    return run.states, run.steps
