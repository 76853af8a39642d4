"""What a user is told: a wrong dimension, a wrong key or precision, warnings that point at the
user's line with words that match the numbers and advice that fits the call."""

import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import restore
from restore._diagnostics import TourStatistics, heavy_tail_reasons, tour_statistics
from restore.local import RandomWalk
from restore.regeneration import Gaussian, StudentT


def two_d(x):
    """A 2-d standard normal that reads its coordinates by index."""
    return -0.5 * (x[0] ** 2 + x[1] ** 2)


def std_normal(x):
    return -0.5 * jnp.sum(x**2)


def test_a_dimension_smaller_than_the_density_reads_is_refused():
    """JAX clamps `x[1]` of a 1-d point to `x[0]`: a proper density with a wrong Z, silently."""
    with pytest.raises(ValueError, match=r"reads past the 1 coordinates.*dim=1 is too small"):
        restore.autosample(two_d, jax.random.key(0), scale=3.0, dim=1, progress=False)


@pytest.mark.parametrize(
    ("knowledge", "what"),
    [
        ({"scale": np.ones(3)}, "scale"),
        ({"scale": 1.0, "loc": np.zeros(3)}, "loc"),
        ({"box": (-np.ones(3), np.ones(3))}, "box"),
        ({"prior": Gaussian(jnp.zeros(3), 1.0)}, "prior"),
    ],
)
def test_a_dimension_that_disagrees_with_what_the_user_knows_is_refused(knowledge, what):
    with pytest.raises(ValueError, match=f"dim=2 disagrees with {what}, which has 3 coordinates"):
        restore.autosample(std_normal, jax.random.key(0), dim=2, progress=False, **knowledge)


def test_scale_and_loc_of_different_lengths_are_refused():
    with pytest.raises(ValueError, match="scale has 3 coordinates and loc 2"):
        restore.autosample(std_normal, jax.random.key(0), scale=np.ones(3), loc=np.zeros(2), progress=False)


@pytest.mark.parametrize("key", [0, np.zeros(3, np.uint32)])
def test_a_seed_instead_of_a_key_is_named(key):
    sampler = restore.JumpRestore(std_normal, RandomWalk(1.0), Gaussian(jnp.zeros(2), 2.0), log_rate=0.0)
    with pytest.raises(TypeError, match=r"key must be a JAX random key such as jax.random.key\(0\)"):
        restore.sample(sampler, key, num_lanes=4, num_steps=10, progress=False)
    with pytest.raises(TypeError, match="key must be a JAX random key"):
        restore.autosample(std_normal, key, scale=1.0, dim=2, progress=False)


def test_a_density_flat_in_a_coordinate_is_named_and_the_advice_fits_autosample():
    """`dim=3` for a 2-d density: infinite mass along the third coordinate. The user hears that
    (not only "a missed mode"), at their own line, with advice for `autosample`, not advice to
    use it."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = restore.autosample(
            two_d, jax.random.key(0), scale=3.0, dim=3, num_lanes=64, num_steps=200, stage_steps=100, max_stages=1,
            progress=False,
        )  # fmt: skip
        result.normalising_constant()
    messages = [str(w.message) for w in caught]
    assert any("did not change when coordinate 2 moved" in m and "reads (2)" in m for m in messages), messages
    assert {w.filename for w in caught} == {__file__}, [(w.filename, w.lineno) for w in caught]
    unreliable = [m for w, m in zip(caught, messages, strict=True) if issubclass(w.category, restore.UnreliableEstimateWarning)]
    assert unreliable and all("max_stages" in m and "builds one in stages" not in m for m in unreliable), unreliable
    assert any("infinite mass" in m for m in messages)


def test_a_run_the_user_built_is_advised_to_use_autosample_at_the_users_line():
    sampler = restore.JumpRestore(std_normal, RandomWalk(0.5), Gaussian(jnp.zeros(2), 400.0), tour_length=1.0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = restore.sample(sampler, jax.random.key(1), num_lanes=64, num_steps=500, progress=False)
        result.estimate("x")
    unreliable = [w for w in caught if issubclass(w.category, restore.UnreliableEstimateWarning)]
    assert unreliable and all("restore.autosample builds one in stages" in str(w.message) for w in unreliable)
    assert {w.filename for w in caught} == {__file__}


def _stats(**changes) -> TourStatistics:
    """Healthy tour statistics (exponential-like), with `changes`."""
    healthy = dict(
        num_tours=1000, mean_duration=1.0, mean_duration_se=0.03, expected_duration=1.0, effective_num_tours=500.0,
        longest_share=0.05, max_duration=7.0, incomplete_fraction=0.0, heavy_tailed=False, k_hat=0.14, k_limit=0.5,
        unfinished_tours=0,
    )  # fmt: skip
    return TourStatistics(**{**healthy, **changes})


def test_the_heavy_tail_words_quote_only_the_checks_that_failed():
    """One tour outlasted the run, and the longest 1% hold 5%: the words say that, and do not call
    a k_hat of 0.14 heavy-tailed or the tours "dominated by a few"."""
    words = heavy_tail_reasons(_stats(unfinished_tours=1))
    assert words == "1 tour still open at the end of the run was left out"
    assert heavy_tail_reasons(_stats()) == ""
    words = heavy_tail_reasons(_stats(longest_share=0.4, k_hat=0.9))
    assert "hold 40% of the time" in words and "k_hat = 0.90" in words and "worth" not in words
    assert "worth 20.0 equally long ones" in heavy_tail_reasons(_stats(effective_num_tours=20.0))
    assert heavy_tail_reasons(_stats(num_tours=10, longest_share=0.9, k_hat=math.nan)) == ""  # too few tours to judge


def test_the_flag_and_its_words_agree():
    """`tour_statistics` sets `heavy_tailed` exactly when there are words for it."""
    counts, times = np.zeros(8), np.zeros(8)
    counts[2], times[2] = 1000, 1000.0
    for unfinished, k in ((0, 0.1), (1, 0.1), (0, 0.9)):
        stats = tour_statistics(
            np.array([1000.0]), np.array([2000.0]), np.array([1000]), np.array([6.0]), np.array([1000.0]),
            (counts, times), 1.0, k_hat=k, unfinished_tours=unfinished,
        )  # fmt: skip
        assert stats.heavy_tailed == bool(heavy_tail_reasons(stats)) == (unfinished > 0 or k > 0.5)


def test_a_target_or_prior_used_in_another_precision_names_the_cause():
    """Switching `jax_enable_x64` after building a NumPyro target failed deep inside JAX
    ("lax.add requires arguments to have the same dtypes")."""
    from targets.numpyro import EIGHT_SCHOOLS, NumPyroTarget, eight_schools

    target = NumPyroTarget(eight_schools, **EIGHT_SCHOOLS)
    prior = StudentT(jnp.zeros(2, jnp.float32), jnp.ones(2, jnp.float32), 3.0)  # as target.prior() builds it
    before = bool(jax.config.read("jax_enable_x64"))
    then, now = ("float64", "float32") if before else ("float32", "float64")
    jax.config.update("jax_enable_x64", not before)
    try:
        for call in (lambda: target.logdensity(jnp.zeros(target.dim)), target.prior):
            with pytest.raises(RuntimeError, match=f"built in {then} and JAX now computes in {now}"):
                call()
    finally:
        jax.config.update("jax_enable_x64", before)
    if before:  # a float32 prior in a float64 session
        with pytest.raises(ValueError, match="the prior draws float32 numbers and JAX computes in float64"):
            restore.autosample(std_normal, jax.random.key(0), prior=prior, progress=False)


def test_thinned_draws_are_noted_once_at_the_users_line_when_used():
    """Not at every run (the demo said it twice), only when the thinned draws are used."""
    sampler = restore.JumpRestore(std_normal, RandomWalk(1.0), Gaussian(jnp.zeros(2), 2.0), log_rate=0.0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = restore.sample(sampler, jax.random.key(0), num_lanes=8, num_steps=400, save=restore.SaveDraws(800), progress=False)
        assert not caught and result.thin == 4
        result.estimate_draws(lambda x: x[..., 0])
        result.to_arviz()
    assert [w.category for w in caught] == [restore.ThinnedDrawsWarning]
    assert caught[0].filename == __file__ and "one state in every 4 steps" in str(caught[0].message)


def test_tour_statistics_survive_an_expected_duration_beyond_float64():
    """`exp(log Z - log c)` overflowed (an `OverflowError` ended a 50-d autosample run)."""
    import dataclasses

    sampler = restore.JumpRestore(std_normal, RandomWalk(1.0), Gaussian(jnp.zeros(2), 2.0), log_rate=0.0)
    result = restore.sample(sampler, jax.random.key(0), num_lanes=8, num_steps=100, progress=False)
    stats = dataclasses.replace(result, log_rate=-800.0, expected_tour_times=None).tour_statistics()
    assert stats.expected_duration == math.inf and stats.num_tours > 0


def test_the_advice_is_left_out_only_where_the_reason_gives_its_own():
    """Too few terms: the reason says "run longer"; any other reason (an open-tour caveat with few
    tours among them) gets the advice of the call."""
    from restore._estimates import Estimate
    from restore._result import _warn_unreliable

    few = Estimate(np.array(0.0), np.array(0.1), np.array(0.6), 0.4)
    caveat = Estimate(np.array(0.0), np.array(0.1), np.array(0.1), 0.4, "3 tours were still running")
    for estimate, advised in ((few, False), (caveat, True)):
        with pytest.warns(restore.UnreliableEstimateWarning) as caught:
            _warn_unreliable("the estimate", estimate, "ADVICE")
        assert ("ADVICE" in str(caught[0].message)) == advised, str(caught[0].message)
