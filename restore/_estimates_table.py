"""The table of a run's estimates in its `summary()`: one row per component of each observable.

Like `arviz.summary` or NumPyro's `print_summary`, but with what a Restore estimate carries:
the estimate, its standard error, the effective sample size `Var_pi(f) / se^2`, the tail
shape `k_hat` of the terms it sums and whether its error bar can be trusted. Vector
observables get one row per component (`alpha[0]`, `w[1,2]`); past `max_rows` components an
observable's other components are summed up in one line, so a wide target stays readable and
no unreliable component goes unseen.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable

import numpy as np

from ._estimates import Estimate, UnreliableEstimateWarning, unreliable_reason
from ._observables import Observables

#: Components of one observable shown as rows before the rest are summed up in one line.
MAX_ROWS = 12

_HEADER = ("", "mean", "se", "ess", "k_hat", "reliable")


def component_names(name: str, shape: tuple[int, ...]) -> list[str]:
    """`name` for a scalar, else `name[i]` / `name[i,j]` per component in C order."""
    if not shape:
        return [name]
    return [f"{name}[{','.join(map(str, index))}]" for index in np.ndindex(*shape)]


def _number(value: float, spec: str) -> str:
    return format(value, spec) if math.isfinite(value) else str(value)


def _mean_and_error(value: float, error: float) -> tuple[str, str]:
    """Both to the decimal place of the error's second significant digit (`0.8676`, `0.0021`)."""
    if not (math.isfinite(error) and error > 0):
        return _number(value, ".4g"), _number(error, ".2g")
    places = min(max(1 - math.floor(math.log10(error)), 0), 12)
    return _number(value, f".{places}f"), f"{error:.{places}f}"


def _rows(names: list[str], est: Estimate, ess: np.ndarray, max_rows: int) -> list[tuple[str, ...]]:
    """An observable's rows: one per component up to `max_rows`, then one for the rest."""
    value, error, k_hat, ess = (
        np.broadcast_to(np.asarray(a, np.float64), np.shape(est.value)).reshape(-1)
        for a in (est.value, est.standard_error, est.k_hat, ess)
    )
    reliable = np.asarray(est.reliable).reshape(-1)
    rows: list[tuple[str, ...]] = [
        (
            names[i],
            *_mean_and_error(value[i], error[i]),
            _number(ess[i], ",.0f"),
            _number(k_hat[i], ".2f"),
            "yes" if reliable[i] else "NO",
        )
        for i in range(min(len(names), max_rows))
    ]
    if len(names) > max_rows:
        rest = slice(max_rows, None)
        worst = float(np.nanmax(k_hat[rest])) if np.any(np.isfinite(k_hat[rest])) else math.nan
        bad = int(np.sum(~reliable[rest]))
        least = _number(float(np.min(ess[rest])), ",.0f")
        verdict = f"{bad} NO" if bad else "all yes"
        rows.append((f"... {len(names) - max_rows} more", "", "", f">={least}", f"<={_number(worst, '.2f')}", verdict))
    return rows


def estimates_table(
    observables: Observables,
    estimate: Callable[[str], Estimate],
    ess: Callable[[str], np.ndarray],
    method: str,
    max_rows: int = MAX_ROWS,
) -> list[str]:
    """The lines of the table of a run's estimates, for its `summary()`.

    Arguments:
        observables: what the run streamed; the position `"x"` is left out where it was
            only added because other observables were given.
        estimate: a name's `Estimate` by the run's default method (e.g. `SampleResult.estimate`).
        ess: a name's effective sample size (e.g. `SampleResult.ess`).
        method: that method's name, for the title.
        max_rows: rows per observable before its other components are summed up in one.

    The warnings of unreliable estimates are replaced by their rows and a line that says why.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnreliableEstimateWarning)
        try:
            estimates = [(slot, estimate(slot.name), ess(slot.name)) for slot in observables.requested]
        except ValueError as err:  # e.g. fewer than two complete tours
            return [f"  estimates: none ({err})"]
    rows: list[tuple[str, ...]] = []
    unreliable: dict[str, list[str]] = {}
    for slot, est, sizes in estimates:
        rows += _rows(component_names(slot.name, slot.shape), est, sizes, max_rows)
        if not np.all(est.reliable):
            unreliable.setdefault(unreliable_reason(est), []).append(slot.name)
    widths = [max(len(row[j]) for row in [_HEADER, *rows]) for j in range(len(_HEADER))]

    def line(row: tuple[str, ...]) -> str:
        cells = (c.ljust(w) if j in (0, 5) else c.rjust(w) for j, (c, w) in enumerate(zip(row, widths, strict=True)))
        return ("    " + "  ".join(cells)).rstrip()

    limit = estimates[-1][1].k_limit
    trusted = "" if math.isnan(limit) else f", k_hat trusted below {limit:.2f}"
    lines = [f"  estimates ({method}; se: standard error, ess: effective sample size{trusted})", line(_HEADER)]
    lines += [line(row) for row in rows]
    lines += [f"  UNRELIABLE {', '.join(names)}: {reason}" for reason, names in unreliable.items()]
    return lines
