"""Metropolis Restore: jump Restore with Kelemen's small step as local dynamics."""

from __future__ import annotations

from typing import cast

from ..local import AbstractTorusMutation, TorusMetropolis
from ._learned_regeneration import LearnedRegeneration
from ._pss import small_step
from ._restore_renderer import AbstractPSSRestore


class MetropolisRestore(AbstractPSSRestore):
    """Metropolis Restore (the Restore variant of PSSMLT's small step).

    Local dynamics: Metropolis on luminance with a symmetric small step on the torus
    (`min(1, lum' / lum)`) that keeps the target's `frozen_coordinates` (on
    `MultiplexedBDPT` the depth and strategy, as MMLT's small step), embedded in continuous
    time at rate 1; regeneration: uniform on the whole torus (PSSMLT's large step); kill rate `gamma = c / lum`. Each step evaluates the target
    once per lane. The image is `W H c S_j / N` with `S_j` the film of
    `rgb / lum / (1 + gamma)` and `N` the number of tours, all run to completion (see
    `restore.render._restore_renderer` for the derivation). The sampler is the core's
    `restore.JumpRestore` with `restore.local.TorusMetropolis` and a uniform regeneration.

    The default `tour_length = 1` (a tour makes one local move on average; `c` is the
    bootstrap mean luminance) follows the paper's authors: tours are short where the
    image is average and last about `lum / c` steps where it is bright, so local
    exploration goes where it pays; `docs/rendering.md` has the sweep over `L` behind it.
    The statistics report `tours_per_lane` and `completed_tour_cv`, and `render` the
    `finishing_steps` spent completing the open tours after the budget.

    Arguments:
        mutation: the small step (default `KelemenMutation()`, `s1 = 1/1024`, `s2 = 1/64`).
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
        mutation: AbstractTorusMutation | None = None,
        *,
        tour_length: float = 1.0,
        rate: float | None = None,
        n_bootstrap: int = 65536,
        start: str | None = None,
        finish_tours: bool = True,
        learned: LearnedRegeneration | None = None,
    ):
        self._setup(TorusMetropolis(mutation), tour_length, rate, n_bootstrap, start, finish_tours, learned)

    def local_kernel(self, target) -> TorusMetropolis:
        """The small step, keeping the target's `frozen_coordinates` (on `MultiplexedBDPT`:
        the depth and strategy, as in MMLT)."""
        return small_step(cast(TorusMetropolis, self.kernel).mutation, target)  # `__init__` sets a TorusMetropolis
