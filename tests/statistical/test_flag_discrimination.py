"""The reliability flag discriminates: over regenerations from the target itself to poor ones and tails
from normal to Student-t df 2 (`tests/_flag_table.py`, whose table the regeneration how-to shows),
reliable estimates keep honest error bars, near-target runs stay reliable, and flagged estimates are,
on the whole, farther off than a flag drawn at random would pick (not by coverage: the strict xfail)."""

import math

import numpy as np
import pytest

from tests._flag_table import ESTIMATES, MIN_SIDE, Row, error_ratio, table

pytestmark = pytest.mark.slow

#: The permutation test's level, and its number of random flags.
LEVEL, DRAWS = 0.01, 1000


@pytest.fixture(scope="module")
def rows() -> list[Row]:
    return table()


def test_reliable_estimates_cover_and_none_is_far_off(rows):
    """At least 93% coverage and no reliable estimate more than 5 SE off, in every setting. Fails
    for central-limit standard errors without the Pareto-smoothed tail (`tail_square_excess`):
    reliable estimates of Gaussian regenerations of Student-t targets covered at 0.87-0.92 then
    (df 2 narrow 0.870, df 2 poor 0.892, df 4 narrow 0.917), as replications that met no long tour
    look light to every `k_hat` and their squares sum short of the tail's."""
    for r in rows:
        if not math.isnan(r.reliable_coverage):
            assert r.reliable_coverage >= 0.93, r
            assert r.worst_reliable_z <= 5.0, r


def test_near_target_runs_are_reliable(rows):
    """Fails for a flag that is always on (planted: always False), and for a tail fit that counts
    ties at the threshold as exceedances (28% of the normal target's estimates were flagged)."""
    for r in rows:
        if r.setting.near_target:
            assert r.flagged <= 0.10, r


@pytest.mark.xfail(
    strict=True,
    reason="within one setting k_hat flags the replications that met the long tours, whose error bars include "
    "them: flagged estimates cover at 0.947-1.000, reliable ones at 0.936-0.973 (df 2-4)",
)
def test_flagged_estimates_cover_worse(rows):
    """Wherever both sides hold `MIN_SIDE` estimates, reliable ones cover better than flagged ones."""
    compared = 0
    for r in rows:
        if min(r.flagged, 1 - r.flagged) * r.estimates >= MIN_SIDE:
            compared += 1
            assert r.reliable_coverage > r.flagged_coverage, r
    assert compared >= 1


def _cells(rows: list[Row]) -> list[tuple[np.ndarray, np.ndarray]]:
    """`(errors, reliable)` of each estimate of each setting with `MIN_SIDE` estimates on both sides."""
    return [(r.errors[:, i], r.reliable[:, i]) for r in rows for i in range(len(ESTIMATES)) if not math.isnan(r.error_ratio[i])]


def _mean_ratio(cells: list[tuple[np.ndarray, np.ndarray]]) -> float:
    """Geometric mean over the cells of the flagged estimates' RMS error over the reliable ones'."""
    return float(np.exp(np.mean(np.log([error_ratio(errors, reliable) for errors, reliable in cells]))))


def _beats_random_flags(cells: list[tuple[np.ndarray, np.ndarray]], seed: int) -> bool:
    """Permutation test at level `LEVEL`: the flag's `_mean_ratio` above that of all but `LEVEL` of
    `DRAWS` flags drawn at random (the same share flagged in each cell)."""
    rng = np.random.default_rng(seed)
    null = [_mean_ratio([(e, rng.permutation(m)) for e, m in cells]) for _ in range(DRAWS)]
    return _mean_ratio(cells) > np.quantile(null, 1 - LEVEL)


def test_flagged_estimates_are_farther_off_than_a_random_flag_would_pick(rows):
    """On the whole, flagged estimates are the worse ones: their RMS error over the reliable ones',
    averaged over the cells with `MIN_SIDE` estimates on both sides, beats random flags (measured:
    1.18, above 99.7% of random flags). Not everywhere: flagged `log Z` estimates are 1.08-1.74
    times farther off, and at df 2 those of P(x > 1) 1.25-1.50 times, but at df 3 and 4 flagged
    P(x > 1) estimates are no worse (0.92-1.00)."""
    cells = _cells(rows)
    assert len(cells) >= 4, len(cells)
    assert _beats_random_flags(cells, seed=0), _mean_ratio(cells)


def test_a_flag_drawn_at_random_fails_the_permutation_test(rows):
    """Negative control: the test above with each cell's flags shuffled (20 shuffles) passes at most twice."""
    rng = np.random.default_rng(1)
    cells = _cells(rows)
    passed = sum(_beats_random_flags([(e, rng.permutation(m)) for e, m in cells], seed=2 + i) for i in range(20))
    assert passed <= 2, passed
