"""Metropolis Restore: jump Restore with Kelemen's small step as local dynamics."""

from __future__ import annotations

from ..local import AbstractTorusMutation, TorusMetropolis
from ._restore_renderer import AbstractPSSRestore


class MetropolisRestore(AbstractPSSRestore):
    """Metropolis Restore (the Restore variant of PSSMLT's small step).

    Local dynamics: Metropolis on luminance with a symmetric small step on the torus
    (`min(1, lum' / lum)`), embedded in continuous time at rate 1; regeneration: uniform
    (PSSMLT's large step); kill rate `gamma = c / lum`. Each step evaluates the target
    once per lane. The image is `W H c S_j / K` with `S_j` the film of
    `rgb / lum / (1 + gamma)` and `K` the Rao-Blackwellised number of finished tours (see
    `restore.render._restore_renderer` for the derivation). The sampler is the core's
    `restore.JumpRestore` with `restore.local.TorusMetropolis` and a uniform regeneration.

    The default `tour_length = 32` local moves per tour: a tour's one uniform start is
    then amortised over about 32 local moves (about 3% of the evaluations are fresh draws,
    the same as PSSMLT with `p_large = 1 / 33`), while a budget of a few thousand steps per
    lane still holds about a hundred tours per lane, so that no single long tour (one that
    found a bright region) carries much of a lane's estimate. Longer tours explore more
    locally per fresh draw but make the tour-length tail heavier; the statistics report
    `tours_per_lane` and `completed_tour_cv`.

    Arguments:
        mutation: the small step (default `KelemenMutation()`, `s1 = 1/1024`, `s2 = 1/64`).
        tour_length: mean number of local moves per tour `L`; `c = Z_hat / L`.
        rate: give `c` directly instead of `tour_length`.
        n_bootstrap: uniform draws in the bootstrap: `Z_hat` and the lanes' starts.
        start: `"stationary"` (default): lanes start in the stationary law of the jump
            chain, `lum + c`, resampled from the bootstrap, which removes the bias of
            unfinished tours in finite runs; `"uniform"`: at tour starts, as in the paper.
    """

    def __init__(
        self,
        mutation: AbstractTorusMutation | None = None,
        *,
        tour_length: float = 32.0,
        rate: float | None = None,
        n_bootstrap: int = 65536,
        start: str = "stationary",
    ):
        self._setup(TorusMetropolis(mutation), tour_length, rate, n_bootstrap, start)
