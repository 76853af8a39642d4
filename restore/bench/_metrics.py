"""Error metrics against exact answers: mode weights, moments, and MMD to exact draws."""

from __future__ import annotations

import math

import numpy as np

from ._problems import Reference
from ._runner import RunOutput


def median_bandwidth(x: np.ndarray, max_points: int = 1000) -> float:
    """Median heuristic: the median pairwise distance between (at most `max_points` of) the rows of `x`."""
    x = np.asarray(x, np.float64)[:max_points]
    if x.ndim != 2 or len(x) < 2:
        raise ValueError(f"need at least 2 points of shape (n, d) for the median heuristic, got {x.shape}")
    d2 = _sq_dists(x, x)
    h = math.sqrt(float(np.median(d2[np.triu_indices(len(x), k=1)])))
    return h if h > 0 else 1.0


def _sq_dists(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    d2 = np.sum(x**2, 1)[:, None] + np.sum(y**2, 1)[None, :] - 2.0 * x @ y.T
    return np.maximum(d2, 0.0)


def subsample(draws: np.ndarray, weights: np.ndarray | None, max_points: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """At most `max_points` of the draws with positive weight, chosen uniformly; weights renormalised."""
    draws = np.asarray(draws, np.float64)
    w = np.ones(len(draws)) if weights is None else np.asarray(weights, np.float64)
    keep = np.flatnonzero(np.isfinite(w) & (w > 0) & np.all(np.isfinite(draws), axis=1))
    if len(keep) > max_points:
        keep = rng.choice(keep, max_points, replace=False)
    w = w[keep]
    return draws[keep], w / w.sum() if len(keep) else w


def mmd(x: np.ndarray, wx: np.ndarray, y: np.ndarray, bandwidth: float) -> float:
    """Maximum mean discrepancy between weighted draws `(x, wx)` and equally weighted exact draws `y`.

    Gaussian kernel `exp(-|a - b|^2 / (2 h^2))`. Within-sample terms leave out the
    diagonal (the weighted U-statistic), so two samples of the same law give values near
    zero whatever their size; the square root of the positive part is returned.
    """
    if len(x) < 2 or len(y) < 2:
        return math.nan
    wx = np.asarray(wx, np.float64) / np.sum(wx)
    k = lambda a, b: np.exp(-_sq_dists(a, b) / (2.0 * bandwidth**2))  # noqa: E731
    kxx, kyy, kxy = k(x, x), k(y, y), k(x, y)
    sxx = (wx @ kxx @ wx - np.sum(wx**2 * np.diag(kxx))) / max(1.0 - np.sum(wx**2), 1e-12)
    m = len(y)
    syy = (np.sum(kyy) - np.trace(kyy)) / (m * (m - 1))
    sxy = float(wx @ kxy.mean(axis=1))
    return math.sqrt(max(sxx + syy - 2.0 * sxy, 0.0))


def score(output: RunOutput, ref: Reference, max_points: int, seed: int) -> dict[str, float]:
    """All error metrics of one run against the reference.

    `mode_rmse`: root-mean-square error of the mode weights. `mean_error` and
    `second_moment_error`: root-mean-square over coordinates of the errors in units of
    the target's standard deviation (`sd_i` for means, `sd_i^2` for `E[x_i^2]`).
    `mmd`: MMD to the exact draws with the reference's bandwidth, on at most
    `max_points` subsampled draws.
    """
    mode = math.nan
    if ref.mode_weights is not None and output.mode_weights is not None:
        mode = float(np.sqrt(np.mean((np.asarray(output.mode_weights) - ref.mode_weights) ** 2)))
    mean_err = float(np.sqrt(np.mean(((np.asarray(output.mean) - ref.mean) / ref.sd) ** 2)))
    m2_err = float(np.sqrt(np.mean(((np.asarray(output.second_moment) - ref.second_moment) / ref.sd**2) ** 2)))
    dist = math.nan
    if output.draws is not None and len(output.draws) >= 2:
        x, w = subsample(output.draws, output.draw_weights, max_points, np.random.default_rng(seed))
        dist = mmd(x, w, ref.draws[:max_points], ref.bandwidth)
    return {"mode_rmse": mode, "mean_error": mean_err, "second_moment_error": m2_err, "mmd": dist}


def pooled_rms(values) -> float:
    """Root mean square over seeds (NaNs ignored): how errors are pooled before ratios are taken."""
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], np.float64)
    return float(np.sqrt(np.mean(v**2))) if v.size else math.nan
