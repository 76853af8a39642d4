"""Kill rate and acceptance per chunk of a run."""

from __future__ import annotations

import math
import warnings

import numpy as np

from ._axes import axes_or_new
from ._source import run_of


def traces(result, axes=None):
    """Kill rate and acceptance rate per chunk of the run, against the steps.

    In stationarity tours are killed at rate `c`, one over the mean tour duration (the
    dashed line). Lanes start at regenerations, so there is no burn-in to see: a kill rate
    that drifts down means tours longer than the run (the first chunks end only the short
    ones). The numbers are `result.trace` (a `restore.RunTrace`), recorded between chunks
    at no cost per step.

    Arguments:
        result: a `SampleResult` or an `AutoResult` (its final run).
        axes: two matplotlib `Axes` (default: a new figure with two panels).

    Returns:
        The two `Axes`.
    """
    result = run_of(result)
    trace = getattr(result, "trace", None)
    if trace is None:
        raise ValueError("the result has no per-chunk trace (merged from parts with other chunks, or made by hand)")
    if axes is None:
        left = axes_or_new(None, figsize=(10, 3.4))
        left.figure.clear()
        axes = left.figure.subplots(1, 2)
    kill, accept = axes
    kill.plot(trace.step, trace.kill_rate, "o-", color="C3", markersize=3, label="per chunk")
    if getattr(result, "has_tours", False) and int(np.sum(result.sums.num_tours)) > 0:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mean = result.tour_statistics().mean_duration
        if math.isfinite(mean) and mean > 0:
            kill.axhline(1.0 / mean, color="k", linestyle="--", linewidth=1, label="1 / mean tour duration")
    kill.set(xlabel="steps per lane", ylabel="kills per unit time", title="kill rate", ylim=(0, None))
    kill.legend(fontsize="small")
    accept.plot(trace.step, trace.acceptance, "o-", color="C2", markersize=3)
    accept.axhline(result.acceptance_rate, color="k", linestyle="--", linewidth=1)
    accept.set(xlabel="steps per lane", ylabel="accepted moves per step", title="acceptance", ylim=(0, 1))
    return axes
