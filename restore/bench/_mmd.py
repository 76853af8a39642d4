"""Maximum mean discrepancy with a Gaussian kernel, and the median heuristic for its bandwidth."""

from __future__ import annotations

import math

import numpy as np


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
