"""MALA Restore: jump Restore with Metropolis-adjusted Langevin moves on the torus."""

from __future__ import annotations

from ..local import TorusMALA
from ._learned_regeneration import LearnedRegeneration
from ._restore_renderer import AbstractPSSRestore


class MALARestore(AbstractPSSRestore):
    """MALA Restore: gradient-informed local dynamics, uniform regeneration, `gamma = c / lum`.

    Local moves propose `wrap(u + h grad log lum + sqrt(2h) N(0, I))` and accept with the
    exact wrapped-normal Hastings ratio (see `restore.local.TorusMALA`); fresh draws and proposals are
    evaluated together with `target.jax_evaluate_with_grad`, once per lane and step.
    Estimator and tour length as in `MetropolisRestore`.

    The default `step_size = 1e-4` gives proposal noise `sqrt(2h) = 0.014` per coordinate,
    the scale of the Kelemen step's largest moves (`1/64`), so the two Restore variants
    explore at comparable scales.

    Arguments:
        step_size: `h`, with `0 < h` and `sqrt(2h) <= 0.25`.
        tour_length: mean number of local moves per tour `L`; `c = Z_hat / L`.
        rate: give `c` directly instead of `tour_length`.
        n_bootstrap: uniform draws in the bootstrap: `Z_hat` and the lanes' starts.
        finish_tours: (default) lanes start at uniform draws and, when the budget is
            spent, every open tour runs to its end; the image divides by the number of
            tours, so it has no bias from unfinished tours (as the paper's authors run it).
        start: only with `finish_tours=False`: `"stationary"` (default) starts the lanes
            in the jump chain's stationary law `lum + c`, resampled from the bootstrap;
            `"uniform"` at tour starts (darker in short runs: tours in bright regions are
            still open at the end).
        learned: regenerate from a density learned from the bootstrap paths
            (`LearnedRegeneration`) instead of uniformly (`docs/rendering.md` measures both).
    """

    def __init__(
        self,
        step_size: float = 1e-4,
        *,
        tour_length: float = 1.0,
        rate: float | None = None,
        n_bootstrap: int = 65536,
        start: str | None = None,
        finish_tours: bool = True,
        learned: LearnedRegeneration | None = None,
    ):
        self._setup(TorusMALA(step_size), tour_length, rate, n_bootstrap, start, finish_tours, learned)
