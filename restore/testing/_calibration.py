"""Check 3: over independent replications, z-scores are standard normal."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from jaxtyping import Array, PRNGKeyArray
from scipy import stats

from .._options import SaveDraws
from .._sample import sample
from ._stationarity import CheckReport


def calibration_test(
    sampler,
    key: PRNGKeyArray,
    truths: Mapping[str, tuple[Callable[[Array], Array], float]],
    *,
    num_replications: int = 200,
    lanes_per_replication: int = 16,
    num_steps: int = 1000,
    alpha: float = 1e-3,
    coverage_tolerance: float | None = None,
    **sample_kwargs,
) -> CheckReport:
    """Calibration of standard errors: z-scores over replications are `N(0, 1)`.

    One run of `num_replications * lanes_per_replication` lanes is cut into groups of
    lanes; each group is an independent replication with its own estimate and standard
    error. For each scalar observable, the z-scores `(estimate - truth) / se` are tested
    with a Kolmogorov-Smirnov test against `N(0, 1)`, and the coverage of the nominal
    95% interval must lie within `coverage_tolerance` of 0.95 (default: three binomial
    standard errors, `3 sqrt(0.95 * 0.05 / R)`). Standard errors are asymptotic: give
    each replication enough tours (hundreds) for the normal approximation to hold.

    Arguments:
        sampler: a `JumpRestore` (or `MixtureMH`, whose lanes are then the replicates).
        key: PRNG key.
        truths: mapping `name -> (function of one state returning a scalar, truth)`.
        num_replications: `R`, number of independent replications.
        lanes_per_replication: lanes in each replication.
        num_steps: steps per lane.
        alpha: family-wise level of the KS tests.
        coverage_tolerance: allowed deviation of the 95% coverage from 0.95.
        sample_kwargs: passed on to `restore.sample`.
    """
    observables = {name: fn for name, (fn, _) in truths.items()}
    sample_kwargs.setdefault("progress", False)
    sample_kwargs.setdefault("save", SaveDraws(0))
    lanes = num_replications * lanes_per_replication
    result = sample(sampler, key, num_lanes=lanes, num_steps=num_steps, observables=observables, **sample_kwargs)
    tolerance = coverage_tolerance if coverage_tolerance is not None else 3.0 * math.sqrt(0.95 * 0.05 / num_replications)
    p_values: dict[str, float] = {}
    details: dict[str, Any] = {}
    passed = True
    for name, (_, truth) in truths.items():
        z = np.array(
            [
                float(result.estimate(name, lanes=slice(r * lanes_per_replication, (r + 1) * lanes_per_replication)).z_score(truth))
                for r in range(num_replications)
            ]
        )
        coverage = float(np.mean(np.abs(z) < stats.norm.isf(0.025)))
        p_values[f"KS z {name}"] = float(stats.kstest(z, "norm").pvalue)
        details[f"coverage {name}"] = coverage
        details[f"z {name}"] = z
        passed &= abs(coverage - 0.95) <= tolerance
    threshold = alpha / len(p_values)
    details["coverage tolerance"] = tolerance
    return CheckReport(bool(passed and min(p_values.values()) > threshold), p_values, threshold, details)
