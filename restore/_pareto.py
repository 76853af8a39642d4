"""The Pareto shape `k_hat` of a tail: is the variance of a sum of such values finite?

A sum of i.i.d. terms has a normal limit with the usual standard error only when the
terms have finite variance. Fitting a generalised Pareto distribution (GPD) to the
largest terms estimates the tail shape `k`: the `m`-th moment exists for `k < 1/m`, so
the variance is finite for `k < 1/2` and the mean itself for `k < 1`. This is the
diagnostic of Pareto-smoothed importance sampling (Vehtari, Simpson, Gelman, Yao and
Gabry, JMLR 2024), applied here to tour durations, per-tour residuals of observables and
importance weights. The fit is the empirical-Bayes estimate of Zhang and Stephens (2009)
with PSIS's weakly informative prior on `k`, the same as ArviZ's `psislw`.
"""

from __future__ import annotations

import math

import numpy as np

#: Above this `k_hat` an error bar is not trusted, whatever the sample size: the variance of
#: the terms is infinite (`k >= 1/2`), so the central-limit standard error is meaningless.
K_HAT_LIMIT = 0.5
#: Fewer terms than this and no tail can be fitted (PSIS needs at least five tail values).
MIN_TERMS = 25


def tail_length(n: int) -> int:
    """How many of the largest of `n` terms PSIS fits: `ceil(min(n / 5, 3 sqrt(n)))`."""
    return math.ceil(min(n / 5.0, 3.0 * math.sqrt(n)))


def k_hat_limit(n: float) -> float:
    """The largest `k_hat` at which an estimate from `n` terms is trusted.

    `min(K_HAT_LIMIT, 1 - 1 / log10(n))`: the second term is PSIS's sample-size bound
    (with few terms even a light tail is estimated too poorly), the first the
    finite-variance bound of a plain (unsmoothed) sum.
    """
    if not n > 10:
        return -math.inf
    return min(K_HAT_LIMIT, 1.0 - 1.0 / math.log10(n))


def gpd_shape(exceedances: np.ndarray) -> float:
    """Empirical-Bayes estimate of the GPD shape `k` from exceedances over a threshold.

    Arguments:
        exceedances: positive values above the threshold (any order), at least 5.

    Returns:
        The shape `k_hat`, shrunk towards 1/2 by PSIS's prior (10 pseudo-observations).
    """
    return gpd_fit(exceedances)[0]


def gpd_fit(exceedances: np.ndarray) -> tuple[float, float]:
    """`(k_hat, sigma_hat)`: the shape of `gpd_shape` and the GPD scale fitted with it.

    The scale is Zhang and Stephens' `-k / b` at the posterior mean of `b` (before the
    shape is shrunk), as in PSIS; `S(x) = (1 + k x / sigma)^(-1/k)` is then the fitted
    survival function of the exceedances.
    """
    x = np.sort(np.asarray(exceedances, np.float64))
    n = x.size
    if n < 5:
        raise ValueError(f"a GPD fit needs at least 5 exceedances, got {n}")
    if not x[-1] > 0:
        return 0.0, 0.0
    m = 30 + int(math.sqrt(n))
    b = 1.0 - np.sqrt(m / (np.arange(1, m + 1, dtype=np.float64) - 0.5))
    quartile = x[int(n / 4 + 0.5) - 1]
    if not quartile > 0:  # ties at the threshold: the smallest positive exceedance sets the scale instead
        quartile = x[x > 0][0]
    b = b / (3.0 * quartile) + 1.0 / x[-1]
    k = np.log1p(-b[:, None] * x).mean(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        profile = n * (np.log(-(b / k)) - k - 1.0)
    profile = np.where(np.isfinite(profile), profile, -np.inf)
    weights = np.exp(profile - profile.max())
    weights /= weights.sum()
    keep = weights >= 10 * np.finfo(np.float64).eps
    b_post = np.sum(b[keep] * weights[keep]) / np.sum(weights[keep])
    k_post = float(np.log1p(-b_post * x).mean())
    return (n * k_post + 10 * 0.5) / (n + 10), -k_post / b_post


def pareto_k(largest: np.ndarray, n: int) -> float:
    """`k_hat` of a sample of `n` terms, given (at least) its largest terms.

    Arguments:
        largest: the largest values of the sample, any order; only the top
            `tail_length(n) + 1` are used (fewer if fewer are given: then the smallest
            given value is the threshold). Non-finite values must not be among them.
        n: the size of the whole sample.

    Returns:
        `k_hat`, or NaN when fewer than `MIN_TERMS` terms or 6 largest values are at hand.
    """
    top = np.sort(np.asarray(largest, np.float64).reshape(-1))[::-1]
    if n < MIN_TERMS or top.size < 6:
        return math.nan
    if not np.all(np.isfinite(top)):
        raise ValueError("pareto_k needs finite values")
    exceedances = _exceedances(*_tail_top(top, n))
    if exceedances.size < 5:  # a flat top: no tail at all
        return 0.0
    return gpd_shape(exceedances)


def _tail_top(top: np.ndarray, n: int) -> tuple[float, np.ndarray]:
    """The threshold and the values above it that PSIS fits, from values sorted largest first:
    the `tail_length(n) + 1`-th largest, and the ones before it."""
    top = top[: tail_length(n) + 1]
    return float(top[-1]), top[:-1]


def _exceedances(threshold: float, above: np.ndarray) -> np.ndarray:
    """The positive exceedances of `above` over `threshold` (from `_tail_top`). Values tied
    with it (durations and integrals on a lattice of holding times) are not exceedances:
    zeros would read as a heavy tail."""
    exceedances = above - threshold
    return exceedances[exceedances > 0]


def tail_square_excess(largest: np.ndarray, n: int) -> float:
    """How far the squares of the largest of `n` terms fall short of what their fitted tail expects.

    A central-limit standard error sums the terms' squares. With a heavy tail (`0 < k < 1/2`)
    the squares of the largest terms usually sum to less than their expectation, which the
    rare, larger terms make up for: the standard error is then too small, most of all in the
    runs that met none of those terms, whose estimates are also the most wrong (they miss the
    terms that would have pulled them up). This fits the GPD to the top of the sample as
    `pareto_k` does (shape `k`, scale `sigma`, above the next value `u`) and returns
    `max(0, M E[(u + Y)^2] - (sum of the M squares))`, with
    `E[(u + Y)^2] = u^2 + 2 u sigma / (1 - k) + 2 sigma^2 / ((1 - k)(1 - 2k))`: added to the
    sum of squares, it counts the tail's terms at their expected size (a Pareto-smoothed
    variance). It is 0 where no tail can be fitted, and where `k >= 1/2` (there the variance
    is infinite and `k_hat` marks the estimate unreliable anyway).

    Arguments:
        largest: the largest absolute values of the sample, any order (as for `pareto_k`).
        n: the size of the whole sample.
    """
    top = np.sort(np.asarray(largest, np.float64).reshape(-1))[::-1]
    top = top[np.isfinite(top)]
    if n < MIN_TERMS or top.size < 6:
        return 0.0
    threshold, above = _tail_top(top, n)
    exceedances = _exceedances(threshold, above)
    if exceedances.size < 5:
        return 0.0
    k, sigma = gpd_fit(exceedances)
    if not (k < 0.5 and sigma > 0):
        return 0.0
    expected = threshold**2 + 2 * threshold * sigma / (1 - k) + 2 * sigma**2 / ((1 - k) * (1 - 2 * k))
    return max(0.0, float(above.size * expected - np.sum(above**2)))


def pareto_k_log(log_largest: np.ndarray, n: int) -> float:
    """`pareto_k` of `exp(log_largest)`, computed without overflow (for importance weights)."""
    log_top = np.asarray(log_largest, np.float64).reshape(-1)
    log_top = log_top[np.isfinite(log_top)]
    if log_top.size == 0:
        return math.nan
    return pareto_k(np.exp(log_top - log_top.max()), n)
