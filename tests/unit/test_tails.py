"""The Pareto tail diagnostic: the fit against ArviZ, and the run's largest tours kept exactly."""

import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import restore
import restore._tails
from restore._pareto import k_hat_limit, pareto_k, pareto_k_log, tail_length, tail_square_excess
from restore._tails import duration_k, importance_k, residual_k, select_lanes, signed_square_excess
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


def _pareto_sample(rng, k: float, n: int) -> np.ndarray:
    """`n` draws of a generalised Pareto distribution of shape `k` and unit scale (`k = 0`: exponential)."""
    u = rng.random(n)
    return -np.log(u) if k == 0 else (u**-k - 1) / k


def test_tail_square_excess_makes_up_the_squares_a_heavy_tail_usually_hides():
    """Over repeated samples of n terms, the squares of the largest sum short of their expectation
    more often and by more as the tail gets heavier; adding the excess brings the median of
    (sum of all squares) / (its expectation) close to 1. A light tail gets almost nothing, and no
    excess is given where the variance is infinite, nor without enough terms to fit."""
    rng, n = np.random.default_rng(3), 4000
    ratios = {}
    for k in (0.0, 0.25, 0.4):
        expected = n * 2 / ((1 - k) * (1 - 2 * k))  # E[Y^2] of a unit-scale GPD, n times
        plain, smoothed = [], []
        for _ in range(200):
            x = _pareto_sample(rng, k, n)
            excess = tail_square_excess(np.sort(x)[-200:], n)
            assert excess >= 0
            plain.append(np.sum(x**2) / expected)
            smoothed.append((np.sum(x**2) + excess) / expected)
        ratios[k] = (np.median(plain), np.median(smoothed))
    assert ratios[0.0][1] - ratios[0.0][0] < 0.02  # a light tail: nearly nothing added
    assert ratios[0.4][0] < 0.85 and abs(ratios[0.4][1] - 1) < 0.15, ratios  # the plain sum falls short; smoothed is near 1
    assert ratios[0.25][0] < ratios[0.25][1] <= 1.1, ratios
    assert tail_square_excess(_pareto_sample(rng, 0.8, n), n) == 0.0  # infinite variance: k_hat says so
    assert tail_square_excess(np.arange(5.0), n) == 0.0 and tail_square_excess(np.arange(50.0), 20) == 0.0


def test_the_excess_counts_in_proportion_to_how_one_sided_the_tail_is():
    """A one-sided heavy tail gets the whole excess; the same terms with random signs (a
    symmetric tail, whose misses cancel) nearly none."""
    rng, n = np.random.default_rng(4), 4000
    x = _pareto_sample(rng, 0.4, n)
    whole = tail_square_excess(x, n)
    assert whole > 0 and signed_square_excess(x, n) == pytest.approx(whole)
    symmetric = signed_square_excess(x * rng.choice([-1.0, 1.0], n), n)
    assert symmetric < 0.3 * whole


def test_values_on_a_lattice_keep_their_light_tail():
    """Tour durations and integrals are sums of equal holding times, so the largest values tie. Ties with
    the threshold are not exceedances: counted as zeros (the planted defect), they read as k_hat near 1."""
    rng = np.random.default_rng(1)
    n = 4000
    lattice = 0.75 * rng.geometric(0.5, size=n)  # light (geometric) tail on steps of 0.75, many tied at the threshold
    assert pareto_k(lattice, n) < 0.2
    assert 0.6 < pareto_k(np.ceil(rng.pareto(1 / 0.8, size=n)), n) < 1.0  # a heavy tail on a lattice stays heavy


def test_k_hat_limit():
    assert k_hat_limit(10**6) == restore.K_HAT_LIMIT == 0.5
    assert k_hat_limit(100) == pytest.approx(0.5)
    assert k_hat_limit(30) < 0.35
    assert k_hat_limit(5) == -math.inf


def _run(regeneration, lanes=64, steps=400, key=1, **kwargs):
    kwargs.setdefault("save", restore.SaveDraws(0))  # no draws: runs of any length share one compiled program
    logdensity = lambda x: -0.5 * jnp.sum(x**2)  # noqa: E731
    sampler = restore.JumpRestore(logdensity, restore.local.RandomWalk(0.8), regeneration, tour_length=4.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return restore.sample(sampler, jax.random.key(key), num_lanes=lanes, num_steps=steps, progress=False, **kwargs)


@pytest.fixture(scope="module")
def good():
    return _run(Gaussian(jnp.zeros(2), 1.2))


@pytest.mark.slow
def test_k_hat_from_a_compacted_buffer_equals_the_fit_to_every_tour(monkeypatch):
    """The same run with a buffer large enough for every tour and with one a fraction of
    that size (compacted many times): the tail fits agree, and agree with ArviZ's PSIS fit to
    all the tour durations."""
    regeneration = Gaussian(jnp.zeros(2), 0.6)  # narrower than the target: a real tail
    whole = _run(regeneration, lanes=128, steps=800)
    assert whole.tails.threshold[0] == -np.inf  # the buffer never filled: every tour is in it
    durations = whole.tails.column(0, 1)
    n = int(np.sum(whole.sums.num_tours))
    assert durations.size == n > 10_000
    monkeypatch.setattr(restore._tails, "MIN_ROWS", 2**13)  # 6 columns of at least 683 largest (tail fits use 437)
    monkeypatch.setattr(restore._tails, "ROWS_PER_LANE", 2)
    small = _run(regeneration, lanes=128, steps=800, key=1)
    assert small.tails.threshold[0] > 0 and small.tails.rows.shape[0] < 2**13  # compacted
    np.testing.assert_array_equal(small.sums.sum_t, whole.sums.sum_t)  # the same run
    assert duration_k(small.tails, n) == duration_k(whole.tails, n) == pytest.approx(_psis_k(durations), abs=0.05)
    for j in range(2):
        value = float(whole.estimate("x").value[j])
        assert residual_k(small.tails, j, value, n) == residual_k(whole.tails, j, value, n)
    starts = int(np.sum(whole.sums.num_iw))
    assert importance_k(small.tails, starts) == importance_k(whole.tails, starts)


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
    """While the buffer has never filled it holds every tour: the residual fit is the fit to all residuals."""
    res = _run(Gaussian(jnp.zeros(2), 1.2), lanes=32, steps=60)
    tails = res.tails
    est = res.estimate("x")
    n = int(np.sum(res.sums.num_tours))
    assert np.all(tails.threshold == -np.inf)
    tour = tails.rows[:, 0] > 0
    t, f = tails.rows[tour, 0], tails.rows[tour, 1]
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
    order = lambda t: np.lexsort((t.rows[:, 0], t.lane))  # noqa: E731
    np.testing.assert_array_equal(merged.tails.rows[order(merged.tails)], good.tails.rows[order(good.tails)])
    assert float(merged.normalising_constant().k_hat) == float(good.normalising_constant().k_hat)
    own = restore.merge_results([a]).tails
    np.testing.assert_array_equal(select_lanes(good.tails, slice(0, 32), 64).rows[order(own)], own.rows[order(own)])
