"""The Pareto tail diagnostic: the fit against ArviZ, and the exact top sets of a run's tours."""

import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import restore
import restore._tails
from restore._pareto import k_hat_limit, pareto_k, pareto_k_log, tail_length
from restore._tails import Pending, add_records, duration_k, importance_k, init_tails, residual_k, settle
from restore._tour_records import TourRecords
from restore.regeneration import Gaussian


def _psis_k(values):
    """ArviZ's PSIS shape for the same values (as importance weights), with ArviZ 0.x or 1.x."""
    az = pytest.importorskip("arviz")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if int(az.__version__.split(".")[0]) >= 1:  # arviz-stats takes log likelihoods: weights are their negatives
            from arviz_stats.base import array_stats

            _, k = array_stats.psislw(-np.log(values))
        else:
            _, k = az.psislw(np.log(values)[None, :], normalize=False)
    return float(np.asarray(k).reshape(-1)[0])


# ArviZ 0.x fits ceil(3 sqrt(n)) tail values and 1.x floor(3 sqrt(n)): sizes with an integer
# 3 sqrt(n) (or n / 5 < 3 sqrt(n)) make both the same, so the fit is compared with both.
@pytest.mark.parametrize("n", [50, 400, 4900])
@pytest.mark.parametrize("tail", ["exponential", "pareto", "half-cauchy"])
def test_pareto_k_equals_arviz(n, tail):
    rng = np.random.default_rng(n)
    values = {
        "exponential": lambda: rng.exponential(size=n),
        "pareto": lambda: rng.pareto(1 / 0.7, size=n) + 1.0,
        "half-cauchy": lambda: np.abs(rng.standard_cauchy(n)),
    }[tail]()
    assert pareto_k(values, n) == pytest.approx(_psis_k(values), abs=1e-10)
    assert pareto_k_log(np.log(values), n) == pytest.approx(_psis_k(values), abs=1e-10)
    # only the tail is needed
    top = np.sort(values)[-(tail_length(n) + 1) :]
    assert pareto_k(top, n) == pytest.approx(_psis_k(values), abs=1e-10)


def test_pareto_k_separates_light_from_infinite_variance_tails():
    rng = np.random.default_rng(0)
    n = 20_000
    assert pareto_k(rng.exponential(size=n), n) < 0.1
    assert 0.6 < pareto_k(rng.pareto(1 / 0.8, size=n), n) < 1.0  # shape 0.8: infinite variance
    assert math.isnan(pareto_k(rng.exponential(size=10), 10))  # too few to fit


def test_k_hat_limit():
    assert k_hat_limit(10**6) == restore.K_HAT_LIMIT == 0.5
    assert k_hat_limit(100) == pytest.approx(0.5)
    assert k_hat_limit(30) < 0.35
    assert k_hat_limit(5) == -math.inf


def _run(regeneration, lanes=64, steps=400, key=1, **kwargs):
    kwargs.setdefault("max_draws", 0)  # no draws: runs of any length share one compiled program
    logdensity = lambda x: -0.5 * jnp.sum(x**2)  # noqa: E731
    sampler = restore.JumpRestore(logdensity, restore.local.RandomWalk(0.8), regeneration, tour_length=4.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return restore.sample(sampler, jax.random.key(key), num_lanes=lanes, num_steps=steps, progress=False, **kwargs)


@pytest.fixture(scope="module")
def good():
    return _run(Gaussian(jnp.zeros(2), 1.2))


@pytest.mark.slow
def test_top_sets_hold_the_largest_tours_exactly(good):
    """Each lane keeps its largest tours; with a single chunk's worth of tours the sets equal a brute-force record."""
    tails, sums = good.tails, good.sums
    depth = tails.duration.shape[1]
    counts = np.asarray(sums.num_tours)
    for lane in range(4):
        kept = np.sort(tails.duration[lane][np.isfinite(tails.duration[lane])])
        assert len(kept) == min(depth, counts[lane])
        assert kept.max() <= float(sums.max_tour[lane]) + 1e-12 and kept.max() == pytest.approx(float(sums.max_tour[lane]))
        # the sum of all durations bounds the kept ones, and their squares add up within the lane's sum of squares
        assert np.sum(kept**2) <= float(sums.sum_t2[lane]) * (1 + 1e-12)


def test_light_tails_are_reliable(good):
    log_z = good.normalising_constant()
    assert log_z.reliable and log_z.k_hat < 0.3
    est = good.estimate("x")
    assert np.all(est.reliable) and np.all(est.k_hat < 0.3)
    assert "UNRELIABLE" not in repr(est)
    assert good.tour_statistics().k_hat == pytest.approx(float(log_z.k_hat))


def test_a_too_narrow_regeneration_only_harms_importance_sampling():
    """u = N(0, 0.3^2) for a standard normal target: p/u is unbounded, so the importance weights have an
    infinite-variance tail and are flagged; the local moves bring wandering tours back to where they are
    killed, so the tours stay light-tailed and their log Z is right and trusted."""
    narrow = _run(Gaussian(jnp.zeros(2), 0.09))
    with pytest.warns(restore.UnreliableEstimateWarning, match="cannot be trusted"):
        importance = narrow.normalising_constant("importance")
    assert not importance.reliable and importance.k_hat > 0.7
    assert "UNRELIABLE" in repr(importance)
    tours = narrow.normalising_constant()
    assert tours.reliable and abs(float(tours.z_score(math.log(2 * math.pi)))) < 3


def _two_modes(x):
    return jnp.logaddexp(-0.5 * jnp.sum((x - 3) ** 2), -0.5 * jnp.sum((x + 3) ** 2)) - math.log(4 * math.pi)


@pytest.mark.slow
def test_a_missed_mode_is_flagged():
    """u covers only the left of two modes: log Z comes out near log(1/2) with a tiny standard error, but the
    rare tours that cross into the uncovered mode are never killed there, outlast the run, and say so."""
    sampler = restore.JumpRestore(_two_modes, restore.local.RandomWalk(1.0), Gaussian(-3 * jnp.ones(2), 1.0), tour_length=4.0)
    with pytest.warns(RuntimeWarning, match="still had an open tour"):
        result = restore.sample(sampler, jax.random.key(1), num_lanes=64, num_steps=400, progress=False)
    assert result.unfinished_tours > 0
    with pytest.warns(restore.UnreliableEstimateWarning, match="outlast the run"):
        log_z = result.normalising_constant()
    assert abs(float(log_z.z_score(0.0))) > 10  # the confident wrong answer...
    assert not log_z.reliable  # ...is marked
    with pytest.warns(restore.UnreliableEstimateWarning):
        assert not np.any(result.estimate("x").reliable)
    assert result.tour_statistics().heavy_tailed


def test_residual_tail_matches_brute_force_when_every_tour_is_kept():
    """With fewer tours per lane than the set size, the sets hold every tour: the residual fit is exact."""
    res = _run(Gaussian(jnp.zeros(2), 1.2), lanes=32, steps=60)
    tails = res.tails
    est = res.estimate("x")
    n = int(np.sum(res.sums.num_tours))
    assert np.all(np.asarray(res.sums.num_tours) < tails.duration.shape[1])
    finite = np.isfinite(tails.duration)
    t, f = tails.duration[finite], tails.duration_integral[finite][:, 0]
    assert len(t) == n
    assert residual_k(tails, 0, float(est.value[0]), n) == pytest.approx(pareto_k(np.abs(f - est.value[0] * t), n))
    assert duration_k(tails, n) == pytest.approx(pareto_k(t, n))
    assert importance_k(tails, int(np.sum(res.sums.num_iw))) == pytest.approx(float(res.normalising_constant("importance").k_hat))


@pytest.mark.slow
def test_lanes_subsets_and_merges_keep_their_diagnostics(good):
    part = good.estimate("x", lanes=slice(0, 32))
    assert part.k_hat.shape == (2,) and np.all(np.isfinite(part.k_hat))
    a = _run(Gaussian(jnp.zeros(2), 1.2), lanes=32, first_lane=0)
    b = _run(Gaussian(jnp.zeros(2), 1.2), lanes=32, first_lane=32)
    merged = restore.merge_results([a, b])
    np.testing.assert_array_equal(merged.tails.duration, good.tails.duration)
    assert float(merged.normalising_constant().k_hat) == float(good.normalising_constant().k_hat)


@pytest.mark.parametrize("lanes_per_block", [None, 1, 4])
def test_records_merged_in_batches_give_the_exact_top_sets(lanes_per_block, monkeypatch):
    """Chunks of records wait on the host and join the sets in batches: every set equals the
    brute-force top set of all the lane's tours, and a merge per chunk gives the same sets.
    A chunk whose result is dropped (interrupted) writes into the buffers but leaves no trace.
    Merged a few lanes at a time (`lanes_per_block`), the sets are bit for bit those of one merge."""
    lanes, size, depth, slots = 6, 2, 8, 5
    rng = np.random.default_rng(3)
    tails, pending, each = init_tails(lanes, size, depth), Pending(), init_tails(lanes, size, depth)
    tours, weights = [[] for _ in range(lanes)], [[] for _ in range(lanes)]
    merges = 0
    for chunk in range(60):
        count, starts = rng.integers(0, slots + 1, lanes), rng.integers(0, slots + 1, lanes)
        duration, weight = rng.exponential(size=(lanes, slots)), rng.normal(size=(lanes, slots))
        integral = rng.normal(size=(lanes, slots, size)) * duration[..., None]
        weight[0, 0] = np.nan  # a NaN weight never enters
        records = TourRecords(duration, integral, count, weight, starts)
        if chunk % 7 == 3:  # an interrupted chunk: its records are written past the counts, then dropped
            add_records(tails, pending, records._replace(duration=records.duration + 100.0, integral=integral * 1e3))
        before = 0 if pending.tours is None else int(pending.tours.sum())
        tails, pending = add_records(tails, pending, records)
        merges += int(pending.tours.sum()) < before + int(count.sum())
        each = settle(*add_records(each, Pending(), records))  # a merge per chunk
        for lane in range(lanes):
            tours[lane] += [(duration[lane, r], *integral[lane, r]) for r in range(count[lane])]
            weights[lane] += [w for w in weight[lane, : starts[lane]] if not np.isnan(w)]
    assert merges >= 2 and pending.tours.sum() > 0  # merged in batches, and some records still wait
    whole = settle(tails, pending)
    if lanes_per_block is not None:  # SETTLE_BLOCK counts lanes x components x candidates
        width = int(max(pending.tours.max(), pending.starts.max()))
        monkeypatch.setattr(restore._tails, "SETTLE_BLOCK", lanes_per_block * size * (depth + width))
    final = settle(tails, pending)
    for blocked, one in zip(final, whole, strict=True):
        np.testing.assert_array_equal(blocked, one)
    for lane in range(lanes):
        rows = np.asarray(tours[lane])
        longest = rows[np.argsort(rows[:, 0])[::-1][:depth]]
        kept = np.isfinite(final.duration[lane])
        np.testing.assert_array_equal(np.sort(final.duration[lane][kept]), np.sort(longest[:, 0]))
        by_duration = dict(zip(final.duration[lane][kept], final.duration_integral[lane][kept]))
        for row in longest:
            np.testing.assert_array_equal(by_duration[row[0]], row[1:])
        for j in range(size):
            biggest = rows[np.argsort(np.abs(rows[:, 1 + j]))[::-1][:depth]]
            used = np.isfinite(final.integral_duration[lane, j])
            np.testing.assert_array_equal(np.sort(final.integral[lane, j][used]), np.sort(biggest[:, 1 + j]))
            np.testing.assert_array_equal(np.sort(final.integral_duration[lane, j][used]), np.sort(biggest[:, 0]))
        top_weights = np.sort(weights[lane])[::-1][:depth]
        kept_weights = final.log_importance_weight[lane]
        np.testing.assert_array_equal(np.sort(kept_weights[np.isfinite(kept_weights)]), np.sort(top_weights))
    for a, b in zip(final, each):
        np.testing.assert_array_equal(np.sort(a, axis=-1), np.sort(b, axis=-1))
