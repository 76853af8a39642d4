"""Weighted maximum-likelihood fit of a `ConditionalGaussian` (NumPy, float64).

Coordinate by coordinate, the conditional Gaussian of `y_i` given `y_<i` is a regression
with a mean linear in `[1, y_<i, y_<i^2]` and a log variance linear in `[1, y_<i]`. Its
weighted log likelihood is concave in either set of coefficients with the other fixed, so
the fit alternates a weighted least-squares step for the mean with a damped Newton step
for the log variance (a gamma regression with log link on the squared residuals), each
with a weak ridge that keeps the systems well posed. Whether a coordinate's mean, and whether
its log variance, follow the earlier coordinates at all is decided by the Bayesian information
criterion among the four choices (each constant or following): where the spread shrinks
exponentially (a funnel's neck), a mean slope that is only noise would, carried beyond the
draws, put the conditional many of its own standard deviations off; and noise slopes of the
log variance, carried into the tails, make the fit thinner than the target there (long tours).
Student-t conditionals (`df`) are fitted the same way on the draws weighted by their latent
precisions (expectation-conditional maximisation, as for the Student-t mixtures).
"""

from __future__ import annotations

import functools
import math

import jax.numpy as jnp
import numpy as np

from ._conditional import (
    LOG_VARIANCE_RANGE,
    ConditionalGaussian,
    conditional_log_density,
    mean_features,
    variance_features,
)
from ._diagonal_mixture import check_df
from ._fit import Fit, _prepare, single_threaded

#: Alternations of the mean and log-variance steps per coordinate (at most).
ITERATIONS = 25
#: Ridge on the coefficients other than the intercepts, per unit of effective sample size.
RIDGE = 1e-6
#: Stop a coordinate's alternation when its mean log likelihood improves by less than this.
TOLERANCE = 1e-7


def conditional_cost(d: int) -> int:
    """Multiply-adds of one log density: the two coefficient matrices times their features."""
    return int(d * (2 * d + 1) + d * (d + 1))


@single_threaded
def fit_conditional(draws, weights, *, df: float | None = None, iterations: int = ITERATIONS) -> Fit:
    """Fit a `ConditionalGaussian` (Student-t conditionals with `df`) to weighted draws `(n, d)` by weighted maximum likelihood."""
    x, w = _prepare(draws, weights)
    df = check_df(df)
    d = x.shape[1]
    loc = w @ x / w.sum()
    scale = np.sqrt(w @ (x - loc) ** 2 / w.sum())
    if not np.all(scale > 0):
        raise ValueError("the draws do not vary along every coordinate")
    y = (x - loc) / scale
    features, spread_features = mean_features(y), variance_features(y)
    a = np.zeros((d, 2 * d + 1))
    c = np.zeros((d, d + 1))
    ridge, log_n = RIDGE * w.sum(), math.log(w.sum())
    for i in range(d):
        constant = np.zeros(1, np.int64)
        mean_cols = np.r_[0, 1 + np.arange(i), 1 + d + np.arange(i)]  # [1, y_<i, y_<i^2]
        best, start = -math.inf, None
        for mean in (constant, mean_cols) if i else (constant,):
            for spread in (1, i + 1) if i else (1,):
                g = spread_features[:, :spread]
                m, v, fitted = _fit_coordinate(features[:, mean], g, y[:, i], w, ridge, iterations, df, start if spread > 1 else None)
                if mean is constant and spread > 1:
                    start = v  # the full mean's spread starts from the constant mean's
                bic = fitted - 0.5 * (mean.size + spread) * log_n  # the Bayesian information criterion, as a log likelihood
                if bic > best:
                    best, a[i], c[i] = bic, 0.0, 0.0
                    a[i, mean], c[i, :spread] = m, v
    return _conditional_fit(loc, scale, a, c, df)


def _fit_coordinate(
    f: np.ndarray, g: np.ndarray, target: np.ndarray, w: np.ndarray, ridge: float, iterations: int, df: float | None, start: np.ndarray | None = None
):
    """The mean and log-variance coefficients of one coordinate (`f`, `g`: its features; `start`:
    log-variance coefficients to start from) and its weighted log likelihood."""
    low, high = LOG_VARIANCE_RANGE
    penalty_a = np.full(f.shape[1], ridge)
    penalty_a[0] = 0.0
    penalty_c = np.full(g.shape[1], ridge)
    penalty_c[0] = 0.0
    if start is None:
        c = np.zeros(g.shape[1])
        c[0] = math.log(max(float(w @ (target - w @ target / w.sum()) ** 2 / w.sum()), 1e-300))
    else:
        c = np.array(start, np.float64)
    total = w.sum()

    def loss(c_, r2):
        v = np.clip(g @ c_, low, high)
        return float(w @ (r2 * np.exp(-v) + v)) / total + 0.5 * float(penalty_c @ c_**2) / total

    previous = math.inf
    a = np.zeros(f.shape[1])
    precision = np.ones_like(w)  # the Student-t's latent precisions (1 for Gaussian conditionals)
    for _ in range(iterations):
        raw = g @ c
        v = np.clip(raw, low, high)
        if df is not None and np.any(a):
            precision = (df + 1.0) / (df + (target - f @ a) ** 2 * np.exp(-v))
        omega = w * precision * np.exp(-v)
        lhs = (f.T * omega) @ f + np.diag(penalty_a)
        a = _solve(lhs, (f.T * omega) @ target)
        r2 = precision * (target - f @ a) ** 2
        e = r2 * np.exp(-v)
        inside = (raw > low) & (raw < high)  # the clipped rows do not move with c
        grad = g.T @ (w * (1.0 - e) * inside) + penalty_c * c
        hess = (g.T * (w * e * inside)) @ g + np.diag(penalty_c + 1e-12 * total)
        step = _solve(hess, grad)
        current = loss(c, r2)
        for _ in range(30):  # damped: halve the step until the loss falls
            trial = c - step
            if loss(trial, r2) <= current:
                c = trial
                break
            step = 0.5 * step
        value = loss(c, r2)
        if previous - value < TOLERANCE:
            break
        previous = value
    v = np.clip(g @ c, low, high)
    z2 = (target - f @ a) ** 2 * np.exp(-v)
    return a, c, float(w @ conditional_log_density(z2, v, df))


def _solve(lhs: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    try:
        return np.linalg.solve(lhs, rhs)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(lhs, rhs, rcond=None)[0]


def _conditional_fit(loc: np.ndarray, scale: np.ndarray, a: np.ndarray, c: np.ndarray, df: float | None) -> Fit:
    d = loc.shape[0]
    dtype = jnp.result_type(float)
    low, high = LOG_VARIANCE_RANGE

    @functools.cache
    def build(size: int):
        if size != 1:
            raise ValueError(f"a conditional Gaussian has one component, not {size}")
        return ConditionalGaussian(jnp.asarray(loc, dtype), scale, a, c, df)

    def log_prob(points):
        y = (np.asarray(points, np.float64) - loc) / scale
        m = mean_features(y) @ a.T
        v = np.clip(variance_features(y) @ c.T, low, high)
        return np.sum(conditional_log_density((y - m) ** 2 * np.exp(-v), v, df), axis=1) - np.sum(np.log(scale))

    family = "conditional" + ("" if df is None else f" student-t(df={df:g})")
    return Fit(build, log_prob, family, 1, conditional_cost(d), dict(loc=loc, scale=scale, mean=a, log_variance=c))
