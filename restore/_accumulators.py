"""Streaming per-lane sums for the regenerative ratio estimator: constant memory in the run length."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ._sampler import StepInfo
from ._tour_records import TourRecords

#: Tour durations are binned on a log10 scale over this range for the tail diagnostics.
HISTOGRAM_RANGE = (-6.0, 6.0)
HISTOGRAM_BINS = 96


class LaneSums(NamedTuple):
    """Running sums of one lane (a leading lane axis when batched).

    Per complete tour `k` with integral `F_k = sum w f(x)` and duration `T_k = sum w`,
    the sums `F, F^2, F T, T, T^2` and the count are all the ratio estimator and its
    standard error need. The open tour's partial sums wait until the tour ends. The
    `all_*` sums cover every step, complete tours or not (for lane-based estimates).
    The run loop updates the open tour, the `all_*` sums and the counts at every step
    (`update_lane_sums`); the sums over complete tours and over tour starts once per
    chunk, from the chunk's tour records (`add_recorded_tours`).
    """

    open_f: Float[Array, " m"]
    open_t: Float[Array, ""]
    sum_f: Float[Array, " m"]
    sum_f2: Float[Array, " m"]
    sum_ft: Float[Array, " m"]
    sum_t: Float[Array, ""]
    sum_t2: Float[Array, ""]
    num_tours: Int[Array, ""]
    open_steps: Int[Array, ""]
    max_tour: Float[Array, ""]
    all_f: Float[Array, " m"]
    all_f2: Float[Array, " m"]
    all_t: Float[Array, ""]
    skip_first: Bool[Array, ""]
    log_iw_sum: Float[Array, ""]
    log_iw_sum2: Float[Array, ""]
    num_iw: Int[Array, ""]
    num_invalid: Int[Array, ""]
    num_uncovered: Int[Array, ""]
    num_accepted: Int[Array, ""]
    num_regenerations: Int[Array, ""]
    num_negative_rate: Int[Array, ""]
    num_bound_exceeded: Int[Array, ""]
    max_bound_ratio: Float[Array, ""]


def init_lane_sums(num_lanes: int, size: int, dtype, skip_first: Array) -> LaneSums:
    """Zero sums (`-inf` for log sums); `skip_first` marks lanes that did not start at a regeneration."""

    def start(name: str) -> Array:
        kind, per_observable, integer = _FIELDS[name]
        shape = (num_lanes, size) if per_observable else (num_lanes,)
        return jnp.full(shape, -jnp.inf if kind == "log_sum" else 0, jnp.int32 if integer else dtype)

    return LaneSums(**{name: start(name) for name in LaneSums._fields if name != "skip_first"}, skip_first=skip_first)


def open_tour_totals(sums: LaneSums, values: Array, weight: Array) -> tuple[Array, Array]:
    """`F` `(L, m)` and `T` `(L,)` of each lane's open tour, this step included (the tour's
    totals when it ends at this step)."""
    w = weight[:, None]
    return sums.open_f + jnp.where(w > 0, w * values, 0.0), sums.open_t + weight


def update_lane_sums(sums: LaneSums, values: Array, weight: Array, info: StepInfo) -> LaneSums:
    """Add one step of every lane: `values` `(L, m)` at the held states, weights `(L,)`.

    Only the per-step fields change here (the open tour, the sums over every step, the
    counts). The sums over complete tours and over tour starts are added once per chunk,
    from the chunk's tour records (`add_recorded_tours`): a tenth of the lanes or fewer
    end a tour at a step, and masked updates of every lane at every step cost a tenth of
    a jump-Restore run's time.
    """
    w = weight[:, None]
    wf = jnp.where(w > 0, w * values, 0.0)
    wf2 = jnp.where(w > 0, w * values**2, 0.0)
    open_f, open_t = open_tour_totals(sums, values, weight)
    end = info.regenerated
    bound_ratio = info.bound_ratio
    zero = jnp.zeros((), jnp.int32)
    return sums._replace(
        open_f=jnp.where(end[:, None], 0.0, open_f),
        open_t=jnp.where(end, 0.0, open_t),
        open_steps=jnp.where(end, 0, sums.open_steps + 1),
        all_f=sums.all_f + wf,
        all_f2=sums.all_f2 + wf2,
        all_t=sums.all_t + weight,
        skip_first=sums.skip_first & ~end,
        num_invalid=sums.num_invalid + info.invalid.astype(jnp.int32),
        num_uncovered=sums.num_uncovered + info.uncovered.astype(jnp.int32),
        num_accepted=sums.num_accepted + info.accepted.astype(jnp.int32),
        num_regenerations=sums.num_regenerations + jnp.where(end, 1, zero),
        num_negative_rate=sums.num_negative_rate + info.negative_rate.astype(jnp.int32),
        num_bound_exceeded=sums.num_bound_exceeded + (bound_ratio > 1).astype(jnp.int32),
        max_bound_ratio=jnp.maximum(sums.max_bound_ratio, bound_ratio),
    )


def add_recorded_tours(sums: LaneSums, records: TourRecords) -> LaneSums:
    """Add a chunk's recorded tours (`F`, `T`) and tour starts (importance weights) to the
    sums over complete tours and over starts.

    The records hold every counted tour and every drawn start of the chunk, in order (a
    chunk stops when some lane's buffer is full), so adding them one slot at a time gives
    the same sums, bit for bit, as adding each tour at the step it ended. Samplers without
    tours keep no records, and their tour sums stay zero.
    """
    if records.capacity == 0:
        return sums

    def add(slot, s: dict[str, Array]) -> dict[str, Array]:
        count = slot < records.count
        c = count[:, None]
        f, t = records.integral[:, slot], records.duration[:, slot]
        log_iw = jnp.where(slot < records.starts, records.log_importance_weight[:, slot], -jnp.inf)
        return dict(
            sum_f=s["sum_f"] + jnp.where(c, f, 0.0),
            sum_f2=s["sum_f2"] + jnp.where(c, f**2, 0.0),
            sum_ft=s["sum_ft"] + jnp.where(c, f * t[:, None], 0.0),
            sum_t=s["sum_t"] + jnp.where(count, t, 0.0),
            sum_t2=s["sum_t2"] + jnp.where(count, t**2, 0.0),
            num_tours=s["num_tours"] + count.astype(jnp.int32),
            max_tour=jnp.maximum(s["max_tour"], jnp.where(count, t, 0.0)),
            log_iw_sum=jnp.logaddexp(s["log_iw_sum"], log_iw),
            log_iw_sum2=jnp.logaddexp(s["log_iw_sum2"], 2.0 * log_iw),
            num_iw=s["num_iw"] + (slot < records.starts).astype(jnp.int32),
        )

    start = {name: getattr(sums, name) for name in _RECORDED}
    used = jnp.maximum(jnp.max(records.count), jnp.max(records.starts))  # short chunks fill a few slots
    return sums._replace(**jax.lax.fori_loop(0, used, add, start))


def counted_ends(sums_before: LaneSums, info) -> Array:
    """Lanes whose tour ends at this step and counts (not a lane's partial first tour)."""
    return info.regenerated & ~sums_before.skip_first


def update_histogram(hist: tuple[Array, Array], durations: Array, mask: Array) -> tuple[Array, Array]:
    """Add completed tour durations to a log10-binned (count, total time) histogram."""
    counts, times = hist
    lo, hi = HISTOGRAM_RANGE
    safe = jnp.where(durations > 0, durations, 10.0**lo)  # a tour of zero length is among the shortest
    position = (jnp.log10(safe) - lo) / (hi - lo) * HISTOGRAM_BINS
    index = jnp.clip(jnp.floor(position), 0, HISTOGRAM_BINS - 1).astype(jnp.int32)
    counts = counts.at[index].add(mask.astype(counts.dtype))
    times = times.at[index].add(jnp.where(mask, durations, 0.0).astype(times.dtype))
    return counts, times


def init_histogram(dtype) -> tuple[Array, Array]:
    return jnp.zeros((HISTOGRAM_BINS,), dtype), jnp.zeros((HISTOGRAM_BINS,), dtype)


# How each field of `LaneSums` is reduced, in one table: `(kind, per observable, integer)`.
# Sums that grow with the run ("sum", "log_sum" combined with logaddexp, "max") are drained
# to float64 / int64 host totals after every chunk and restarted on the device, so float32
# runs keep full precision over any number of steps (a float32 sum of 10^6 terms can be
# off by percents) and int32 counts never overflow. "state" fields (the open tour's
# partial sums, its step counter, `skip_first`) stay on the device and are taken from the
# latest chunk.
_FIELDS: dict[str, tuple[str, bool, bool]] = {
    "open_f": ("state", True, False), "open_t": ("state", False, False),
    "sum_f": ("sum", True, False), "sum_f2": ("sum", True, False), "sum_ft": ("sum", True, False),
    "sum_t": ("sum", False, False), "sum_t2": ("sum", False, False), "num_tours": ("sum", False, True),
    "open_steps": ("state", False, True), "max_tour": ("max", False, False),
    "all_f": ("sum", True, False), "all_f2": ("sum", True, False), "all_t": ("sum", False, False),
    "skip_first": ("state", False, False),
    "log_iw_sum": ("log_sum", False, False), "log_iw_sum2": ("log_sum", False, False), "num_iw": ("sum", False, True),
    "num_invalid": ("sum", False, True), "num_uncovered": ("sum", False, True), "num_accepted": ("sum", False, True),
    "num_regenerations": ("sum", False, True), "num_negative_rate": ("sum", False, True),
    "num_bound_exceeded": ("sum", False, True), "max_bound_ratio": ("max", False, False),
}  # fmt: skip
if tuple(_FIELDS) != LaneSums._fields:  # pragma: no cover - a new field without a reduction is a bug
    raise AssertionError("every LaneSums field needs its reduction in _FIELDS, in order")
_ADDITIVE = tuple(name for name, (kind, *_) in _FIELDS.items() if kind == "sum")
_LOG_ADDITIVE = tuple(name for name, (kind, *_) in _FIELDS.items() if kind == "log_sum")
#: The fields summed from the tour records once per chunk (`add_recorded_tours`), not at every step.
_RECORDED = ("sum_f", "sum_f2", "sum_ft", "sum_t", "sum_t2", "num_tours", "max_tour", "log_iw_sum", "log_iw_sum2", "num_iw")
_MAXIMA = tuple(name for name, (kind, *_) in _FIELDS.items() if kind == "max")


def restart_sums(sums: LaneSums) -> LaneSums:
    """The device sums after a drain: totals restarted (zero, or `-inf` for log sums), state kept."""
    restarted = {name: jnp.zeros_like(getattr(sums, name)) for name in _ADDITIVE}
    restarted.update({name: jnp.full_like(getattr(sums, name), -jnp.inf) for name in _LOG_ADDITIVE})
    return sums._replace(**restarted)


def _host(x) -> np.ndarray:
    x = np.asarray(x)
    if np.issubdtype(x.dtype, np.floating):
        return x.astype(np.float64)
    return x.astype(np.int64) if np.issubdtype(x.dtype, np.integer) else x


def drain_sums(total: LaneSums | None, sums: LaneSums) -> LaneSums:
    """Host totals plus the device sums of one chunk (NumPy, float64 / int64).

    Additive fields are added, log sums combined with `logaddexp`, maxima maximised; the
    state fields (open tour, `skip_first`) are taken from `sums`, the latest.
    """
    sums = LaneSums(*(_host(x) for x in sums))
    if total is None:
        return sums
    merged = {name: getattr(total, name) + getattr(sums, name) for name in _ADDITIVE}
    merged.update({name: np.logaddexp(getattr(total, name), getattr(sums, name)) for name in _LOG_ADDITIVE})
    merged.update({name: np.maximum(getattr(total, name), getattr(sums, name)) for name in _MAXIMA})
    return sums._replace(**merged)


def drain_histogram(total: tuple | None, histogram: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Host totals of the tour histogram plus the device histogram of one chunk (per-device rows summed)."""
    counts, times = (np.asarray(h, np.float64) for h in histogram)
    if counts.ndim == 2:  # one partial histogram per device
        counts, times = counts.sum(axis=0), times.sum(axis=0)
    return (counts, times) if total is None else (total[0] + counts, total[1] + times)
