"""Error metrics against exact answers: mode weights, moments, and MMD to exact draws."""

from __future__ import annotations

import math

import numpy as np

from ._mmd import mmd
from ._problems import Reference
from ._runner import RunOutput


def subsample(draws: np.ndarray, weights: np.ndarray | None, max_points: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """At most `max_points` of the draws with positive weight, chosen uniformly; weights renormalised."""
    draws = np.asarray(draws, np.float64)
    w = np.ones(len(draws)) if weights is None else np.asarray(weights, np.float64)
    keep = np.flatnonzero(np.isfinite(w) & (w > 0) & np.all(np.isfinite(draws), axis=1))
    if len(keep) > max_points:
        keep = rng.choice(keep, max_points, replace=False)
    w = w[keep]
    return draws[keep], w / w.sum() if len(keep) else w


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
