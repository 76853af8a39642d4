"""What a plot reads: the `SampleResult` of a run, and an observable given by name or as a function.

Plots take what `restore.sample` and `restore.autosample` return alike, and name
observables as `result.estimate` does: the names given to `restore.sample` (NumPyro site
names from `NumPyroTarget.observables` among them), evaluated on the stored draws.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import numpy as np

from .._autosample import AutoResult
from .._result import SampleResult

Observable = str | Callable[[np.ndarray], np.ndarray]


def run_of(result) -> SampleResult:
    """The `SampleResult` behind `result`: itself, or the final run of an `AutoResult`."""
    run = result.result if isinstance(result, AutoResult) else result
    if not isinstance(run, SampleResult):
        raise TypeError(f"expected what restore.sample or restore.autosample returns, got {type(result).__name__}")
    return run


def draw_values(run: SampleResult, observable: Observable) -> np.ndarray:
    """`observable` on every stored draw, `(slots, lanes, ...)`.

    A name picks an observable streamed by the run (`result.estimate`'s names), whose
    function of one state is mapped over the draws; a function maps the draws `(..., d)`
    itself.
    """
    if not isinstance(observable, str):
        if not callable(observable):
            raise TypeError(f"an observable is a name or a function of the draws, got {type(observable).__name__}")
        return np.asarray(observable(run.draws), np.float64)
    slot = run.observables.slot(observable)
    fn = run.observables.functions[run.observables.slots.index(slot)]
    points = np.reshape(run.draws, (-1, run.draws.shape[-1]))
    values = np.asarray(jax.jit(jax.vmap(fn))(points), np.float64)
    return values.reshape(run.draws.shape[:2] + slot.shape)
