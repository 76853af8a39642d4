"""The largest tours of every lane, and the tail shapes `k_hat` read off them.

Each lane keeps (on the host, updated from the chunks' tour records) its
`K` longest tours with their observable integrals `F`, for each observable component `j`
its `K` tours of largest `|F_j|` with their durations, and its `K` largest importance
weights `p(y) / q(y)` at tour starts. These are exact per-lane top sets, so after the run
the largest values of the whole run (or of any group of lanes) are known exactly above a
bound, and the Pareto shape of each tail that matters can be fitted (`_pareto`):

- the tour durations `T` (the `"tours"` estimate of `log Z` is their mean);
- the residuals `|F_j - pi_hat_j T|` of the ratio estimator of each component (or, when
  too few of the largest residuals are certain, the heavier of the tails of `|F_j|` and
  `T`, which bounds it);
- the importance weights (the `"importance"` estimate of `log Z`).

A lane whose set is full has no other value above its set's smallest one, so every value
above the largest such minimum over lanes is in the sets. For residuals, which depend on
the final `pi_hat`, a tour outside both of its lane's sets has
`|F_j - pi_hat T| <= min |F_j| + |pi_hat| min T` of that lane's sets.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from jaxtyping import Array, Float

from ._pareto import pareto_k, pareto_k_log, tail_length
from ._tour_records import TourRecords

#: Per-lane top sets are capped so that they hold at most this many numbers in all.
MAX_TAIL_ELEMENTS = 2**22
#: At most this many values per lane and tail.
MAX_TAIL_PER_LANE = 64


class TourTails(NamedTuple):
    """Each lane's largest tours (`-inf` durations mark unused slots).

    Attributes:
        duration: `(L, K)` the lane's longest tour durations.
        duration_integral: `(L, K, m)` the observable integrals of those tours.
        integral: `(L, m, K)` per component `j`, the integrals `F_j` of largest `|F_j|`.
        integral_duration: `(L, m, K)` the durations of those tours.
        log_importance_weight: `(L, K)` the largest log importance weights at tour starts.
    """

    duration: Float[Array, "L K"]
    duration_integral: Float[Array, "L K m"]
    integral: Float[Array, "L m K"]
    integral_duration: Float[Array, "L m K"]
    log_importance_weight: Float[Array, "L K"]


def tail_depth(num_lanes: int, size: int) -> int:
    """`K`: as many values per lane as the memory cap allows, between 8 and 64."""
    return int(max(8, min(MAX_TAIL_PER_LANE, MAX_TAIL_ELEMENTS // max(num_lanes * (3 * size + 2), 1))))


def init_tails(num_lanes: int, size: int, depth: int) -> TourTails:
    """Empty float64 sets on the host (depth 0 for samplers without tours)."""
    ninf = np.full((num_lanes, depth), -np.inf)
    return TourTails(
        ninf,
        np.zeros((num_lanes, depth, size)),
        np.zeros((num_lanes, size, depth)),
        np.full((num_lanes, size, depth), -np.inf),
        ninf.copy(),
    )


def _top(values: np.ndarray, depth: int) -> np.ndarray:
    """Indices of the `depth` largest entries along the last axis (in no particular order)."""
    return np.argpartition(values, values.shape[-1] - depth, axis=-1)[..., -depth:]


class Pending(NamedTuple):
    """Tour records of recent chunks that have not yet joined the top sets, packed per lane.

    A merge costs about the same for the few tours of one chunk as for many chunks' worth
    (the partial sort runs over the whole sets), so the records wait on the host, each
    lane's packed after its earlier ones, and join the sets in one merge when some lane's
    buffer would overflow (or when the sets are read). Only a lane's first `tours`
    (`starts`) slots count: a chunk writes its records past them in place, and only the
    new counts commit them, so a chunk interrupted half-way leaves the committed records
    as they were. `Pending()` is the empty buffer.

    Attributes:
        duration: `(L, W)` durations of waiting tours.
        integral: `(L, W, m)` their observable integrals.
        tours: `(L,)` waiting tours per lane.
        log_importance_weight: `(L, W)` waiting log importance weights of tour starts.
        starts: `(L,)` waiting starts per lane.
    """

    duration: np.ndarray | None = None
    integral: np.ndarray | None = None
    tours: np.ndarray | None = None
    log_importance_weight: np.ndarray | None = None
    starts: np.ndarray | None = None


def pending_width(num_lanes: int, size: int, depth: int, capacity: int) -> int:
    """`W`: room for several chunks' records (fewer merges), within the sets' memory cap.

    At least `max(depth, capacity)`, so one chunk's records always fit an empty buffer.
    """
    least = max(depth, capacity)
    return int(max(least, min(8 * least, MAX_TAIL_ELEMENTS // max(num_lanes * (size + 2), 1))))


def _packed(pending: Pending, lanes: int, size: int, width: int) -> Pending:
    if pending.duration is not None:
        return pending
    used = np.zeros(lanes, np.int64)
    return Pending(np.empty((lanes, width)), np.empty((lanes, width, size)), used, np.empty((lanes, width)), used)


def _append(buffer: np.ndarray, used: np.ndarray, values: np.ndarray, count: np.ndarray) -> np.ndarray:
    """`buffer` with each lane's first `count` `values` written, in place, after its `used` slots."""
    lane, slot = np.nonzero(np.arange(int(np.max(count, initial=0)))[None, :] < count[:, None])
    buffer[lane, used[lane] + slot] = values[lane, slot]
    return buffer


def add_records(tails: TourTails, pending: Pending, records: TourRecords) -> tuple[TourTails, Pending]:
    """The sets and pending records after one chunk's records (merged first if a lane's buffer would overflow)."""
    depth = tails.duration.shape[1]
    if depth == 0:
        return tails, pending
    count, starts = np.asarray(records.count, np.int64), np.asarray(records.starts, np.int64)
    lanes, size = records.integral.shape[0], records.integral.shape[2]
    width = pending_width(lanes, size, depth, records.capacity)
    if pending.duration is not None and (np.any(pending.tours + count > width) or np.any(pending.starts + starts > width)):
        tails, pending = settle(tails, pending), Pending()
    pending = _packed(pending, lanes, size, width)
    weights = np.asarray(records.log_importance_weight)
    return tails, Pending(
        _append(pending.duration, pending.tours, np.asarray(records.duration), count),
        _append(pending.integral, pending.tours, np.asarray(records.integral), count),
        pending.tours + count,
        _append(pending.log_importance_weight, pending.starts, np.where(np.isnan(weights), -np.inf, weights), starts),
        pending.starts + starts,
    )


#: `settle` merges this many numbers (lanes x components x candidates) at a time at most.
SETTLE_BLOCK = 2**18


def settle(tails: TourTails, pending: Pending) -> TourTails:
    """Each lane's top sets with the pending records merged in (the sets, when none are pending).

    Runs on the host, in NumPy: a partial sort there takes a few milliseconds where XLA's
    `top_k` on the CPU sorts with a comparator call per comparison (a few hundred
    milliseconds per chunk for 512 lanes). Only the scores (durations, `|F_j|`, weights)
    are concatenated and partially sorted; the kept integrals are then gathered from the
    sets or the buffers by flat indices, without copying the integrals whole.

    Lanes are merged a block at a time (each lane's merge is its own), so that the
    temporary arrays stay a few megabytes: with temporaries of tens of megabytes, the
    merge at the end of the README's autosample run (1024 lanes, 13 components, 64 per
    set) took 0.45-0.7 s of CPU time in the sampling process, against 0.05-0.15 s for the
    same merge repeated; in blocks it takes 0.07 s there. The sets are bit for bit the same.
    """
    depth = tails.duration.shape[1]
    if depth == 0 or pending.duration is None:
        return tails
    assert pending.integral is not None and pending.log_importance_weight is not None
    assert pending.tours is not None and pending.starts is not None
    width = int(max(np.max(pending.tours), np.max(pending.starts)))  # the slots some lane used
    lanes, _, size = pending.integral.shape
    block = max(1, SETTLE_BLOCK // (size * (depth + width)))
    if block >= lanes:
        return _settle_lanes(tails, pending, width)
    blocks = [slice(start, start + block) for start in range(0, lanes, block)]
    parts = [_settle_lanes(TourTails(*(a[b] for a in tails)), Pending(*(a[b] for a in pending if a is not None)), width) for b in blocks]
    return TourTails(*(np.concatenate(arrays) for arrays in zip(*parts)))


def _settle_lanes(tails: TourTails, pending: Pending, width: int) -> TourTails:
    """`settle` of some lanes, over the first `width` slots of their buffers."""
    depth = tails.duration.shape[1]
    assert pending.integral is not None and pending.log_importance_weight is not None
    assert pending.tours is not None and pending.starts is not None and pending.duration is not None
    lanes, buffer, size = pending.integral.shape
    lane = np.arange(lanes)[:, None]
    slots = np.arange(width)[None, :]
    new_duration = np.where(slots < pending.tours[:, None], pending.duration[:, :width], -np.inf)  # committed slots only

    # the longest tours: index < depth picks from the set, the rest from the buffer
    duration = np.concatenate([tails.duration, new_duration], axis=1)
    index = _top(duration, depth)
    kept = np.take_along_axis(duration, index, axis=1)
    from_set = tails.duration_integral.reshape(-1, size)[lane * depth + np.minimum(index, depth - 1)]
    from_buffer = pending.integral.reshape(-1, size)[lane * buffer + np.maximum(index - depth, 0)]
    duration_integral = np.where((index < depth)[:, :, None], from_set, from_buffer)
    duration_integral[np.isinf(kept)] = 0.0  # unused slots hold zeros, whatever the buffer held

    # per component, the tours of largest |F_j|
    new_score = np.where(np.isfinite(new_duration)[:, :, None], np.abs(pending.integral[:, :width]), -np.inf)
    old_score = np.where(np.isfinite(tails.integral_duration), np.abs(tails.integral), -np.inf)
    by_size = _top(np.concatenate([old_score, np.swapaxes(new_score, 1, 2)], axis=2), depth)  # (L, m, K)
    in_set = by_size < depth
    component = np.arange(size)[None, :, None]
    set_index = (lane[:, :, None] * size + component) * depth + np.minimum(by_size, depth - 1)
    slot = np.maximum(by_size - depth, 0)
    integral_duration = np.where(
        in_set, np.take(tails.integral_duration, set_index), np.take(new_duration, lane[:, :, None] * width + slot)
    )
    integral = np.where(
        in_set, np.take(tails.integral, set_index), np.take(pending.integral, (lane[:, :, None] * buffer + slot) * size + component)
    )
    integral[np.isinf(integral_duration)] = 0.0

    new_weights = np.where(slots < pending.starts[:, None], pending.log_importance_weight[:, :width], -np.inf)
    weights = np.concatenate([tails.log_importance_weight, new_weights], axis=1)
    return TourTails(kept, duration_integral, integral, integral_duration, np.take_along_axis(weights, _top(weights, depth), axis=1))


# ---------------------------------------------------------------------------- after the run (numpy)
def largest_of_lanes(values: np.ndarray) -> np.ndarray:
    """The entries of per-lane top sets `(L, K)` (`-inf` unused) certain to be among the largest of all lanes.

    A lane whose set is full has no other value above its set's smallest one, so every
    value above the largest such minimum is in the sets.
    """
    values = np.asarray(values, np.float64)
    full = np.all(np.isfinite(values), axis=1)
    bound = np.max(np.min(values[full], axis=1)) if np.any(full) else -np.inf
    flat = values[np.isfinite(values)]
    return flat[flat > bound]


def duration_k(tails: TourTails, num_tours: int) -> float:
    """`k_hat` of the tour durations."""
    return pareto_k(largest_of_lanes(tails.duration), num_tours)


def importance_k(tails: TourTails, num_starts: int) -> float:
    """`k_hat` of the importance weights at tour starts."""
    return pareto_k_log(largest_of_lanes(tails.log_importance_weight), num_starts)


def residual_k(tails: TourTails, column: int, value: float, num_tours: int) -> float:
    """`k_hat` of the residuals `|F_j - value * T|` of component `column` of the observables."""
    d = np.asarray(tails.duration, np.float64)
    if d.shape[1] == 0:
        return math.nan
    f_long = np.asarray(tails.duration_integral[:, :, column], np.float64)
    f_big = np.asarray(tails.integral[:, column, :], np.float64)
    t_big = np.asarray(tails.integral_duration[:, column, :], np.float64)
    lanes = np.arange(d.shape[0])[:, None]
    rows = np.concatenate(
        [
            np.stack([np.broadcast_to(lanes, d.shape), d, f_long], axis=-1).reshape(-1, 3),
            np.stack([np.broadcast_to(lanes, t_big.shape), t_big, f_big], axis=-1).reshape(-1, 3),
        ]
    )
    rows = np.unique(rows[np.isfinite(rows[:, 1])], axis=0)  # a tour in both sets of its lane counts once
    residual = np.abs(rows[:, 2] - value * rows[:, 1])
    full = np.all(np.isfinite(d), axis=1)
    floor = np.min(np.abs(f_big), axis=1) + abs(value) * np.min(d, axis=1)
    bound = np.max(floor[full]) if np.any(full) else -np.inf
    certain = residual[residual > bound]
    if certain.size > tail_length(num_tours):
        return pareto_k(certain, num_tours)
    # Too few residuals are certain to be the largest: bound the tail instead. Since
    # |F - pi T| <= |F| + |pi| T, the residuals' tail is no heavier than the heavier of
    # the tails of |F_j| and T, each known exactly from its own set.
    k_size = pareto_k(largest_of_lanes(np.where(np.isfinite(t_big), np.abs(f_big), -np.inf)), num_tours)
    return max(k_size, duration_k(tails, num_tours))


def select_lanes(tails: TourTails, lanes) -> TourTails:
    """The sets of some lanes (an index, slice or mask), for estimates from groups of lanes."""
    return TourTails(*(np.asarray(a)[lanes] for a in tails))
