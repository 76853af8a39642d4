"""Tour statistics: is the tour-length distribution well behaved?"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ._pareto import K_HAT_LIMIT, k_hat_limit

#: A tour-length distribution is flagged as heavy-tailed when the longest 1% of tours hold
#: more than this share of the total time (exponential tour lengths give about 5.6%)...
LONGEST_SHARE_LIMIT = 0.3
#: ...or when the effective number of tours `(sum T)^2 / sum T^2` falls below this share of
#: the tour count (exponential tour lengths give about one half).
EFFECTIVE_SHARE_LIMIT = 0.05


class TourStatistics(NamedTuple):
    """Summary of the complete tours of a run.

    Attributes:
        num_tours: complete tours over all lanes.
        mean_duration: mean tour duration (in local-move time units).
        mean_duration_se: its standard error.
        expected_duration: `1 / c = Z_hat / c_tilde`, with the run's importance estimate
            of `Z`. For a sampler calibrated from a `tour_length`, this is the requested
            length corrected for the pilot's error in `Z`.
        effective_num_tours: `(sum T)^2 / sum T^2`, how many equally long tours carry the
            same information.
        longest_share: share of the total tour time held by the longest 1% of tours
            (from a log-binned histogram: exact to a bin, about 30%, in duration).
        max_duration: the longest complete tour.
        incomplete_fraction: share of the simulated time in tours that were still open at
            the end (left out of tour-based estimates).
        heavy_tailed: the warning flag: the Pareto shape of the longest tours is at or above
            its limit, or the shares `LONGEST_SHARE_LIMIT`, `EFFECTIVE_SHARE_LIMIT` are crossed.
        k_hat: Pareto shape of the tail of the tour durations (`restore.K_HAT_LIMIT`); NaN
            with too few tours to fit it.
        k_limit: the largest `k_hat` at which tour-based error bars are trusted for this
            many tours.
        unfinished_tours: tours still running after the finishing steps, left out of the
            tour-based estimates (any at all flags the tours as heavy-tailed).
    """

    num_tours: int
    mean_duration: float
    mean_duration_se: float
    expected_duration: float
    effective_num_tours: float
    longest_share: float
    max_duration: float
    incomplete_fraction: float
    heavy_tailed: bool
    k_hat: float = math.nan
    k_limit: float = math.nan
    unfinished_tours: int = 0

    def __str__(self) -> str:
        """The statistics rounded to what they can tell (`repr` keeps every digit)."""
        return (
            f"TourStatistics({self.num_tours} tours, mean duration {self.mean_duration:.4g} +- {self.mean_duration_se:.2g} "
            f"(expected 1/c = {self.expected_duration:.4g}), longest {self.max_duration:.4g}, effective tours "
            f"{self.effective_num_tours:,.0f}, longest 1% hold {self.longest_share:.1%}, k_hat {self.k_hat:.2f} "
            f"(limit {self.k_limit:.2f}), unfinished {self.unfinished_tours}, heavy-tailed: {self.heavy_tailed})"
        )


def longest_share(counts: np.ndarray, times: np.ndarray, fraction: float = 0.01) -> float:
    """Share of total time in the longest `fraction` of tours, from a duration histogram."""
    total_time, total_count = times.sum(), counts.sum()
    if total_count == 0 or total_time == 0:
        return math.nan
    wanted = max(1.0, math.ceil(fraction * total_count))
    taken_count = taken_time = 0.0
    for c, t in zip(counts[::-1], times[::-1], strict=True):
        if c == 0:
            continue
        if taken_count + c >= wanted:
            taken_time += t * (wanted - taken_count) / c
            break
        taken_count += c
        taken_time += t
    return float(taken_time / total_time)


def tour_statistics(
    sum_t: np.ndarray,
    sum_t2: np.ndarray,
    num_tours: np.ndarray,
    max_tour: np.ndarray,
    all_t: np.ndarray,
    histogram: tuple[np.ndarray, np.ndarray],
    expected_duration: float,
    k_hat: float = math.nan,
    unfinished_tours: int = 0,
) -> TourStatistics:
    n = int(np.sum(num_tours))
    T, T2 = float(np.sum(sum_t, dtype=np.float64)), float(np.sum(sum_t2, dtype=np.float64))
    total = float(np.sum(all_t, dtype=np.float64))
    limit = k_hat_limit(n)
    if n == 0:
        return TourStatistics(0, math.nan, math.nan, expected_duration, 0.0, math.nan, 0.0, 1.0, unfinished_tours > 0, k_hat, limit, unfinished_tours)
    mean = T / n
    var = max(T2 / n - mean**2, 0.0) * n / max(n - 1, 1)
    eff = T**2 / T2 if T2 > 0 else 0.0
    share = longest_share(*histogram)
    stats = TourStatistics(
        num_tours=n,
        mean_duration=mean,
        mean_duration_se=math.sqrt(var / n),
        expected_duration=expected_duration,
        effective_num_tours=eff,
        longest_share=share,
        max_duration=float(np.max(max_tour)),
        incomplete_fraction=max(0.0, 1.0 - T / total) if total > 0 else 1.0,
        heavy_tailed=False,
        k_hat=float(k_hat),
        k_limit=limit,
        unfinished_tours=int(unfinished_tours),
    )
    return stats._replace(heavy_tailed=bool(heavy_tail_reasons(stats)))


def heavy_tail_reasons(stats: TourStatistics) -> str:
    """Why the tours are flagged (`heavy_tailed`), in words that quote only the checks that
    failed: tours left open, a longest 1% that holds too much time, too few effective
    tours, a Pareto tail shape at or above its limit. Empty when none failed."""
    reasons = []
    if stats.unfinished_tours > 0:
        u = stats.unfinished_tours
        reasons.append(f"{u} tour{'s' if u > 1 else ''} still open at the end of the run {'were' if u > 1 else 'was'} left out")
    # With underflowed durations (T or T^2 summing to zero: no effective tours) the tail
    # statistics mean nothing: estimates refuse such runs with a clear error instead.
    if stats.num_tours >= 20 and stats.effective_num_tours > 0:
        if stats.longest_share > LONGEST_SHARE_LIMIT:
            reasons.append(
                f"the longest 1% of tours hold {stats.longest_share:.0%} of the time (more than "
                f"{LONGEST_SHARE_LIMIT:.0%}; exponential tours give about 6%)"
            )
        if stats.effective_num_tours < EFFECTIVE_SHARE_LIMIT * stats.num_tours:
            reasons.append(f"the {stats.num_tours} tours are worth {stats.effective_num_tours:.1f} equally long ones")
        if K_HAT_LIMIT <= stats.k_limit <= stats.k_hat:
            reasons.append(
                f"the tour durations have a heavy tail (Pareto shape k_hat = {stats.k_hat:.2f}, at or above "
                f"{stats.k_limit:.2f}: their variance is likely infinite)"
            )
    return "; ".join(reasons)
