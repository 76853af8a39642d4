"""The rendering methods by name, built with matched parameters (same small step, same large step)."""

from __future__ import annotations

from ..local import AbstractTorusMutation, KelemenMutation
from ._erpt import ERPT
from ._mala_restore import MALARestore
from ._metropolis_restore import MetropolisRestore
from ._pssmlt import PSSMLT
from ._renderer import AbstractRenderer
from ._uniform import UniformSampler

#: `path` is Mitsuba's own integrator; the others run on the primary-sample-space target.
METHODS = ("path", "uniform", "pssmlt", "restore", "mala-restore", "erpt")
GRADIENT_METHODS = ("mala-restore",)


def make_renderer(
    method: str,
    *,
    tour_length: float = 32.0,
    mutation: AbstractTorusMutation | None = None,
    step_size: float = 1e-4,
) -> AbstractRenderer:
    """The PSS renderer called `method`, with parameters matched across methods.

    All share `mutation` (default `KelemenMutation()`) as small step and a uniform draw
    as large step. A Restore tour makes `tour_length` local moves on average; PSSMLT takes
    a large step with probability `1 / (tour_length + 1)`, the same share of fresh
    uniform draws; ERPT chains are `tour_length` mutations long.

    Raises:
        ValueError: for `path` (Mitsuba's integrator is not a PSS renderer) or an unknown name.
    """
    mutation = KelemenMutation() if mutation is None else mutation
    if method == "uniform":
        return UniformSampler()
    if method == "pssmlt":
        return PSSMLT(mutation, p_large=1.0 / (tour_length + 1.0))
    if method == "restore":
        return MetropolisRestore(mutation, tour_length=tour_length)
    if method == "mala-restore":
        return MALARestore(step_size=step_size, tour_length=tour_length)
    if method == "erpt":
        return ERPT(mutation, chain_length=max(1, round(tour_length)))
    if method == "path":
        raise ValueError("'path' is Mitsuba's native integrator, not a primary-sample-space renderer")
    raise ValueError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
