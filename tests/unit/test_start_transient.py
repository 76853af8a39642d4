"""Lane-based estimates say when the lanes have not forgotten their start.

The lanes of a non-regenerative sampler (the MH baseline `MixtureMH`) start at draws of the
regeneration with no burn-in, and their time averages lean towards the start until it is
forgotten; lanes as replicates do not see that lean in their standard error. The two halves
of each lane's run do: their means disagree by many standard errors while the start is
remembered (`restore._estimates.halves_z_from_sums` on the lanes' sums kept at the middle of
the budget; `halves_z` on the stored draws, for `estimate_draws`).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import restore
from restore._estimates import START_Z_LIMIT, halves_z
from restore.local import RandomWalk
from restore.regeneration import Gaussian


def std_normal(x):
    return -0.5 * jnp.sum(x**2)


def _mh(variance: float, save=restore.SaveDraws(thin=2), num_chunks: int = 50):
    sampler = restore.MixtureMH(std_normal, RandomWalk(0.75), Gaussian(jnp.zeros(2), variance * jnp.eye(2)), 0.1)
    return restore.sample(sampler, jax.random.key(3), num_lanes=1024, num_steps=200, progress=False, save=save, num_chunks=num_chunks)


def test_lanes_that_remember_a_wide_start_are_marked():
    """Lanes started at draws of N(0, 9 I) for a standard normal: 200 steps leave `E[x**2]` 14 and 15
    standard errors high, which lanes as replicates called reliable. The halves of the lanes' runs
    disagree by many standard errors, so the estimate, and the same one from the draws, are marked and say why."""
    result = _mh(9.0)
    with pytest.warns(restore.UnreliableEstimateWarning, match="have not forgotten their start"):
        second = result.estimate("x**2")
    assert np.all(second.z_score(1.0) > 8) and not np.any(second.reliable)
    assert "not forgotten their start" in second.caveat
    drawn = result.estimate_draws(lambda x: x**2)
    assert not np.any(drawn.reliable) and "not forgotten their start" in drawn.caveat


def test_lanes_started_from_the_target_are_not_marked():
    """The control: lanes started at the target's own draws have nothing to forget; the estimates are
    right and reliable, and the halves agree within their error."""
    result = _mh(1.0)
    second = result.estimate("x**2")
    assert np.all(second.reliable) and np.all(np.abs(second.z_score(1.0)) < 3)
    values = result.draws**2
    assert np.all(np.abs(halves_z(values, result.draw_weights)) < START_Z_LIMIT)


def test_halves_need_two_stored_rows_each():
    values, weights = np.zeros((3, 8, 2)), np.ones((3, 8))
    assert halves_z(values, weights) is None
    drift = np.linspace(1.0, 0.0, 8)[:, None, None] + np.random.default_rng(0).normal(0.0, 0.1, (8, 50, 1))
    assert float(halves_z(drift, np.ones((8, 50)))[0]) > START_Z_LIMIT


def test_a_run_that_stores_no_draws_is_checked_too():
    """With `SaveDraws(0)` and the whole budget in one chunk (the speed benchmarks' settings) the
    halves come from the lanes' sums kept at the middle of the budget: the wide start is marked,
    the target's start is not (control)."""
    wide, target = (_mh(v, restore.SaveDraws(0), num_chunks=1) for v in (9.0, 1.0))
    with pytest.warns(restore.UnreliableEstimateWarning, match="have not forgotten their start"):
        assert not np.any(wide.estimate("x**2").reliable)
    assert np.all(target.estimate("x**2").reliable)


def test_the_first_half_is_the_first_half_of_the_steps():
    """The sums kept as the first half are those of exactly the first `num_steps // 2` steps, whatever
    the chunks: every step's draw is stored (thin 1), and the first 100 rows' weights add up to them."""
    for chunks in (1, 3, 50):
        result = _mh(9.0, restore.SaveDraws(1024 * 200, thin=1), num_chunks=chunks)
        first = result.draw_weights[:100]
        np.testing.assert_allclose(result.sums.half_t, first.sum(axis=0), rtol=1e-12)
        np.testing.assert_allclose(result.sums.half_f[:, :2], np.einsum("rl,rld->ld", first, result.draws[:100]), rtol=1e-12, atol=1e-9)
