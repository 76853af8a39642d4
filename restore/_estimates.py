"""Ratio estimators and their standard errors, from summed tours or lanes (numpy, float64)."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ._pareto import K_HAT_LIMIT, k_hat_limit, pareto_k


class UnreliableEstimateWarning(RuntimeWarning):
    """An estimate's standard error cannot be trusted (a heavy tail, or too few terms to check)."""


class Estimate(NamedTuple):
    """An estimate with its standard error, and whether that error bar can be trusted.

    `k_hat` is the Pareto shape of the tail of the terms the estimate sums (per-tour
    residuals `F - pi_hat T` for tour-based estimates, tour durations or importance
    weights for `log Z`, per-lane residuals for lane-based ones). The central-limit
    standard error needs finite variance, `k < 1/2`: at or above `k_limit` (see
    `restore.K_HAT_LIMIT`) the estimate is marked unreliable, because a few terms
    dominate and the true error can be many times the reported one. NaN means the tail
    could not be assessed (too few terms), which also counts as unreliable.

    Attributes:
        value: the estimate (the observable's shape).
        standard_error: its standard error (same shape). Tour-based ones count the squares
            of their largest terms at the size the fitted tail expects, where that is more
            than they sum to, in proportion to how one-sided those terms are (a Pareto-smoothed
            variance: `restore._tails.signed_square_excess`).
        k_hat: the tail shape of each component (same shape; NaN where not assessed).
        k_limit: the largest `k_hat` at which the error bar is trusted (depends on how many
            terms there are; NaN where no diagnostic was computed).
        caveat: a reason, found outside the tail fit, why the error bar cannot be trusted
            (e.g. tours that were still running when the run ended); empty if none.
    """

    value: np.ndarray
    standard_error: np.ndarray
    k_hat: np.ndarray | float = math.nan
    k_limit: float = math.nan
    caveat: str = ""

    @property
    def reliable(self) -> np.ndarray:
        """Whether each component's error bar can be trusted: `k_hat < k_limit` and no caveat (a bool array)."""
        with np.errstate(invalid="ignore"):
            ok = (np.asarray(self.k_hat) < self.k_limit) & (not self.caveat)
        return np.broadcast_to(ok, np.shape(self.value))

    def z_score(self, truth) -> np.ndarray:
        """`(value - truth) / standard_error`."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return (self.value - np.asarray(truth)) / self.standard_error

    def __repr__(self) -> str:
        show = lambda a: np.array2string(np.asarray(a), formatter={"float_kind": lambda v: f"{v:.4g}"})  # noqa: E731
        text = f"{type(self).__name__}(value={show(self.value)}, standard_error={show(self.standard_error)}, k_hat={show(self.k_hat)}"
        if not np.all(self.reliable):
            text += f", UNRELIABLE: {unreliable_reason(self)}"
        return text + ")"


#: What `unreliable_reason` advises when there are too few terms (callers add no other advice then).
FEW_TERMS_REMEDY = "run longer or with more lanes"
#: Lane-based estimates are marked unreliable when the halves of the lanes' runs (or stored draws)
#: disagree by more than this many standard errors in some component (`start_transient`).
START_Z_LIMIT = 4.0
#: What to do when the lanes have not forgotten their start (callers add no other advice then).
START_REMEDY = "run longer, or start the lanes nearer the target (positions=)"
#: What to do about the tours a run dropped at its end (`SampleResult.tours_dropped`; callers add no other advice then).
DROPPED_TOURS_REMEDY = "finish them (finish_tours=True, the default) for error bars that hold"
#: What to do about mass the final regeneration of `autosample` leaves unseen (`restore._autosample.coverage_caveat`).
COVERAGE_REMEDY = "give autosample more lanes or steps (better stages choose a better regeneration), or build one that covers every mode"


def unreliable_reason(estimate: Estimate) -> str:
    """Plain words on why an estimate's error bar cannot be trusted (empty if it can)."""
    k = np.asarray(estimate.k_hat, np.float64)
    if np.all(estimate.reliable):
        return ""
    if estimate.caveat:
        return estimate.caveat
    if math.isnan(estimate.k_limit) or np.all(np.isnan(k)):
        return "too few tours (or lanes) to check the tail of the terms; its error bar is not backed by a diagnostic"
    worst = float(np.nanmax(k))
    if estimate.k_limit < K_HAT_LIMIT:
        return (
            f"too few terms (tours, or lanes) to trust a standard error: tail shape k_hat = {worst:.2f} >= "
            f"{estimate.k_limit:.2f}, the limit for so few; {FEW_TERMS_REMEDY}"
        )
    return (
        f"tail shape k_hat = {worst:.2f} >= {estimate.k_limit:.2f}: a few long tours dominate, the variance is likely "
        "infinite and the true error can be many times the standard error"
    )


def check_total_time(total: float, total_sq: float, what: str) -> None:
    """Refuse ratio estimates whose time weights underflowed to zero (a silent `0 / 0` or a zero
    standard error otherwise).

    Holding times `1 / (r + gamma)` underflow when the kill rate is astronomically large
    (a huge `log_rate`, or a tiny `tour_length`): then every weight is zero, or their
    squares are, and no estimate or standard error can be formed.
    """
    if not total > 0:
        raise ValueError(
            f"the {what} hold no time: every holding time 1 / (r + gamma) is zero, so the kill rate was "
            "infinite or far too large at every visited state (the log density was -inf, NaN or +inf wherever "
            "the tours went, or log_rate is so large that the holding times underflow); check the log density, "
            "or lower log_rate (lengthen tour_length)"
        )
    if not total_sq > 0:
        raise ValueError(
            f"the durations of the {what} are so short that their squares underflow, so no standard error "
            "can be computed: the holding times 1 / (r + gamma) are tiny because the kill rate gamma (log_rate) "
            "or the local_rate r is far too large; lower log_rate (lengthen tour_length) or local_rate"
        )


def tour_ratio(sum_f, sum_f2, sum_ft, sum_t, sum_t2, num_tours) -> Estimate:
    """Regenerative ratio estimator `sum F / sum T` over i.i.d. tours.

    Standard error `sqrt(sum (F - pi_hat T)^2) / sum T`, expanded in the running sums,
    with the `n / (n - 1)` small-sample factor.
    """
    n = float(np.sum(num_tours))
    if n < 2:
        raise ValueError(
            f"only {int(n)} complete tour(s): tour-based estimates need at least 2; run more steps or "
            "lanes, shorten the tours, or use method='lanes'"
        )
    F, F2, FT = (np.sum(np.asarray(a, np.float64), axis=0) for a in (sum_f, sum_f2, sum_ft))
    T, T2 = float(np.sum(np.asarray(sum_t, np.float64))), float(np.sum(np.asarray(sum_t2, np.float64)))
    check_total_time(T, T2, "tours")
    value = F / T
    ss = np.maximum(F2 - 2.0 * value * FT + value**2 * T2, 0.0)
    return Estimate(value, np.sqrt(ss * n / (n - 1.0)) / T)


def with_tail_excess(estimate: Estimate, excess: np.ndarray, num_tours: float, total_time: float) -> Estimate:
    """`estimate` (from `tour_ratio`) with the squares of its largest residuals counted at
    their fitted tail's expected size: `excess` (per component, `signed_square_excess`) is
    added to the residuals' sum of squares (a Pareto-smoothed standard error)."""
    n = float(num_tours)
    extra = np.asarray(excess, np.float64).reshape(np.shape(estimate.standard_error)) * n / (n - 1.0) / total_time**2
    return estimate._replace(standard_error=np.sqrt(np.asarray(estimate.standard_error) ** 2 + extra))


def lane_ratio(all_f, all_t) -> Estimate:
    """Ratio estimator over independent lanes: each lane's weighted sums are one replicate.

    Its `k_hat` is the tail shape of the per-lane residuals `|F_lane - value T_lane|`.
    """
    f = np.asarray(all_f, np.float64)
    t = np.asarray(all_t, np.float64)
    lanes = t.shape[0]
    if lanes < 2:
        raise ValueError("lane-based standard errors need at least 2 lanes")
    T = t.sum()
    check_total_time(T, float(np.sum(t**2)), "lanes")
    value = f.sum(axis=0) / T
    resid = f - value * t.reshape((-1,) + (1,) * (f.ndim - 1))
    flat = np.abs(resid.reshape(lanes, -1))
    k_hat = np.array([pareto_k(flat[:, j], lanes) for j in range(flat.shape[1])]).reshape(value.shape)
    return Estimate(value, np.sqrt(np.sum(resid**2, axis=0) * lanes / (lanes - 1.0)) / T, k_hat, k_hat_limit(lanes))


def halves_z(values, weights) -> np.ndarray | None:
    """How far apart, in standard errors, the weighted means of the first and the second half of
    each lane's stored draws are (`values`: `(rows, lanes, ...)`, `weights`: `(rows, lanes)`),
    per component; `None` with fewer than 4 rows or 2 lanes.

    The lanes are the replicates: each gives its sums over both halves, so the difference of the
    two ratio estimates has a delta-method standard error over lanes, whatever the correlation
    within a lane. A lane that has forgotten its start gives halves that agree within their
    error; one that starts away from the target (a draw of the regeneration, no burn-in) has a
    first half that leans towards the start.
    """
    v, w = np.asarray(values, np.float64), np.asarray(weights, np.float64)
    half = v.shape[0] // 2
    if half < 2:
        return None
    sums = lambda rows: (np.einsum("rl,rl...->l...", w[rows], v[rows]), w[rows].sum(axis=0))  # noqa: E731
    return halves_z_from_sums(*sums(slice(0, half)), *sums(slice(half, 2 * half)))


def halves_z_from_sums(f1, t1, f2, t2) -> np.ndarray | None:
    """`halves_z` from each lane's weighted sums `(lanes, ...)` and weights `(lanes,)` over the
    first and the second half of its run (or of its draws); `None` with fewer than 2 lanes, or
    with a half of zero weight."""
    lanes = f1.shape[0]
    if lanes < 2:
        return None
    T1, T2 = t1.sum(), t2.sum()
    if not (T1 > 0 and T2 > 0):
        return None
    m1, m2 = f1.sum(axis=0) / T1, f2.sum(axis=0) / T2
    lane = (-1,) + (1,) * (f1.ndim - 1)
    resid = (f1 - m1 * t1.reshape(lane)) / T1 - (f2 - m2 * t2.reshape(lane)) / T2
    se = np.sqrt(np.sum(resid**2, axis=0) * lanes / (lanes - 1.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(se > 0, (m1 - m2) / np.where(se > 0, se, 1.0), 0.0)


def start_transient(z: np.ndarray | None) -> str:
    """Why a lane-based estimate leans towards the lanes' start (`halves_z` or
    `halves_z_from_sums` above `START_Z_LIMIT`), or `""`: no sign of it, or nothing to
    compare (`None`: too few stored draws, or a run with no second half)."""
    if z is None or not np.any(np.abs(z) > START_Z_LIMIT):
        return ""
    return (
        f"the first and second halves of the lanes' runs disagree by up to {float(np.max(np.abs(z))):.1f} "
        "standard errors: the lanes have not forgotten their start (a draw of the regeneration, with no burn-in), "
        f"so the estimate leans towards it; {START_REMEDY}"
    )


def log_mean_exp(log_sum: np.ndarray, log_sum2: np.ndarray, count: float) -> tuple[float, float]:
    """`log` of a mean from log-sums of values and squares, with the standard error of that log."""
    if count < 2:
        raise ValueError("need at least 2 importance draws")
    ls = np.logaddexp.reduce(np.asarray(log_sum, np.float64))
    ls2 = np.logaddexp.reduce(np.asarray(log_sum2, np.float64))
    if ls == -np.inf:
        raise ValueError(
            f"all {int(count)} importance weights p(y) / q(y) at the tour starts are zero: no tour started where "
            "the target density is positive (the regeneration distribution misses the target's support, or "
            "the log density was -inf, NaN or +inf at every start), so log Z cannot be estimated"
        )
    log_mean = ls - math.log(count)
    # relative variance of the mean: (E w^2 / (E w)^2 - 1) / n
    rel = math.exp(ls2 - math.log(count) - 2.0 * log_mean) - 1.0
    return float(log_mean), math.sqrt(max(rel, 0.0) / (count - 1.0))
