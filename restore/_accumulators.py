"""Streaming per-lane sums for the regenerative ratio estimator: constant memory in the run length."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ._sampler import StepInfo

#: Tour durations are binned on a log10 scale over this range for the tail diagnostics.
HISTOGRAM_RANGE = (-6.0, 6.0)
HISTOGRAM_BINS = 96


class LaneSums(NamedTuple):
    """Running sums of one lane (a leading lane axis when batched).

    Per complete tour `k` with integral `F_k = sum w f(x)` and duration `T_k = sum w`,
    the sums `F, F^2, F T, T, T^2` and the count are all the ratio estimator and its
    standard error need. The open tour's partial sums wait until the tour ends. The
    `all_*` sums cover every step, complete tours or not (for lane-based estimates).
    The run loop updates them at every step (`update_lane_sums`) and, at the end of each
    chunk, adds them to the run's totals on the device (`fold`). `half_f` and `half_t` are
    `all_f` and `all_t` as they stood at the middle of the step budget (`halved`): the two
    halves of a lane's run, which show whether it has forgotten its start.
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
    half_f: Float[Array, " m"]
    half_t: Float[Array, ""]


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


def update_step_sums(sums: LaneSums, values: Array, weight: Array, info: StepInfo, integral: Array, duration: Array) -> LaneSums:
    """Add one step of every lane to the fields that change at every step: `values` `(L, m)`
    at the held states, weights `(L,)`, and the open tours' totals this step included
    (`open_tour_totals`). The sums over complete tours and tour starts change only for the
    lanes that end a tour or draw a start, a tenth of them or fewer (`add_events`).
    """
    w = weight[:, None]
    wf = jnp.where(w > 0, w * values, 0.0)
    wf2 = jnp.where(w > 0, w * values**2, 0.0)
    end = info.regenerated
    bound_ratio = info.bound_ratio
    zero = jnp.zeros((), jnp.int32)
    return sums._replace(
        open_f=jnp.where(end[:, None], 0.0, integral),
        open_t=jnp.where(end, 0.0, duration),
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


def add_events(
    sums: LaneSums, index: Array, ended: Array, drawn: Array, integral: Array, duration: Array, log_importance_weight: Array
) -> LaneSums:
    """Add the tours that ended (integrals `(S, m)`, durations `(S,)`) and the starts drawn
    (log importance weights `(S,)`) at lanes `index` `(S,)` (distinct; `L` or more: none)
    to the sums over complete tours and over starts.

    Only those lanes' rows are read and written, so a step costs in proportion to the
    lanes that end a tour; the sums are the same, bit for bit, as adding zeros at the
    other lanes.
    """
    num_lanes = sums.all_t.shape[0]
    safe = jnp.minimum(index, num_lanes - 1)
    e, e2 = ended, ended[:, None]
    t = jnp.where(ended, duration, 0.0)
    f = jnp.where(e2, integral, 0.0)
    log_iw = jnp.where(drawn, log_importance_weight, -jnp.inf)
    fields = dict(
        sum_f=lambda old: old + f,
        sum_f2=lambda old: old + jnp.where(e2, integral**2, 0.0),
        sum_ft=lambda old: old + jnp.where(e2, integral * duration[:, None], 0.0),
        sum_t=lambda old: old + t,
        sum_t2=lambda old: old + t * t,
        num_tours=lambda old: old + e.astype(jnp.int32),
        max_tour=lambda old: jnp.maximum(old, t),
        log_iw_sum=lambda old: jnp.logaddexp(old, log_iw),
        log_iw_sum2=lambda old: jnp.logaddexp(old, 2.0 * log_iw),
        num_iw=lambda old: old + drawn.astype(jnp.int32),
    )
    new = {name: getattr(sums, name).at[index].set(update(getattr(sums, name)[safe]), mode="drop") for name, update in fields.items()}
    return sums._replace(**new)


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
# Sums that grow with the run ("sum", "log_sum" combined with logaddexp, "max") are kept
# per chunk, then added to the run's totals on the device and restarted (`fold`); the
# float sums are added with their rounding errors carried along in float32 runs, so those
# keep full precision over any number of steps (a float32 sum of 10^6 terms can be off by
# percents). "state" fields (the open tour's partial sums, its step counter,
# `skip_first`) are the lane's current state, the same in the chunk's sums and the totals.
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
    "half_f": ("state", True, False), "half_t": ("state", False, False),
}  # fmt: skip
if tuple(_FIELDS) != LaneSums._fields:  # pragma: no cover - a new field without a reduction is a bug
    raise AssertionError("every LaneSums field needs its reduction in _FIELDS, in order")
_ADDITIVE = tuple(name for name, (kind, *_) in _FIELDS.items() if kind == "sum")
_FLOAT_SUMS = tuple(name for name, (kind, _, integer) in _FIELDS.items() if kind == "sum" and not integer)
_LOG_ADDITIVE = tuple(name for name, (kind, *_) in _FIELDS.items() if kind == "log_sum")
_MAXIMA = tuple(name for name, (kind, *_) in _FIELDS.items() if kind == "max")


class Totals(NamedTuple):
    """The run's totals, on the device: per-lane sums and the tour histogram.

    Attributes:
        sums: per-lane totals of every chunk so far (`LaneSums`; the state fields are the
            lanes' current ones).
        histogram: `(counts, total time)` of complete tour durations in log10 bins.
        error: in float32 runs, the rounding errors of the float sums and of the histogram,
            carried along as they are added (compensated summation), else `None`.
    """

    sums: LaneSums
    histogram: tuple[Array, Array]
    error: tuple | None


def _compensated(dtype) -> bool:
    return jnp.finfo(dtype).bits < 64


def init_totals(sums: LaneSums, histogram: tuple[Array, Array]) -> Totals:
    """Zero totals shaped like a chunk's sums and histogram."""
    dtype = sums.all_t.dtype
    error = None
    if _compensated(dtype):
        error = (tuple(jnp.zeros_like(getattr(sums, name)) for name in _FLOAT_SUMS), jax.tree.map(jnp.zeros_like, histogram))
    return Totals(restart_sums(sums), jax.tree.map(jnp.zeros_like, histogram), error)


def _two_sum(a: Array, b: Array) -> tuple[Array, Array]:
    """`a + b` and its rounding error (Knuth's TwoSum: exact in any order of magnitude)."""
    s = a + b
    v = s - a
    return s, (a - (s - v)) + (b - v)


def _add(total: Array, part: Array, error: Array | None) -> tuple[Array, Array | None]:
    """`total + part`, with `error` the part of the sum lost so far: it is added back with the next
    part (Kahan's feedback), so it stays below the total's last bit."""
    if error is None:
        return total + part, None
    return _two_sum(total, part + error)


def fold(totals: Totals, sums: LaneSums, histogram: tuple[Array, Array]) -> Totals:
    """The totals with one chunk's sums and histogram added (on the device)."""
    merged = {name: getattr(totals.sums, name) + getattr(sums, name) for name in _ADDITIVE if name not in _FLOAT_SUMS}
    merged.update({name: jnp.logaddexp(getattr(totals.sums, name), getattr(sums, name)) for name in _LOG_ADDITIVE})
    merged.update({name: jnp.maximum(getattr(totals.sums, name), getattr(sums, name)) for name in _MAXIMA})
    merged.update({name: getattr(sums, name) for name, (kind, *_) in _FIELDS.items() if kind == "state"})
    errors, histogram_errors = totals.error if totals.error is not None else ((None,) * len(_FLOAT_SUMS), (None, None))
    new_errors = []
    for name, error in zip(_FLOAT_SUMS, errors):
        merged[name], error = _add(getattr(totals.sums, name), getattr(sums, name), error)
        new_errors.append(error)
    counts, count_error = _add(totals.histogram[0], histogram[0], histogram_errors[0])
    times, time_error = _add(totals.histogram[1], histogram[1], histogram_errors[1])
    error = None if totals.error is None else (tuple(new_errors), (count_error, time_error))
    return Totals(LaneSums(**merged), (counts, times), error)


def halved(totals: Totals, sums: LaneSums, now: Array) -> tuple[Totals, LaneSums]:
    """The totals and the restarted chunk sums with the totals' `all_f` and `all_t` kept as
    the first half of the run (`half_f`, `half_t`) if `now` (the chunk ended at the middle of
    the budget), else unchanged."""
    keep = {"half_f": jnp.where(now, totals.sums.all_f, sums.half_f), "half_t": jnp.where(now, totals.sums.all_t, sums.half_t)}
    return totals._replace(sums=totals.sums._replace(**keep)), sums._replace(**keep)


def restart_sums(sums: LaneSums) -> LaneSums:
    """The chunk's sums after they joined the totals: restarted (zero, or `-inf` for log sums), state kept."""
    restarted = {name: jnp.zeros_like(getattr(sums, name)) for name in _ADDITIVE + _MAXIMA}
    restarted.update({name: jnp.full_like(getattr(sums, name), -jnp.inf) for name in _LOG_ADDITIVE})
    return sums._replace(**restarted)


def _host(x) -> np.ndarray:
    x = np.asarray(x)
    if np.issubdtype(x.dtype, np.floating):
        return x.astype(np.float64)
    return x.astype(np.int64) if np.issubdtype(x.dtype, np.integer) else x


def host_totals(totals: Totals) -> tuple[LaneSums, tuple[np.ndarray, np.ndarray]]:
    """The totals on the host as float64 / int64, rounding errors added back; a histogram
    kept per device (a leading device axis) is summed over the devices."""
    sums = LaneSums._make(_host(x) for x in totals.sums)
    counts, times = (_host(h) for h in totals.histogram)
    if totals.error is not None:
        errors, (count_error, time_error) = totals.error
        sums = sums._replace(**{name: getattr(sums, name) + _host(e) for name, e in zip(_FLOAT_SUMS, errors)})
        counts, times = counts + _host(count_error), times + _host(time_error)
    if counts.ndim == 2:  # one partial histogram per device
        counts, times = counts.sum(axis=0), times.sum(axis=0)
    return sums, (counts, times)
