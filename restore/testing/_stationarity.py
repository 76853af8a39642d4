"""Check 1: started from the target, the state at a fixed time is still target-distributed."""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, PRNGKeyArray
from scipy import stats

from .._validation import check_integer
from .._warnings import warn
from ._fixed_time import simulate_to_time


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
        worst = min(self.p_values, key=lambda name: self.p_values[name]) if self.p_values else "-"
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
    logdensity: Callable[[Array], Array] | None = None,
    num_reference: int | None = None,
) -> CheckReport:
    """KS tests of projections (and of `logdensity`) against fresh exact draws, and a chi-square on mode counts.

    `num_reference` exact draws (default: as many as `states`) make the reference sample.
    """
    k_ref, k_dir = jax.random.split(key)
    n, dim = states.shape
    reference = np.asarray(target_sample(k_ref, num_reference or n), np.float64)
    p_values = {}
    for name, v in projection_directions(k_dir, dim, num_projections).items():
        p_values[f"KS {name}"] = float(stats.ks_2samp(states @ v, reference @ v).pvalue)
    if logdensity is not None:
        level = jax.jit(jax.vmap(logdensity))
        values = [np.asarray(level(jnp.asarray(x)), np.float64) for x in (states, reference)]
        values = [np.where(np.isnan(v), -np.inf, v) for v in values]  # NaN is zero density, as in the samplers
        p_values["KS log p"] = float(stats.ks_2samp(*values).pvalue)
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
    logdensity: Callable[[Array], Array] | bool = True,
    reference_factor: int = 10,
    alpha: float = 1e-3,
    max_steps: int = 100_000,
) -> CheckReport:
    """Fixed-time stationarity: `X_0 ~ pi` exactly, then `X_t` must be `~ pi`.

    Runs the sampler's continuous-time process with real holding times from exact target
    draws up to `time` on `num_lanes` independent lanes, then compares `X_t` with
    `reference_factor * num_lanes` fresh exact draws: two-sample Kolmogorov-Smirnov tests
    on coordinate and random projections and on the log density `log p(X_t)`, and a
    chi-square test of mode membership when `assign_mode` and `mode_weights` are given.
    The family-wise level is `alpha` (Bonferroni). A correct sampler passes with
    probability at least `1 - alpha`; use fixed keys. Thinning candidates where the kill
    rate exceeded the bound and states where it was negative (the simulation was not the
    exact process) are counted in `details` and reported with a `RuntimeWarning`.

    The log density is the strongest of these statistics against a kernel that leaves a
    distorted target invariant (a Metropolis test with `(p'/p)^0.8`, a missing Hastings
    term): such a process drifts towards lower or higher densities, which no single
    projection need show. A large reference sample costs only exact draws and makes the
    two-sample tests nearly as strong as tests against the exact law. The power of these
    defaults against deliberately broken kernels is tabulated in the documentation
    (Validate a kernel).

    Arguments:
        sampler: a sampler with `init(key, position)` and `step` (e.g. `JumpRestore`
            with a `log_rate`; call `calibrate` first if it has a `tour_length`).
        key: PRNG key.
        target_sample: exact sampler of the target, `(key, n) -> (n, d)`.
        num_lanes: number of independent lanes.
        time: the fixed time; it should cover a few local moves and tours, so that a
            wrong process has time to drift.
        assign_mode: optional `x -> mode index`, with `mode_weights` the true weights.
        num_projections: random directions to test besides the first coordinates.
        logdensity: compare the distributions of this function of one state too; `True`
            (default) uses the sampler's `logdensity` (skipped for a sampler without
            one), `False` leaves the test out.
        reference_factor: exact reference draws per lane.
        alpha: family-wise significance level.
        max_steps: cap on steps per lane.
    """
    of_state: Callable[[Array], Array] | None
    if isinstance(logdensity, bool):
        of_state = getattr(sampler, "logdensity", None) if logdensity else None
    elif callable(logdensity):
        of_state = logdensity
    else:
        raise TypeError(f"logdensity must be True, False or a function of one state, got {logdensity!r}")
    reference_factor = check_integer(reference_factor, "reference_factor")
    k0, k_run, k_cmp = jax.random.split(key, 3)
    start = target_sample(k0, num_lanes)
    run = simulate_to_time(sampler, k_run, start, time, max_steps)
    states = np.asarray(run.states, np.float64)
    report = compare_to_target(
        k_cmp, states, target_sample, assign_mode, mode_weights, num_projections, alpha, of_state, reference_factor * num_lanes
    )
    report.details.update(
        num_steps=int(np.sum(run.steps)), num_bound_exceeded=run.num_bound_exceeded, num_negative_rate=run.num_negative_rate
    )
    if run.num_bound_exceeded or run.num_negative_rate:
        warn(
            f"the simulated process was not the exact one: the kill rate exceeded the thinning bound at "
            f"{run.num_bound_exceeded} candidate events and was negative at {run.num_negative_rate} states, so "
            "this check tests an approximation (raise the bound, restore.rate_bound; or log_rate, "
            "restore.minimal_log_rate)",
            RuntimeWarning,
        )
    return report
