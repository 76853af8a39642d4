"""Multiplexing over path depth and BDPT strategy (Hachisuka et al. 2014, MMLT).

A point `x = (v, u)` of `[0, 1)^(1 + D)` picks the pair `(k, s)` (depth `k` in
`1..M` segments, strategy `s` in `0..k`) from its first coordinate `v` by the inverse
CDF of `q(k, s) = pmf[k] / (k + 1)`: the depth by the pmf, then one of its `k + 1`
strategies uniformly. The pairs are ordered by `k`, then `s`. A path of `k` segments
has `k + 1` strategies, not `k + 2`: the one with no camera vertex (a light subpath
hitting the pinhole) has zero density and is never drawn.

So a uniform point draws `(k, s)` exactly as MMLT's large step does, and a move that
keeps `v` (within its cell) keeps the depth and the strategy.
"""

from __future__ import annotations

import numpy as np


def strategy_pairs(max_depth: int) -> tuple[np.ndarray, np.ndarray]:
    """`(k, s)` of every pair, as int32 arrays of length `sum_k (k + 1)`."""
    ks = [k for k in range(1, max_depth + 1) for _ in range(k + 1)]
    ss = [s for k in range(1, max_depth + 1) for s in range(k + 1)]
    return np.asarray(ks, np.int32), np.asarray(ss, np.int32)


def depth_pmf(mean_luminance: np.ndarray, floor: float = 0.01) -> np.ndarray:
    """The depth pmf proportional to each depth's mean luminance, each at least `floor / M`.

    `mean_luminance[k - 1]` estimates depth `k`'s share of the image's total luminance.
    The floor keeps every depth reachable even if its bootstrap estimate was zero.
    """
    c = np.asarray(mean_luminance, np.float64)
    if c.ndim != 1 or c.size < 1 or not np.all(np.isfinite(c)) or np.any(c < 0):
        raise ValueError("mean_luminance must be a non-empty vector of finite, non-negative numbers")
    if not 0 < floor <= 1:
        raise ValueError(f"floor must be in (0, 1], got {floor!r}")
    pmf = c / c.sum() if c.sum() > 0 else np.full(c.size, 1.0 / c.size)
    pmf = np.maximum(pmf, floor / c.size)
    return pmf / pmf.sum()


def strategy_pmf(pmf: np.ndarray) -> np.ndarray:
    """`q(k, s) = pmf[k] / (k + 1)` over the pairs of `strategy_pairs(len(pmf))`."""
    pmf = np.asarray(pmf, np.float64)
    if pmf.ndim != 1 or np.any(~np.isfinite(pmf)) or np.any(pmf <= 0) or abs(pmf.sum() - 1) > 1e-6:
        raise ValueError("the depth pmf must be positive and sum to 1")
    ks, _ = strategy_pairs(pmf.size)
    return pmf[ks - 1] / (ks + 1)


def select_pairs(v: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The pair index with `CDF[i-1] <= v < CDF[i]` for each `v` in `[0, 1)` (float32 inputs)."""
    cdf = np.cumsum(np.asarray(q, np.float64))
    cdf[-1] = np.inf  # rounding never maps a v < 1 past the last pair
    return np.searchsorted(cdf, np.asarray(v, np.float64), side="right").astype(np.int64)
