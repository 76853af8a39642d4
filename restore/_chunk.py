"""The one loop of every chunk, in sampling and in rendering: steps of a run's carry on the device.

A chunk is one compiled `while_loop` over the steps of a carry (the lanes' states and what
they accumulate: a sampler's lane sums, tail buffers and draws; a renderer's film and
counts), run for at most a traced number of steps, so one program serves every chunk
length, and, when finishing open tours, only while some tour is open. `restore.sample`'s
chunks and narrow finishing batch (`_run_loop`) and a renderer's chunks and finishing
(`restore.render`) all run on `run_steps`; what differs is their step and their carry.

After the budget, `restore.sample` and the Restore renders finish their open tours by
`run_open_lanes`, the one finishing procedure: a narrow batch of slots, each holding an
open lane until its tour ends. What a slot's step is differs: a plain step of the sampler
(each lane's `j`-th finishing step with its own key, so the result does not depend on the
batch), and for a render speculative steps (`restore.speculative_steps`: the batch's
evaluations shared among its open lanes, several events of a tour per call once fewer
lanes are open than slots).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple, TypeVar

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike
from jaxtyping import Array, Int

from ._sparse_draws import batch_lanes

C = TypeVar("C")


def run_steps(
    step: Callable[[Int[Array, ""], C], C],
    carry: C,
    length: ArrayLike,
    going: Callable[[C], Array] | None = None,
) -> tuple[C, Int[Array, ""]]:
    """`carry` after `step(i, carry)` for `i = 0, 1, ...`: at most `length` steps (traced or
    not) and, with `going`, only while `going(carry)` holds (tested before each step).

    Returns the carry and the number of steps run.
    """

    def cond(loop: tuple[Int[Array, ""], C]) -> Array:
        i, carry = loop
        more = i < length
        return more if going is None else more & going(carry)

    def body(loop: tuple[Int[Array, ""], C]) -> tuple[Int[Array, ""], C]:
        i, carry = loop
        return i + 1, step(i, carry)

    done, carry = jax.lax.while_loop(cond, body, (jnp.zeros((), jnp.int32), carry))
    return carry, done


class _Slots(NamedTuple):
    """The loop of `run_open_lanes`."""

    lanes: Any  # every lane's part of the carry (up to date for the lanes not held by a slot)
    shared: Any  # the carry's part that all lanes add to (histograms, tail buffers)
    taken: Array  # steps each lane has taken (up to date for the lanes not held by a slot)
    slot_lane: Array  # the lane each slot holds
    slot_lanes: Any  # the slots' lanes' parts of the carry
    slot_steps: Array  # steps the slot's lane has taken
    live: Array  # the slot holds an open lane
    held: Array  # the slot holds a lane not yet written back (open, or done and waiting)
    next: Array  # queue position of the next lane to take


#: A batch of slots writes its done lanes back and takes new ones once this share of its
#: slots is done (or none is open): a gather and scatter of every part of the carry per
#: refill, not per step, for a few idle steps of the done slots.
REFILL_SHARE = 8


def run_open_lanes(
    step: Callable[[Any, Any, Array, Array, Array, Array], tuple[Any, Any, Array]],
    lanes: Any,
    shared: Any,
    open_: Array,
    taken: Array,
    limit: ArrayLike,
    iterations: ArrayLike,
    width: int,
) -> tuple[Any, Any, Array, Int[Array, ""]]:
    """Step the `open_` lanes, `width` at a time, until each one's work ends: how
    `restore.sample` finishes its open tours after the budget.

    A batch of `width` slots each holds an open lane (in lane order); every iteration steps
    the batch. A lane whose work ended (or that has taken `limit` steps) waits in its slot,
    unchanged, until `width / REFILL_SHARE` slots are done or none is open; then the done
    lanes go back to their places in `lanes` and their slots take the next open lanes. So a
    few long tours cost a step of the batch, not of every lane. Runs at most `iterations`
    iterations (`run_steps`); the lanes still held by a slot then are written back, to go on
    in a later call. How the steps fall into refills and calls changes no lane's steps.

    Arguments:
        step: `step(slot_lanes, shared, slot_lane, slot_steps, live, iteration)` steps the
            slots' lanes (`live`: the slots that hold an open lane; the others must keep their
            lanes' parts as they are and not add to `shared`) and returns
            `(slot_lanes, shared, ended)`.
        lanes: each lane's part of the carry (a pytree with a leading lane axis).
        shared: what every lane adds to (passed through `step`).
        open_: the lanes to step.
        taken: the steps each lane has taken so far (its slot's `slot_steps` start there).
        limit: the most steps a lane may take.
        iterations: the most iterations of the batch.
        width: slots in the batch (static).

    Returns:
        `lanes`, `shared` and `taken` after the call, and the iterations it ran.
    """
    num_lanes = taken.shape[0]
    open_ = open_ & (taken < limit)
    queue = batch_lanes(open_, jnp.cumsum(open_, dtype=jnp.int32) - 1, jnp.zeros((), jnp.int32), num_lanes)  # open lanes in order
    total = jnp.sum(open_, dtype=jnp.int32)
    take = lambda tree, index: jax.tree.map(lambda a: a[index], tree)  # noqa: E731
    slots = jnp.arange(width, dtype=jnp.int32)
    first = jnp.minimum(queue[jnp.minimum(slots, num_lanes - 1)], num_lanes - 1)
    enough = max(1, width // REFILL_SHARE)

    def write_back(loop: _Slots, which: Array) -> tuple[Any, Array]:
        home = jnp.where(which, loop.slot_lane, num_lanes)  # out of range: not written
        put = lambda full, part: full.at[home].set(part, mode="drop")  # noqa: E731
        return jax.tree.map(put, loop.lanes, loop.slot_lanes), put(loop.taken, loop.slot_steps)

    def refill(loop: _Slots) -> _Slots:
        done = loop.held & ~loop.live
        lanes, taken = write_back(loop, done)  # the done lanes go back to their places...
        position = loop.next + jnp.cumsum(done, dtype=jnp.int32) - 1  # ...and their slots take the next open lanes
        fresh = done & (position < total)
        new_lane = jnp.where(fresh, queue[jnp.minimum(position, num_lanes - 1)], loop.slot_lane)
        pick = lambda full, part: jnp.where(fresh.reshape((-1,) + (1,) * (part.ndim - 1)), full[new_lane], part)  # noqa: E731
        return _Slots(
            lanes, loop.shared, taken, new_lane, jax.tree.map(pick, lanes, loop.slot_lanes),
            jnp.where(fresh, taken[new_lane], loop.slot_steps), loop.live | fresh, loop.live | fresh,
            loop.next + jnp.sum(done, dtype=jnp.int32),
        )  # fmt: skip

    def body(i: Array, loop: _Slots) -> _Slots:
        slot_lanes, shared, ended = step(loop.slot_lanes, loop.shared, loop.slot_lane, loop.slot_steps, loop.live, i)
        slot_steps = loop.slot_steps + loop.live.astype(jnp.int32)
        live = loop.live & ~(ended | (slot_steps >= limit))  # the work ended, or the lane ran out of steps
        loop = loop._replace(shared=shared, slot_lanes=slot_lanes, slot_steps=slot_steps, live=live)
        done = jnp.sum(loop.held & ~live, dtype=jnp.int32)
        due = (done >= enough) | ((done > 0) & ~jnp.any(live))
        return jax.lax.cond(due & (loop.next < total), refill, lambda loop: loop, loop)

    zero = jnp.zeros_like(total)  # varies with the lanes, as the loop's results do (under `shard_map`)
    held = slots < total
    start = _Slots(lanes, shared, taken, first, take(lanes, first), taken[first], held, held, jnp.minimum(total, width) + zero)
    end, iterations_run = run_steps(body, start, iterations, lambda loop: jnp.any(loop.live))
    lanes, taken = write_back(end, end.held)  # the lanes still held by a slot go back to their places
    return lanes, end.shared, taken, iterations_run
