"""The largest values of a run, kept on the device: every row with a score above a threshold that rises as the buffer fills.

A run's tail diagnostics need its largest tour durations, observable integrals and
importance weights, exactly, whatever the number of lanes. An `Exceedances` buffer holds
rows of numbers (a tour's duration and integrals, say) with the lane each came from. Each
row has `C` scores (on a log scale: `log T`, `log |F_j|`, ...), and each score column has a
threshold, `-inf` at first. A row offered is kept when one of its scores exceeds its
column's threshold; when the buffer would overflow it is compacted: the thresholds rise
(each column keeping about as many of its largest scores as the others) until at most half
the buffer is kept. So at every moment, for each column, the buffer holds every row of the
run whose score in that column is above the column's threshold: the column's largest
values, exactly, and a row that is not in the buffer has every score at or below its
column's threshold.

Everything is fixed-shape and stays on the device. An offer costs a comparison per score
and lane; the rows above a threshold are gathered (`_sparse_draws.batch_lanes`: no sort)
and written after the buffer's used rows in one contiguous update, with no scatter. Only a
compaction (about `log(n / B)` times for `n` rows offered) looks at the whole buffer: a
histogram of each column's scores (from a sample of the rows) proposes the thresholds, and
one exact pass checks how many rows they keep, with no sort (XLA's sorts and `top_k` are
far slower on the CPU; `docs/benchmarks.md`).

The values above a threshold of any group of lanes are its own largest values, so
estimates from subsets of lanes (`lanes=` of a result) read their own tails from the same
buffer; buffers over disjoint lanes (devices, parts of a run) merge by taking the highest
of their thresholds.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ._sparse_draws import batch_lanes

#: Histogram bins per factor of two of a score (log scale), for the thresholds of a compaction.
BINS_PER_OCTAVE = 16
#: Histogram bins below each column's largest score (scores further down share the last).
NUM_BINS = 1024
#: A compaction histograms a sample of about this many rows (the thresholds it proposes are checked exactly).
HISTOGRAM_ROWS = 8192

#: How a buffer scores its rows, one score per number: the last `Scoring` numbers of a row
#: are logarithms already (log importance weights) and are their own scores; the others
#: (durations, integrals) are scored by `log |x|`.
Scoring = int


def _log_columns(width: int, scoring: Scoring, xp):
    return xp.arange(width) >= width - scoring


def log_scores(rows, scoring: Scoring, xp=jnp):
    """The rows' scores `(..., P)` on a log scale (`-inf`: never kept); `xp` is `jnp` or `np`."""
    with np.errstate(divide="ignore"):
        return xp.where(_log_columns(rows.shape[-1], scoring, xp), rows, xp.log(xp.abs(rows)))


def _above(rows: Array, threshold: Array, scoring: Scoring) -> Array:
    """Rows with some score above its column's threshold (compared without logarithms)."""
    logs = _log_columns(rows.shape[-1], scoring, jnp)
    return jnp.any(jnp.where(logs, rows > threshold, jnp.abs(rows) > jnp.exp(threshold)), axis=-1)


class Exceedances(NamedTuple):
    """A buffer of rows whose scores exceed their columns' thresholds (device or host arrays).

    Attributes:
        rows: `(B, P)` the kept rows, in the order they came (unused rows after `filled`).
        lane: `(B,)` the lane each row came from.
        filled: `()` used rows.
        threshold: `(C,)` per score column: every row offered and not kept has its score in
            this column at or below this (`-inf`: every row was kept).
    """

    rows: Float[Array, "B P"]
    lane: Int[Array, " B"]
    filled: Int[Array, ""]
    threshold: Float[Array, " C"]

    @property
    def capacity(self) -> int:
        return int(self.rows.shape[-2])


def init_exceedances(capacity: int, width: int, dtype) -> Exceedances:
    """An empty buffer of `capacity` rows (even) of `width` numbers, one score column each."""
    if capacity % 2:
        raise ValueError(f"capacity must be even, got {capacity}")
    return Exceedances(
        jnp.zeros((capacity, width), dtype),
        jnp.zeros((capacity,), jnp.int32),
        jnp.zeros((), jnp.int32),
        jnp.full((width,), -jnp.inf, dtype),
    )


def compact(buffer: Exceedances, scoring: Scoring) -> Exceedances:
    """The buffer with at most half its rows kept: the thresholds raised, the rows below all of them dropped.

    Each column's thresholds are read off a log-scale histogram of its scores (of every
    row, or an even sample of `HISTOGRAM_ROWS`): the column keeps about its `r` largest scores, with `r`
    lowered by quarters from `B / 2` until the rows kept (an exact count) fit in half the
    buffer. The kept rows stay in their order.
    """
    capacity = buffer.capacity
    half = capacity // 2
    scores = log_scores(buffer.rows, scoring)
    used = jnp.arange(capacity) < buffer.filled
    scores = jnp.where(used[:, None], scores, -jnp.inf)
    top = jnp.max(scores, axis=0)  # (C,)
    scale = BINS_PER_OCTAVE / math.log(2.0)
    stride = max(1, capacity // HISTOGRAM_ROWS)
    sample = scores[::stride]
    bins = jnp.clip(jnp.floor((top - sample) * scale), 0, NUM_BINS - 1)
    bins = jnp.where(jnp.isfinite(sample), bins, NUM_BINS).astype(jnp.int32)  # unused rows: out of range
    columns = jnp.arange(scores.shape[1])[None, :]
    histogram = jnp.zeros((scores.shape[1], NUM_BINS), jnp.int32).at[columns, bins].add(1, mode="drop")
    larger = jnp.cumsum(histogram, axis=1) * stride  # (C, NUM_BINS): about how many scores are in bins <= b

    def thresholds(rank: Array) -> Array:
        """Per column, the lower edge of the last bin with about `rank` scores above it."""
        last = jnp.sum(larger <= rank, axis=1) - 1  # -1: even the top bin holds more
        edge = top - (last + 1) / scale
        return jnp.maximum(buffer.threshold, jnp.where(last < 0, top, edge))

    def kept(rank: Array) -> Array:
        return jnp.sum(used & jnp.any(scores > thresholds(rank), axis=1), dtype=jnp.int32)

    half_rank = half + jnp.zeros_like(buffer.filled)  # varies with the buffer, as the loops' results do (under `shard_map`)
    rank = jax.lax.while_loop(lambda r: (kept(r) > half) & (r > 0), lambda r: r * 3 // 4, half_rank)
    threshold = thresholds(rank)
    keep = used & jnp.any(scores > threshold, axis=1)
    index = batch_lanes(keep, jnp.cumsum(keep, dtype=jnp.int32) - 1, jnp.zeros((), jnp.int32), capacity)
    count = jnp.sum(keep, dtype=jnp.int32)
    valid = (jnp.arange(capacity) < count)[:, None]
    index = jnp.minimum(index, capacity - 1)
    return Exceedances(
        jnp.where(valid, buffer.rows[index], 0.0), jnp.where(valid[:, 0], buffer.lane[index], 0), count, threshold
    )


def _append(buffer: Exceedances, rows: Float[Array, "S P"], lanes: Int[Array, " S"], count: Int[Array, ""]) -> Exceedances:
    """The buffer with the first `count` of `rows` appended (all `S` rows must fit after its used ones)."""
    start = (buffer.filled, jnp.zeros((), jnp.int32))
    return buffer._replace(
        rows=jax.lax.dynamic_update_slice(buffer.rows, rows.astype(buffer.rows.dtype), start),
        lane=jax.lax.dynamic_update_slice(buffer.lane, lanes.astype(jnp.int32), start[:1]),
        filled=buffer.filled + count,
    )


def make_room(buffer: Exceedances, incoming: Array, scoring: Scoring) -> Exceedances:
    """The buffer, compacted if `incoming` more rows might not fit (one compaction makes room
    for up to half the buffer)."""
    return jax.lax.cond(buffer.filled + incoming > buffer.capacity, lambda b: compact(b, scoring), lambda b: b, buffer)


def append(buffer: Exceedances, rows: Float[Array, "S P"], lanes: Int[Array, " S"], keep: Bool[Array, " S"]) -> Exceedances:
    """The buffer with the `keep` rows of a batch appended, in order (all `S` rows must fit: `make_room`)."""
    index = jnp.minimum(batch_lanes(keep, jnp.cumsum(keep, dtype=jnp.int32) - 1, jnp.zeros((), jnp.int32), keep.shape[0]), keep.shape[0] - 1)
    return _append(buffer, rows[index], lanes[index], jnp.sum(keep, dtype=jnp.int32))


def offer(
    buffer: Exceedances, rows: Float[Array, "N P"], lanes: Int[Array, " N"], offered: Bool[Array, " N"], scoring: Scoring, batch: int
) -> Exceedances:
    """The buffer after the `offered` rows of `N` with a score above its column's threshold, `batch` at a time.

    The buffer is compacted first if the rows worth keeping might not fit (it holds at
    least `2 (N + batch)` rows, so one compaction always makes room). Those rows are found
    from their running count (`_sparse_draws.batch_lanes`), gathered `batch` at a time in
    row order and appended; a step with none costs a comparison per score and row, and no
    batch at all.
    """
    if buffer.capacity < 2 * (rows.shape[0] + batch):
        raise ValueError(f"a buffer of {buffer.capacity} rows is too small for offers of {rows.shape[0]} rows in batches of {batch}")
    wanted = lambda buffer: offered & _above(rows, buffer.threshold, scoring)
    buffer = make_room(buffer, jnp.sum(wanted(buffer), dtype=jnp.int32) + batch, scoring)
    candidate = wanted(buffer)
    rank = jnp.cumsum(candidate, dtype=jnp.int32) - 1
    total = rank[-1] + 1

    def body(loop):
        buffer, start = loop
        index = jnp.minimum(batch_lanes(candidate, rank, start, batch), candidate.shape[0] - 1)
        count = jnp.minimum(total - start, batch)
        return _append(buffer, rows[index], lanes[index], count), start + batch

    return jax.lax.while_loop(lambda loop: loop[1] < total, body, (buffer, jnp.zeros((), jnp.int32)))[0]


# ---------------------------------------------------------------------------- on the host (numpy)
class Largest(NamedTuple):
    """Host form of `Exceedances`: the rows above a threshold only, from any number of buffers.

    Attributes:
        rows: `(K, P)` the rows.
        lane: `(K,)` their lanes.
        threshold: `(C,)` a row not among these has every score at or below its column's threshold.
    """

    rows: np.ndarray
    lane: np.ndarray
    threshold: np.ndarray

    def column(self, c: int, scoring: Scoring) -> np.ndarray:
        """Column `c` of the rows whose score there is above its threshold: all of the run's, exactly."""
        values = self.rows[:, c]
        with np.errstate(divide="ignore"):  # the logarithms of this column alone (as `log_scores` scores it)
            scores = values if c >= self.rows.shape[-1] - scoring else np.log(np.abs(values))
        return values[scores > self.threshold[c]]


def largest(buffer: Exceedances, scoring: Scoring) -> Largest:
    """The used rows of a buffer above a threshold (host arrays, float64); buffers with a leading
    device axis (one per device) are merged."""
    rows = np.asarray(buffer.rows)
    if rows.ndim == 3:  # one buffer per device
        return merge([largest(Exceedances(*(np.asarray(a)[d] for a in buffer)), scoring) for d in range(rows.shape[0])], scoring)
    count = int(np.asarray(buffer.filled))
    rows = rows[:count].astype(np.float64)
    threshold = np.asarray(buffer.threshold, np.float64)
    keep = np.any(log_scores(rows, scoring, np) > threshold, axis=1)
    return Largest(rows[keep], np.asarray(buffer.lane)[:count][keep].astype(np.int64), threshold)


def merge(parts: list[Largest], scoring: Scoring) -> Largest:
    """Rows of buffers over disjoint lanes, as one buffer's: only scores above every part's threshold
    of their column are certain to be among the largest of all, so the merged thresholds are the highest."""
    threshold = np.max(np.stack([p.threshold for p in parts]), axis=0)
    rows = np.concatenate([p.rows for p in parts])
    lane = np.concatenate([p.lane for p in parts])
    keep = np.any(log_scores(rows, scoring, np) > threshold, axis=1)
    return Largest(rows[keep], lane[keep], threshold)


def select_lanes(entries: Largest, lanes, num_lanes: int) -> Largest:
    """The rows of some lanes (an index, slice or mask of `num_lanes` lanes): still every row above a threshold."""
    chosen = np.zeros(num_lanes, bool)
    chosen[lanes] = True
    keep = chosen[entries.lane]
    return Largest(entries.rows[keep], entries.lane[keep], entries.threshold)
