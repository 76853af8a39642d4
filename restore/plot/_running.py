"""The running estimate of an expectation over the run, with its error band."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ._axes import axes_or_new
from ._source import Observable, draw_values, run_of


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


def running_estimate_values(result, observable: Observable) -> Running:
    """`E[f(x)]` from the stored draws up to each slot, with standard errors over lanes.

    The estimate after slot `s` is the weighted average of `f` over every lane's stored
    draws `0..s` (weights: the draws' holding times), and its standard error treats the
    lanes as independent replicates (ratio estimator over lanes), as
    `result.estimate_draws` does at the last slot. Thinned draws make it a little noisier
    than the run's streamed estimates, which use every step.

    Arguments:
        result: a `SampleResult` or an `AutoResult` with stored draws.
        observable: the name of an observable of the run (as in `result.estimate`, e.g.
            `"x"` or a NumPyro site passed through `target.observables`), or a function
            mapping states `(..., d)` to values `(...)` or `(..., k)`.
    """
    result = run_of(result)
    if result.draws.shape[0] == 0:
        raise ValueError("no draws were stored: pass save=restore.SaveDraws(max_draws > 0) to restore.sample")
    values = draw_values(result, observable)
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


def running_estimate(result, observable: Observable, truth=None, label: str | None = None, ax=None):
    """The running estimate of `E[f(x)]` against the steps, with its 95% band (and the truth).

    See `running_estimate_values` for how it is computed. A vector-valued observable draws
    one line per component, labelled `label[i]`.

    Arguments:
        result: a `SampleResult` or an `AutoResult` with stored draws.
        observable: the name of an observable of the run (e.g. `"x"`, or a NumPyro site
            passed through `target.observables`), or a function of the states `(..., d)`.
        truth: an optional true value (one per component), drawn as a dashed line.
        label: the name of the quantity (default: the observable's name, else "estimate").
        ax: a matplotlib `Axes` (default: a new figure).

    Returns:
        The `Axes`.
    """
    running = running_estimate_values(result, observable)
    if label is None:
        label = observable if isinstance(observable, str) else "estimate"
    shape = running.value.shape[1:]
    value = running.value.reshape(len(running.step), -1)
    band = 1.96 * running.standard_error.reshape(value.shape)
    truths = None if truth is None else np.broadcast_to(np.asarray(truth, np.float64), shape).reshape(-1)
    ax = axes_or_new(ax)
    for j, index in enumerate(np.ndindex(shape)):
        color, name = f"C{j % 10}", label + ("" if not index else "[" + ", ".join(map(str, index)) + "]")
        ax.fill_between(
            running.step,
            value[:, j] - band[:, j],
            value[:, j] + band[:, j],
            color=color,
            alpha=0.25,
            label="95% band" if j == 0 else None,
        )
        ax.plot(running.step, value[:, j], color=color, label=name)
        if truths is not None:
            ax.axhline(
                truths[j],
                color="k" if len(truths) == 1 else color,
                linestyle="--",
                linewidth=1,
                label="truth" if j == 0 else None,
            )
    ax.set(xlabel="steps per lane", ylabel=label, title=f"running estimate of {label}")
    ax.legend(fontsize="small")
    return ax
