"""`unseen_mass`: the target mass that a run's tours would not reach, from draws of another run."""

import numpy as np
import pytest
from scipy import stats

from restore._coverage import unseen_mass

rng = np.random.default_rng(0)
#: Draws of the target `0.95 N(0, 1) + 0.05 N(8, 1)` (normaliser `Z = e^2`: `p = Z pi`).
N = 200_000
DRAWS = np.where(rng.uniform(size=N) < 0.95, 0.0, 8.0) + rng.standard_normal(N)
LOG_Z = 2.0
LOG_P = LOG_Z + np.log(0.95 * stats.norm.pdf(DRAWS) + 0.05 * stats.norm.pdf(DRAWS, 8.0))


def log_u(share_far: float, defensive: float = 1e-3) -> np.ndarray:
    """A regeneration with `share_far` of its non-defensive mass on the far mode, plus a broad
    defensive Student-t (as thin on the far mode as a defensive component is in many dimensions)."""
    near = (1 - share_far) * stats.norm.pdf(DRAWS) + share_far * stats.norm.pdf(DRAWS, 8.0)
    return np.log((1 - defensive) * near + defensive * stats.t(3, scale=50.0).pdf(DRAWS))


def test_a_mode_left_to_the_defensive_component_is_unseen_mass():
    """With the far mode (5% of the mass) left to a thin defensive component, a run of 10^3 tours
    expects 0.02 starts there: the far mode's mass is unseen. A run of 10^6 tours expects about
    20, and sees all but the thinnest part of it."""
    missed = log_u(0.0)
    assert unseen_mass(LOG_P, missed, np.ones(N), LOG_Z, 1e3) == pytest.approx(0.05, abs=0.005)
    assert unseen_mass(LOG_P, missed, np.ones(N), LOG_Z, 1e6) < 0.01


def test_a_regeneration_that_covers_every_mode_leaves_nothing_unseen():
    """Where `u` is close to the target, the unseen mass is that of the `1 / tours` of it a run
    never gets to (whatever the regeneration), not more."""
    covered = log_u(0.05)
    assert unseen_mass(LOG_P, covered, np.ones(N), LOG_Z, 1e5) < 2e-5
    assert unseen_mass(LOG_P, covered, np.ones(N), LOG_Z, 1e3) < 2e-3


def test_weights_count_and_bad_draws_are_dropped():
    """Weights are masses: draws of the near mode only, weighted up, give what all draws do; draws
    with a zero weight or a non-finite density take no part."""
    missed = log_u(0.0)
    w = np.where(DRAWS > 4.0, 0.0, 1.0)
    assert unseen_mass(LOG_P, missed, w, LOG_Z, 1e3) < 2e-3  # the far mode's draws weigh nothing
    bad = LOG_P.copy()
    bad[:10] = np.nan
    assert unseen_mass(bad, missed, np.ones(N), LOG_Z, 1e3) == pytest.approx(0.05, abs=0.005)
    assert unseen_mass(LOG_P, missed, np.ones(N), LOG_Z, 0.0) == 0.0
