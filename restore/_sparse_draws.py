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


def draw_where(draw: Callable[..., Array], needed: Bool[Array, " n"], slots: int, *args) -> Array:
    """`vmap(draw)(*args)` at the lanes where `needed` holds; zeros at the others.

    The lanes that need a draw are taken `slots` at a time, in lane order, until all are
    drawn (one batch in a typical step). `draw` is traced once, so compiling it costs no
    more than under `vmap`; only gathers are used (XLA's CPU scatter costs about as much
    per lane as the draw that is saved).

    Arguments:
        draw: one lane's draw from its own arguments (e.g. a key and a position).
        needed: which lanes use their draw.
        slots: how many lanes are drawn together (static).
        args: arrays with a leading lane axis.
    """
    num_lanes = needed.shape[0]
    rank = jnp.cumsum(needed) - 1  # among the lanes that need a draw
    total = rank[-1] + 1
    one = jax.eval_shape(jax.vmap(draw), *jax.tree.map(lambda a: a[:1], args))
    mask_shape = (-1,) + (1,) * (len(one.shape) - 1)

    def batch(loop):
        first, out = loop
        index = batch_lanes(needed, rank, first, slots)
        values = jax.vmap(draw)(*jax.tree.map(lambda a: a[jnp.minimum(index, num_lanes - 1)], args))
        slot = rank - first
        mine = needed & (slot >= 0) & (slot < slots)
        return first + slots, jnp.where(mine.reshape(mask_shape), values[jnp.clip(slot, 0, slots - 1)], out)

    empty = jnp.zeros((num_lanes,) + one.shape[1:], one.dtype)
    return jax.lax.while_loop(lambda loop: loop[0] < total, batch, (jnp.zeros_like(total), empty))[1]
