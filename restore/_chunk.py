"""The one loop of every chunk, in sampling and in rendering: steps of a run's carry on the device.

A chunk is one compiled `while_loop` over the steps of a carry (the lanes' states and what
they accumulate: a sampler's lane sums, tail buffers and draws; a renderer's film and
counts), run for at most a traced number of steps, so one program serves every chunk
length, and, when finishing open tours, only while some tour is open. `restore.sample`'s
chunks and narrow finishing batch (`_run_loop`) and a renderer's chunks and finishing
(`restore.render`) all run on `run_steps`; what differs is their step and their carry.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike
from jaxtyping import Array, Int

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
