"""Modes found from where the seeding chains went, as Laplace candidates for every stage's choice.

Seeding chains of a few hundred steps do not equilibrate in a correlated, ill-conditioned
target, so a regeneration fitted to their states is too narrow along its long directions.
Optimisation does not need to equilibrate: from the chains' last states, quasi-Newton
searches (`find_modes`, optimistix) reach the modes, and their Hessians give the shape
of the target there. The Laplace mixture of those modes (`laplace_fit`) is offered to
`choose_regeneration` beside the fitted families, which keeps it only where held-out
draws say it is closer to the target.
"""

from __future__ import annotations

import numpy as np

from ._seeding import Seeds
from .regeneration._choose import default_max_cost
from .regeneration._fit import Fit
from .regeneration._laplace import find_modes
from .regeneration._laplace_fit import LAPLACE_DF, laplace_fit

#: Most searches started (from the last states of this many chains, spread over all of them).
MODE_STARTS = 256
#: Most quasi-Newton steps per search.
MODE_STEPS = 256
#: Most Laplace components offered.
MODE_COMPONENTS = 64


def laplace_candidates(logdensity, seeds: Seeds, d: int) -> tuple[tuple[Fit, ...], int]:
    """The Laplace candidates (Gaussian and Student-t components) of the modes found from the
    seeding chains' last states (none when the log density has no gradient or no search
    reaches a mode), and the evaluations spent: `MODE_STEPS` per search (an upper bound) and
    `d` per Hessian."""
    if not seeds.uses_gradient:
        return (), 0
    last = np.flatnonzero(np.r_[seeds.chains[1:] != seeds.chains[:-1], True])  # each chain's last state
    starts = seeds.positions[last[np.unique(np.linspace(0, last.size - 1, min(MODE_STARTS, last.size)).astype(int))]]
    evaluations = int(starts.shape[0] * (MODE_STEPS + 2 * d))
    try:
        modes = find_modes(logdensity, starts, max_steps=MODE_STEPS)
    except (ValueError, np.linalg.LinAlgError):
        return (), evaluations
    most = min(MODE_COMPONENTS, max(1, default_max_cost(d) // (d * d)))
    return tuple(laplace_fit(modes, df=df, max_components=most) for df in (None, LAPLACE_DF)), evaluations
