"""Check 2: from regeneration-started lanes, estimates and tour lengths agree with the truth."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from jaxtyping import Array, PRNGKeyArray
from scipy import stats

from .._sample import sample
from ._stationarity import CheckReport


def _two_sided_p(z: np.ndarray) -> np.ndarray:
    return 2.0 * stats.norm.sf(np.abs(z))


def ergodicity_test(
    sampler,
    key: PRNGKeyArray,
    truths: Mapping[str, tuple[Callable[[Array], Array], Array]],
    *,
    num_lanes: int = 1000,
    num_steps: int = 2000,
    log_z: float | None = None,
    alpha: float = 1e-3,
    **sample_kwargs,
) -> CheckReport:
    """Ergodicity: estimates of known expectations lie within their standard errors.

    Runs `restore.sample` from regeneration-started lanes with the given observables and
    turns each component's estimate into a z-score against its true value. With the true
    `log_z` of the (unnormalised) target, the mean tour duration is also tested against
    `1/c = Z / c_tilde` and the tour-based `log Z` against the truth. Each z-score gives a
    two-sided normal p-value; the family-wise level is `alpha` (Bonferroni).

    Arguments:
        sampler: a `JumpRestore` (calibrated or not).
        key: PRNG key.
        truths: mapping `name -> (function of one state, true expectation)`.
        num_lanes: number of lanes of the run.
        num_steps: steps per lane.
        log_z: true log normalising constant of the sampler's log density, if known.
        alpha: family-wise level.
        sample_kwargs: passed on to `restore.sample` (e.g. `weights="time"`).
    """
    observables = {name: fn for name, (fn, _) in truths.items()}
    sample_kwargs.setdefault("progress", False)
    result = sample(sampler, key, num_lanes=num_lanes, num_steps=num_steps, observables=observables, **sample_kwargs)
    p_values: dict[str, float] = {}
    details: dict[str, Any] = {"result": result}
    for name, (_, truth) in truths.items():
        z = np.atleast_1d(result.estimate(name).z_score(np.asarray(truth)))
        details[f"z {name}"] = z
        for i, p in enumerate(_two_sided_p(z).ravel()):
            p_values[f"{name}[{i}]" if z.size > 1 else name] = float(p)
    tour_log_rate = result.tour_log_rate
    if log_z is not None and result.is_regenerative and tour_log_rate is not None:
        stats_ = result.tour_statistics()
        expected = math.exp(log_z - tour_log_rate)
        z_duration = (stats_.mean_duration - expected) / stats_.mean_duration_se
        details["mean tour duration"] = (stats_.mean_duration, stats_.mean_duration_se, expected)
        p_values["mean tour duration = 1/c"] = float(_two_sided_p(np.asarray(z_duration)))
        est = result.normalising_constant("tours")
        p_values["log Z (tours)"] = float(_two_sided_p(np.asarray(est.z_score(log_z))))
    threshold = alpha / len(p_values)
    return CheckReport(min(p_values.values()) > threshold, p_values, threshold, details)
