"""The rendering methods by name, built with matched parameters (same small step, same large step)."""

from __future__ import annotations

from ..local import AbstractTorusMutation, KelemenMutation, TorusH2MC, TorusMALA
from ._erpt import ERPT
from ._h2mc_restore import H2MCRestore
from ._learned_regeneration import LearnedRegeneration
from ._mala_restore import MALARestore
from ._metropolis_restore import MetropolisRestore
from ._pssmlt import PSSMLT
from ._renderer import AbstractRenderer
from ._uniform import UniformSampler

#: `path` is Mitsuba's own integrator; the others run on the primary-sample-space target.
METHODS = ("path", "uniform", "pssmlt", "restore", "restore-learned", "mala", "mala-restore", "h2mc", "h2mc-restore", "erpt")
GRADIENT_METHODS = ("mala", "mala-restore", "h2mc", "h2mc-restore")


#: Faithful defaults: Restore's mean tour length and PSSMLT's large-step probability as the
#: paper's authors and Kelemen et al. set them, chosen independently (`docs/rendering.md`
#: has the sweep); ERPT's chain length is its own default.
TOUR_LENGTH, P_LARGE, CHAIN_LENGTH = 1.0, 0.3, 32
#: Default parallel lanes: on a CPU, fewer lanes run longer chains for the same number of
#: paths, which PSSMLT needs (`docs/rendering.md`).
LANES = 2048
#: Methods whose own default differs: Restore's tours are independent, so it gains from the
#: throughput of more lanes, up to where finishing the longest open tours after the budget
#: costs more than it gains (16384 lanes on the pool, `docs/rendering.md`).
METHOD_LANES = {"restore": 8192, "restore-learned": 8192}


def default_lanes(method: str) -> int:
    """The parallel lanes `method` runs by default (`METHOD_LANES`, else `LANES`)."""
    return METHOD_LANES.get(method, LANES)


def make_renderer(
    method: str,
    *,
    tour_length: float = TOUR_LENGTH,
    p_large: float = P_LARGE,
    chain_length: int = CHAIN_LENGTH,
    mutation: AbstractTorusMutation | None = None,
    step_size: float = 1e-4,
) -> AbstractRenderer:
    """The PSS renderer called `method`.

    The Metropolis methods share `mutation` (default `KelemenMutation()`) as small step
    and a uniform draw as large step; `mala` and `mala-restore` move by `TorusMALA(step_size)`,
    `h2mc` and `h2mc-restore` by `TorusH2MC()` (its authors' settings), and `mala` and
    `h2mc` are PSSMLT with that small step (its large steps and `p_large`, as their authors
    run them). `restore-learned` is Metropolis Restore regenerating from a density learned
    from its bootstrap paths (`LearnedRegeneration()`). Each method keeps its own exploration setting: a Restore tour makes
    `tour_length` local moves on average (complete tours), PSSMLT takes a large step with
    probability `p_large`, ERPT chains are `chain_length` mutations long.

    Raises:
        ValueError: for `path` (Mitsuba's integrator is not a PSS renderer) or an unknown name.
    """
    mutation = KelemenMutation() if mutation is None else mutation
    if method == "uniform":
        return UniformSampler()
    if method == "pssmlt":
        return PSSMLT(mutation, p_large=p_large)
    if method == "restore":
        return MetropolisRestore(mutation, tour_length=tour_length)
    if method == "restore-learned":
        return MetropolisRestore(mutation, tour_length=tour_length, learned=LearnedRegeneration())
    if method == "mala":
        return PSSMLT(TorusMALA(step_size), p_large=p_large)
    if method == "mala-restore":
        return MALARestore(step_size=step_size, tour_length=tour_length)
    if method == "h2mc":
        return PSSMLT(TorusH2MC(), p_large=p_large)
    if method == "h2mc-restore":
        return H2MCRestore(tour_length=tour_length)
    if method == "erpt":
        return ERPT(mutation, chain_length=chain_length)
    if method == "path":
        raise ValueError("'path' is Mitsuba's native integrator, not a primary-sample-space renderer")
    raise ValueError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")
