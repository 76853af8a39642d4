"""Check 1: started from the target, the state at a fixed time is still target-distributed."""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, PRNGKeyArray
from scipy import stats

from ._fixed_time import fixed_time_states


class CheckReport(NamedTuple):
    """Outcome of a statistical check.

    Attributes:
        passed: whether every test statistic stayed within its threshold.
        p_values: p-value of each sub-test, by name.
        threshold: the per-test level (Bonferroni-corrected).
        details: anything else worth printing (z-scores, coverage...).
    """

    passed: bool
    p_values: dict[str, float]
    threshold: float
    details: dict

    @property
    def min_p_value(self) -> float:
        return min(self.p_values.values()) if self.p_values else float("nan")

    def __str__(self) -> str:
        verdict = "passed" if self.passed else "FAILED"
        worst = min(self.p_values, key=self.p_values.get) if self.p_values else "-"
        return f"{verdict}: {len(self.p_values)} tests, smallest p = {self.min_p_value:.3g} ({worst}), per-test level {self.threshold:.3g}"


def projection_directions(key: PRNGKeyArray, dim: int, num_random: int, max_coordinates: int = 5) -> dict[str, np.ndarray]:
    """Coordinate axes (the first few) and random unit directions to project on."""
    directions = {f"x[{i}]": np.eye(dim)[i] for i in range(min(dim, max_coordinates))}
    if num_random:
        raw = np.asarray(jax.random.normal(key, (num_random, dim)), np.float64)
        for j, v in enumerate(raw):
            directions[f"random[{j}]"] = v / np.linalg.norm(v)
    return directions


def compare_to_target(
    key: PRNGKeyArray,
    states: np.ndarray,
    target_sample: Callable[[PRNGKeyArray, int], Array],
    assign_mode: Callable[[Array], Array] | None,
    mode_weights: Array | None,
    num_projections: int,
    alpha: float,
) -> CheckReport:
    """KS tests of projections against fresh exact draws, and a chi-square on mode counts."""
    k_ref, k_dir = jax.random.split(key)
    n, dim = states.shape
    reference = np.asarray(target_sample(k_ref, n), np.float64)
    p_values = {}
    for name, v in projection_directions(k_dir, dim, num_projections).items():
        p_values[f"KS {name}"] = float(stats.ks_2samp(states @ v, reference @ v).pvalue)
    details = {}
    if assign_mode is not None and mode_weights is not None:
        modes = np.asarray(jax.vmap(assign_mode)(jnp.asarray(states)))
        weights = np.asarray(mode_weights, np.float64)
        counts = np.bincount(modes, minlength=weights.size)
        p_values["chi2 modes"] = float(stats.chisquare(counts, weights / weights.sum() * n).pvalue)
        details["mode_shares"] = counts / n
    threshold = alpha / len(p_values)
    return CheckReport(min(p_values.values()) > threshold, p_values, threshold, details)


def stationarity_test(
    sampler,
    key: PRNGKeyArray,
    target_sample: Callable[[PRNGKeyArray, int], Array],
    *,
    num_lanes: int = 20_000,
    time: float = 5.0,
    assign_mode: Callable[[Array], Array] | None = None,
    mode_weights: Array | None = None,
    num_projections: int = 4,
    alpha: float = 1e-3,
    max_steps: int = 100_000,
) -> CheckReport:
    """Fixed-time stationarity: `X_0 ~ pi` exactly, then `X_t` must be `~ pi`.

    Runs the sampler's continuous-time process with real holding times from exact target
    draws up to `time` on `num_lanes` independent lanes, then compares `X_t` with fresh
    exact draws: two-sample Kolmogorov-Smirnov tests on coordinate and random
    projections, and a chi-square test of mode membership when `assign_mode` and
    `mode_weights` are given. The family-wise level is `alpha` (Bonferroni). A correct
    sampler passes with probability at least `1 - alpha`; use fixed keys.

    Arguments:
        sampler: a sampler with `init(key, position)` and `step` (e.g. `JumpRestore`
            with a `log_rate`; call `calibrate` first if it has a `tour_length`).
        key: PRNG key.
        target_sample: exact sampler of the target, `(key, n) -> (n, d)`.
        num_lanes: number of independent lanes (and of reference draws).
        time: the fixed time; it should cover a few local moves and tours, so that a
            wrong process has time to drift.
        assign_mode: optional `x -> mode index`, with `mode_weights` the true weights.
        num_projections: random directions to test besides the first coordinates.
        alpha: family-wise significance level.
        max_steps: cap on steps per lane.
    """
    k0, k_run, k_cmp = jax.random.split(key, 3)
    start = target_sample(k0, num_lanes)
    states, _ = fixed_time_states(sampler, k_run, start, time, max_steps)
    return compare_to_target(k_cmp, np.asarray(states, np.float64), target_sample, assign_mode, mode_weights, num_projections, alpha)
