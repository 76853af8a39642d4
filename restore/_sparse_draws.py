"""Draws that only some lanes use, computed on those lanes only.

A jump-Restore step uses its regeneration draw only when the lane is killed, and an
MH step its large-step draw only when it takes one: a tenth of the lanes or fewer in a
typical run. Under `vmap` every lane would pay for the draw (a Gaussian draw costs as much
as the rest of the step; a Student-t draw loops over gamma rejections). Here the lanes that
need it are gathered in batches of `slots` lanes, drawn, and put back in place. The batch
size is static; when more lanes need a draw than there are slots, more batches run: the
result never depends on `slots`, only the time does.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool

#: Lanes gathered at least, so small runs never fall back because of noise in the count.
MIN_SLOTS = 8


def draw_slots(num_lanes: int, fraction: float | None) -> int | None:
    """A batch size that holds the lanes needing a draw in almost every step, or `None`.

    `fraction` is the expected share of lanes that need a draw (`None`: unknown, a quarter
    is assumed). The size is the binomial mean plus two standard deviations and `MIN_SLOTS`,
    so about one step in forty needs a second batch; `None` when that is half the lanes or
    more, where gathering would save little. (Six standard deviations never needed a second
    batch but drew twice the lanes a step uses; two were faster with a Student-t mixture,
    whose draws loop over gamma rejections, and as fast with a Gaussian.)
    """
    share = 0.25 if fraction is None else min(max(float(fraction), 0.0), 1.0)
    mean = num_lanes * share
    slots = math.ceil(mean + 2.0 * math.sqrt(mean * (1.0 - share)) + MIN_SLOTS)
    slots = -(-slots // MIN_SLOTS) * MIN_SLOTS  # a multiple of 8
    return slots if 2 * slots <= num_lanes else None


def batch_lanes(needed: Bool[Array, " n"], rank: Array, first: Array, slots: int) -> Array:
    """The lanes whose `rank` among the `needed` ones is `first, ..., first + slots - 1`, in order
    (`n` where there is none).

    A scatter of each lane's index to its rank: linear in the lanes. (A comparison of every
    rank with every slot is quadratic, far too slow at many lanes; a binary search for each
    slot was slower than the scatter on the CPU.)
    """
    num_lanes = needed.shape[0]
    slot = jnp.where(needed & (rank >= first) & (rank < first + slots), rank - first, slots)
    return jnp.full((slots,), num_lanes, jnp.int32).at[slot].set(jnp.arange(num_lanes, dtype=jnp.int32), mode="drop")


def draw_where(draw: Callable[..., Any], needed: Bool[Array, " n"], slots: int, *args) -> Any:
    """`vmap(draw)(*args)` at the lanes where `needed` holds; zeros at the others.

    The lanes that need a draw are listed once, in lane order, and drawn `slots` at a
    time until all are drawn (one batch in a typical step); each batch's results are
    written to the next rows of a compact buffer, and every lane reads its row back at the
    end. So a batch costs in proportion to `slots`, not to the lanes. `draw` is traced
    once, so compiling it costs no more than under `vmap`; only gathers and contiguous
    writes are used (XLA's CPU scatter costs about as much per lane as the draw that is
    saved).

    Arguments:
        draw: one lane's draw (or any computation) from its own arguments (e.g. a key and
            a position); it may return a pytree of arrays.
        needed: which lanes use their draw.
        slots: how many lanes are drawn together (static).
        args: pytrees of arrays with a leading lane axis.
    """
    num_lanes = needed.shape[0]
    rank = jnp.cumsum(needed, dtype=jnp.int32) - 1  # among the lanes that need a draw
    total = rank[-1] + 1
    rows = -(-num_lanes // slots) * slots  # room for every lane, in whole batches
    order = batch_lanes(needed, rank, jnp.zeros((), jnp.int32), rows)  # the lanes that need a draw, then `num_lanes`
    one = jax.eval_shape(jax.vmap(draw), *jax.tree.map(lambda a: a[:1], args))

    def batch(loop):
        first, compact = loop
        index = jnp.minimum(jax.lax.dynamic_slice_in_dim(order, first, slots), num_lanes - 1)
        values = jax.vmap(draw)(*jax.tree.map(lambda a: a[index], args))
        compact = jax.tree.map(lambda c, v: jax.lax.dynamic_update_slice_in_dim(c, v, first, 0), compact, values)
        return first + slots, compact

    empty = jax.tree.map(lambda s: jnp.zeros((rows,) + s.shape[1:], s.dtype), one)
    compact = jax.lax.while_loop(lambda loop: loop[0] < total, batch, (jnp.zeros_like(total), empty))[1]
    row = jnp.clip(rank, 0, rows - 1)
    back = lambda c: jnp.where(needed.reshape((-1,) + (1,) * (c.ndim - 1)), c[row], jnp.zeros((), c.dtype))
    return jax.tree.map(back, compact)
