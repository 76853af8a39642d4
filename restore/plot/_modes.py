"""Mode (or labelling) weights: estimates with 95% intervals against the truth and other methods."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from .._autosample import AutoResult
from .._result import SampleResult
from ._axes import axes_or_new


def mode_weights(
    estimate,
    truth=None,
    others: Mapping[str, object] | None = None,
    labels: Sequence[str] | None = None,
    ax=None,
    name: str | None = None,
):
    """Estimated weights of modes with 95% intervals, against the truth and other methods.

    Arguments:
        estimate: an `Estimate` of the mode weights (e.g. `result.estimate("modes")` of a
            one-hot observable), an array of weights, or a `SampleResult` or `AutoResult`
            whose observable `name` holds them.
        truth: the true weights, drawn as grey bars.
        others: more estimates by name (e.g. `{"NUTS": shares}`), arrays or `Estimate`s.
        labels: a name per mode (default `0, 1, ...`).
        ax: a matplotlib `Axes` (default: a new figure).
        name: the observable of the weights, when `estimate` is a result (e.g. `"modes"`).

    Returns:
        The `Axes`.
    """
    if isinstance(estimate, (SampleResult, AutoResult)):
        if name is None:
            raise ValueError("name the observable of the mode weights, e.g. mode_weights(result, name='modes')")
        estimate = estimate.estimate(name)
    elif name is not None:
        raise ValueError(
            f"name={name!r} picks an observable of a result, but the estimate is a {type(estimate).__name__}"
        )
    entries = {"Restore": estimate, **(others or {})}
    k = np.size(getattr(estimate, "value", estimate))
    for method, entry in entries.items():
        if np.size(getattr(entry, "value", entry)) != k:
            raise ValueError(f"{method} has {np.size(getattr(entry, 'value', entry))} weights, the estimate has {k}")
    ax = axes_or_new(ax)
    modes = np.arange(k)
    if truth is not None:
        ax.bar(modes, np.reshape(np.asarray(truth, np.float64), -1), color="lightgrey", label="truth")
    width = 0.5 / max(len(entries), 1)
    for i, (method, entry) in enumerate(entries.items()):
        value = np.reshape(np.asarray(getattr(entry, "value", entry), np.float64), -1)
        se = getattr(entry, "standard_error", None)
        shift = (i - (len(entries) - 1) / 2) * width
        yerr = None if se is None else 1.96 * np.reshape(np.asarray(se, np.float64), -1)
        ax.errorbar(
            modes + shift,
            value,
            yerr=yerr,
            fmt="o",
            capsize=5,
            color=f"C{i}",
            label=method + (", 95%" if yerr is not None else ""),
        )
    ax.set(
        xticks=modes,
        xticklabels=list(labels) if labels is not None else [str(m) for m in modes],
        ylabel="weight",
        ylim=(0, None),
        title="mode weights",
    )
    ax.legend(fontsize="small")
    return ax
