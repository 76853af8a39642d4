"""Joining the results of runs over disjoint lanes (`first_lane`) into one result."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import jax
import numpy as np

from ._accumulators import LaneSums
from ._result import SampleResult
from ._tails import merge_tails
from ._trace import merge_traces

# What every part must share for the lanes to be parts of one run.
_SHARED = ("sampler_name", "is_regenerative", "has_tours", "num_steps", "thin", "weights", "log_rate")


def merge_results(results: Sequence[SampleResult]) -> SampleResult:
    """One result from runs over disjoint sets of lanes of the same sampler, key and settings.

    Split a large run with `restore.sample(..., num_lanes=n, first_lane=k * n)` for
    `k = 0, 1, ...` (on several machines, say), then join the parts here: per-lane sums,
    stored draws and final states are concatenated along the lane axis in the given order,
    the tour histograms are added, and every estimate is as if one run had all the
    lanes (with `first_lane` in increasing order, the per-lane sums are bit-identical to
    those of that single run). The wall time is the longest part's (parts run in parallel).

    Raises:
        ValueError: for fewer than one result, or parts that differ in sampler, step
            count, weights, thinning, kill-rate constant or observables, or whose stored
            draws have different lengths (pass the same `thin` to every part).
    """
    results = list(results)
    if not results or not all(isinstance(r, SampleResult) for r in results):
        raise ValueError("merge_results needs a non-empty sequence of SampleResult")
    first = results[0]
    for i, other in enumerate(results[1:], start=1):
        for name in _SHARED:
            if getattr(other, name) != getattr(first, name):
                raise ValueError(
                    f"result {i} has {name}={getattr(other, name)!r} but result 0 has {getattr(first, name)!r}: "
                    "only parts of one run (same sampler, key and settings, disjoint first_lane) can be merged"
                )
        if other.observables.slots != first.observables.slots:
            raise ValueError(f"result {i} streamed other observables than result 0")
        if other.draws.shape[0] != first.draws.shape[0]:
            raise ValueError(
                f"result {i} stored {other.draws.shape[0]} draws per lane, result 0 stored {first.draws.shape[0]}: "
                "the thinning followed each part's draws budget; pass the same SaveDraws(thin=...) to every part"
            )
    concat = lambda *parts: np.concatenate(parts, axis=0)
    sums = LaneSums._make(concat(*(np.asarray(getattr(r.sums, f)) for r in results)) for f in LaneSums._fields)
    final_state = jax.tree.map(concat, *(r.final_state for r in results))
    offsets = np.cumsum([0] + [r.num_lanes for r in results[:-1]]).tolist()
    tails = None if first.tails is None else merge_tails([r.tails for r in results if r.tails is not None], offsets)
    return dataclasses.replace(
        first,
        sums=sums,
        tails=tails,
        histogram=tuple(sum(np.asarray(r.histogram[k]) for r in results) for k in range(2)),
        draws=np.concatenate([r.draws for r in results], axis=1),
        draw_weights=np.concatenate([r.draw_weights for r in results], axis=1),
        final_state=final_state,
        expected_tour_times=None if first.expected_tour_times is None else concat(*(r.expected_tour_times for r in results)),
        num_lanes=sum(r.num_lanes for r in results),
        finishing_steps=max(r.finishing_steps for r in results),
        unfinished_tours=sum(r.unfinished_tours for r in results),
        wall_time=max(r.wall_time for r in results),
        interrupted=any(r.interrupted for r in results),
        tours_dropped=any(r.tours_dropped for r in results),
        trace=merge_traces([r.trace for r in results]),
    )
