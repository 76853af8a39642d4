"""Per-tour records kept on the device during one chunk of a run, then handed to the host.

Every complete tour's duration `T` and observable integrals `F`, and every tour start's
importance weight, are written to a small per-lane buffer. At the end of a chunk the
program adds them to the streaming sums over complete tours and starts
(`_accumulators.add_recorded_tours`: once per chunk instead of a masked update of every
lane at every step). The host then takes the buffers and keeps the largest values, since
the sums do not hold the tail of the tours: whether a few tours dominate, and so whether
the standard errors can be trusted, is read off the largest tours (`_tails.add_records`:
the records wait, packed per lane, and join the top sets in batches). A chunk stops early
when some lane's buffer is full, so no tour is ever lost.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

#: Records per lane are capped so that the buffers hold at most this many numbers.
MAX_RECORD_ELEMENTS = 2**20
#: At most this many tours per lane between two drains (the merge into the top sets sorts them).
MAX_RECORDS_PER_LANE = 64


class TourRecords(NamedTuple):
    """The tours completed (and starts drawn) by each lane since the last drain.

    Attributes:
        duration: `(L, R)` durations `T` of complete tours, in order.
        integral: `(L, R, m)` their observable integrals `F`.
        count: `(L,)` how many tours each lane recorded.
        log_importance_weight: `(L, R)` `log p(y) - log q(y)` at each drawn tour start.
        starts: `(L,)` how many starts each lane recorded.
    """

    duration: Float[Array, "L R"]
    integral: Float[Array, "L R m"]
    count: Int[Array, " L"]
    log_importance_weight: Float[Array, "L R"]
    starts: Int[Array, " L"]

    @property
    def capacity(self) -> int:
        return int(self.duration.shape[1])


def records_per_lane(num_lanes: int, size: int) -> int:
    """The buffer depth `R`, within the memory cap.

    It depends on the number of lanes and observables only, not on the run's length, so
    runs of different lengths share one compiled program.
    """
    by_memory = MAX_RECORD_ELEMENTS // max(num_lanes * (size + 2), 1)
    return int(max(4, min(MAX_RECORDS_PER_LANE, by_memory)))


def init_records(num_lanes: int, size: int, depth: int, dtype) -> TourRecords:
    """Empty buffers of depth `depth` (0 for samplers without tours)."""
    count = jnp.zeros((num_lanes,), jnp.int32)
    return TourRecords(
        jnp.zeros((num_lanes, depth), dtype),
        jnp.zeros((num_lanes, depth, size), dtype),
        count,
        jnp.zeros((num_lanes, depth), dtype),
        count,
    )


def record(
    records: TourRecords,
    duration: Float[Array, " L"],
    integral: Float[Array, "L m"],
    ended: Bool[Array, " L"],
    log_importance_weight: Float[Array, " L"],
    drawn: Bool[Array, " L"],
) -> TourRecords:
    """Append the tours that ended (and the starts drawn) at this step, lane by lane."""
    depth = records.capacity
    if depth == 0:
        return records
    lanes = jnp.arange(duration.shape[0])
    slot = jnp.where(ended, records.count, depth)  # out of range: dropped
    start_slot = jnp.where(drawn, records.starts, depth)
    return TourRecords(
        records.duration.at[lanes, slot].set(duration, mode="drop"),
        records.integral.at[lanes, slot].set(integral, mode="drop"),
        records.count + ended.astype(jnp.int32),
        records.log_importance_weight.at[lanes, start_slot].set(log_importance_weight, mode="drop"),
        records.starts + drawn.astype(jnp.int32),
    )


def has_room(records: TourRecords) -> Array:
    """Every lane can record one more tour and one more start (else the chunk must stop)."""
    depth = records.capacity
    if depth == 0:
        return jnp.asarray(True)
    return jnp.all(records.count < depth) & jnp.all(records.starts < depth)


def emptied(records: TourRecords) -> TourRecords:
    """The buffers after the host took their contents."""
    return records._replace(count=jnp.zeros_like(records.count), starts=jnp.zeros_like(records.starts))
