"""H2MC Restore: jump Restore with H2MC's anisotropic Gaussian moves on the torus."""

from __future__ import annotations

import math

from ..local import TorusH2MC
from ._learned_regeneration import LearnedRegeneration
from ._restore_renderer import AbstractPSSRestore


class H2MCRestore(AbstractPSSRestore):
    """H2MC Restore: Hessian-informed local dynamics, uniform regeneration, `gamma = c / lum`.

    Local moves draw from the Gaussian of Hessian-Hamiltonian dynamics at the current path
    (Li et al. 2015) and accept with the Hastings ratio of the forward and reverse
    Gaussians (see `restore.local.TorusH2MC`). Each evaluated path takes `dim` more
    gradients for its Hessian's differences and an eigendecomposition, and keeps its
    Gaussian for the moves from it, so a step costs more than `MALARestore`'s; an
    equal-time comparison charges it. Estimator and tour length as in `MetropolisRestore`.

    Arguments:
        sigma: the bound on each move, in `(0, 0.05]` (default 0.01, as H2MC's authors run it).
        angle: the dynamics' angle `T`, in `(0, pi)` (default `pi / 2`, as its authors run it).
        tour_length: mean number of local moves per tour `L`; `c = Z_hat / L`.
        rate: give `c` directly instead of `tour_length`.
        n_bootstrap: uniform draws in the bootstrap: `Z_hat` and the lanes' starts.
        finish_tours: (default) lanes start at uniform draws and, when the budget is
            spent, every open tour runs to its end (as in `MetropolisRestore`).
        start: only with `finish_tours=False`: `"stationary"` (default) or `"uniform"`
            (as in `MetropolisRestore`).
        learned: regenerate from a density learned from the bootstrap paths
            (`LearnedRegeneration`) instead of uniformly (`docs/rendering.md` measures both).
    """

    def __init__(
        self,
        sigma: float = 0.01,
        angle: float = math.pi / 2,
        *,
        tour_length: float = 1.0,
        rate: float | None = None,
        n_bootstrap: int = 65536,
        start: str | None = None,
        finish_tours: bool = True,
        learned: LearnedRegeneration | None = None,
    ):
        self._setup(TorusH2MC(sigma, angle), tour_length, rate, n_bootstrap, start, finish_tours, learned)
