"""The running estimate of an expectation over the run, with its error band."""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from ._axes import axes_or_new


class Running(NamedTuple):
    """An estimate after each stored slot of a run.

    Attributes:
        step: steps per lane at each stored slot.
        value: the estimate from the stored draws up to that step, `(slots, ...)`.
        standard_error: its standard error, lanes as independent replicates.
    """

    step: np.ndarray
    value: np.ndarray
    standard_error: np.ndarray


def running_estimate_values(result, fn: Callable[[np.ndarray], np.ndarray]) -> Running:
    """`E[fn(x)]` from the stored draws up to each slot, with standard errors over lanes.

    The estimate after slot `s` is the weighted average of `fn` over every lane's stored
    draws `0..s` (weights: the draws' holding times), and its standard error treats the
    lanes as independent replicates (ratio estimator over lanes), as
    `result.estimate_draws` does at the last slot. Thinned draws make it a little noisier
    than the run's streamed estimates, which use every step.

    Arguments:
        result: a `SampleResult` (or `AutoResult`) with stored draws.
        fn: maps states `(..., d)` to values `(...)` or `(..., k)`.
    """
    result = getattr(result, "result", result)
    if result.draws.shape[0] == 0:
        raise ValueError("no draws were stored: pass max_draws > 0 (or thin) to restore.sample")
    values = np.asarray(fn(result.draws), np.float64)
    if values.shape[:2] != result.draws.shape[:2]:
        raise ValueError(f"fn must keep the leading (draw, lane) axes {result.draws.shape[:2]}, got {values.shape}")
    w = np.asarray(result.draw_weights, np.float64)
    lanes = w.shape[1]
    if lanes < 2:
        raise ValueError("running standard errors need at least 2 lanes")
    t = np.cumsum(w, axis=0)  # (slots, lanes)
    extra = (1,) * (values.ndim - 2)
    f = np.cumsum(w.reshape(w.shape + extra) * values, axis=0)
    total = t.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        value = f.sum(axis=1) / total.reshape((-1,) + extra)
        residual = f - value[:, None] * t.reshape(t.shape + extra)
        se = np.sqrt(np.sum(residual**2, axis=1) * lanes / (lanes - 1.0)) / total.reshape((-1,) + extra)
    step = (np.arange(w.shape[0]) + 1) * result.thin
    return Running(step, value, se)


def running_estimate(result, fn: Callable[[np.ndarray], np.ndarray], truth=None, label: str = "estimate", ax=None):
    """The running estimate of `E[fn(x)]` against the steps, with its 95% band (and the truth).

    See `running_estimate_values` for how it is computed. `fn` must return one number per
    state (select a component for vector observables).

    Arguments:
        result: a `SampleResult` (or `AutoResult`) with stored draws.
        fn: maps states `(..., d)` to values `(...)`.
        truth: an optional true value, drawn as a horizontal line.
        label: the name of the quantity.
        ax: a matplotlib `Axes` (default: a new figure).

    Returns:
        The `Axes`.
    """
    running = running_estimate_values(result, fn)
    if running.value.ndim != 1:
        raise ValueError(f"fn must return one number per state for a running plot, got values of shape {running.value.shape[1:]}")
    ax = axes_or_new(ax)
    ax.fill_between(running.step, running.value - 1.96 * running.standard_error, running.value + 1.96 * running.standard_error, color="C0", alpha=0.25, label="95% band")
    ax.plot(running.step, running.value, color="C0", label=label)
    if truth is not None:
        ax.axhline(float(truth), color="k", linestyle="--", linewidth=1, label="truth")
    ax.set(xlabel="steps per lane", ylabel=label, title=f"running estimate of {label}")
    ax.legend(fontsize="small")
    return ax
