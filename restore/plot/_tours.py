"""The tour-length distribution of a run, with the generalised Pareto fit of its tail."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .._accumulators import HISTOGRAM_BINS, HISTOGRAM_RANGE
from .._pareto import gpd_fit, tail_length
from .._tails import longest_durations
from ._axes import axes_or_new
from ._source import run_of

#: Bins per decade of the run's tour-duration histogram.
BINS_PER_DECADE = round(HISTOGRAM_BINS / (HISTOGRAM_RANGE[1] - HISTOGRAM_RANGE[0]))


class TourTail(NamedTuple):
    """The numbers behind `tour_lengths`.

    Attributes:
        num_tours: complete tours `n`.
        edges: tour durations at the edges of the duration histogram's bins (log-spaced).
        survival: share of tours longer than each edge, from the histogram.
        largest: the longest tours, exact (from the run's tail buffer), longest first.
        threshold: the GPD threshold (the `tail_length(n) + 1`-th longest tour); NaN
            when the tail cannot be fitted.
        k_hat: the fitted tail shape (the `k_hat` of `tour_statistics`).
        sigma: the fitted GPD scale.
        mean_duration: the mean tour duration.
    """

    num_tours: int
    edges: np.ndarray
    survival: np.ndarray
    largest: np.ndarray
    threshold: float
    k_hat: float
    sigma: float
    mean_duration: float

    def fitted_survival(self, durations: np.ndarray) -> np.ndarray:
        """The share of tours longer than `durations` (above the threshold) under the GPD fit."""
        x = np.asarray(durations, np.float64) - self.threshold
        share = tail_length(self.num_tours) / self.num_tours
        if abs(self.k_hat) < 1e-12:
            return share * np.exp(-x / self.sigma)
        with np.errstate(invalid="ignore", divide="ignore"):
            return share * np.power(np.maximum(1.0 + self.k_hat * x / self.sigma, 0.0), -1.0 / self.k_hat)


def tour_tail(result) -> TourTail:
    """The tour-length distribution of a Restore run and the GPD fit of its tail.

    The bulk comes from the run's log-binned histogram of complete tour durations, the
    tail from the run's tail buffer (`result.tails`), which holds the run's longest
    tours exactly; the fit is the one behind `k_hat` (`restore._pareto`). `result` is a
    `SampleResult` or an `AutoResult` (its final run).
    """
    result = run_of(result)
    if not getattr(result, "has_tours", False) or result.tails is None:
        raise ValueError(f"{result.sampler_name} has no tours to plot")
    counts = np.asarray(result.histogram[0], np.float64)
    n = int(np.sum(result.sums.num_tours))
    if n == 0:
        raise ValueError("the run has no complete tour")
    # The first bin also holds every tour shorter than its lower edge: the survival function is
    # known from its upper edge on.
    edges = np.logspace(*HISTOGRAM_RANGE, HISTOGRAM_BINS + 1)[1:]
    survival = np.concatenate([np.cumsum(counts[::-1])[::-1][1:], [0.0]]) / max(counts.sum(), 1.0)
    largest = longest_durations(result.tails)
    mean = float(np.sum(result.sums.sum_t)) / n
    threshold = k_hat = sigma = math.nan
    top = largest[: tail_length(n) + 1]
    if n >= 25 and top.size >= 6 and top[0] > top[-1]:
        threshold = float(top[-1])
        k_hat, sigma = gpd_fit(top[:-1] - threshold)
    return TourTail(n, edges, survival, largest, threshold, float(k_hat), float(sigma), mean)


def duration_limits(tail: TourTail) -> tuple[float, float]:
    """The x-axis of `tour_lengths`: from half a decade before the survival function starts
    to fall (its first 1%; tours that last no time, e.g. started where the target is zero,
    make a plateau below 1) to twice the longest tour."""
    keep = tail.survival > 0
    falling = np.flatnonzero(tail.survival < 0.99 * tail.survival[0])
    left = tail.edges[max(int(falling[0]) - BINS_PER_DECADE // 2, 0)] if falling.size else tail.edges[0]
    right = 2.0 * (tail.largest[0] if tail.largest.size else tail.edges[keep][-1])
    return float(left), float(right)


def tour_lengths(result, ax=None):
    """Survival function of the tour durations on log-log axes, with the tail fit and `k_hat`.

    Healthy tours are close to exponential with mean `1/c` (dashed); a straight tail on
    these axes is a power law, whose shape `k_hat` at or above 1/2 means infinite variance.

    Arguments:
        result: a `SampleResult` of a Restore sampler, or an `AutoResult`.
        ax: a matplotlib `Axes` to draw on (default: a new figure).

    Returns:
        The `Axes`.
    """
    tail = tour_tail(result)
    ax = axes_or_new(ax)
    keep = tail.survival > 0
    left, right = duration_limits(tail)
    ax.step(tail.edges[keep], tail.survival[keep], where="post", color="C0", label="all tours (histogram)")
    ranks = np.arange(1, tail.largest.size + 1) / tail.num_tours
    ax.plot(tail.largest, ranks, ".", color="C0", markersize=3, label="longest tours (exact)")
    grid = np.logspace(np.log10(left), np.log10(right), 200)
    ax.plot(
        grid,
        np.exp(-grid / tail.mean_duration),
        "--",
        color="grey",
        label=f"exponential, mean {tail.mean_duration:.3g}",
    )
    if math.isfinite(tail.threshold):
        above = grid[grid >= tail.threshold]
        ax.plot(above, tail.fitted_survival(above), color="C3", label=f"Pareto tail fit, k_hat = {tail.k_hat:.2f}")
    ax.set(
        xscale="log",
        yscale="log",
        xlabel="tour duration",
        ylabel="share of tours longer",
        xlim=(left, right),
        ylim=(0.5 / tail.num_tours, 1.5),
    )
    verdict = (
        ""
        if not math.isfinite(tail.k_hat)
        else (" (heavy: error bars unreliable)" if tail.k_hat >= 0.5 else " (light)")
    )
    ax.set_title(f"{tail.num_tours:,} tours, tail k_hat = {tail.k_hat:.2f}{verdict}")
    ax.legend(fontsize="small")
    return ax
