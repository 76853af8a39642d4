"""dynesty's static nested sampler with a uniform prior on the problem's box, under a wall-time cap."""

from __future__ import annotations

import math
import time
import warnings

import jax
import numpy as np
from jaxtyping import PRNGKeyArray

from ._evidence_runner import EvidenceOutput, EvidenceRunner, right_well_share, weighted_moments
from ._restore_runners import short_notes
from ._timing import Stopwatch


class DynestyRunner(EvidenceRunner):
    """`dynesty.NestedSampler` with its users' usual settings: `bound="multi"`, `sample="auto"`.

    `sample="auto"` is dynesty's rule for the dimension: uniform sampling in the bounding
    ellipsoids below 10 dimensions, random walks up to 20, random slices above. The
    likelihood is the problem's log density (jitted, called once per point from NumPy, as
    a user of dynesty would write it) and the prior is uniform on the box, so
    `log Z = logz + log(box volume)`; its standard error is dynesty's `logzerr`. Runs stop
    at dynesty's default `dlogz` or after `max_seconds` of sampling; a capped run adds the
    live points and reports what it reached (status `capped`). Evaluations are the
    likelihood calls, counted in the wrapper.
    """

    family = "nested"

    def __init__(self, nlive: int = 500, max_seconds: float = 600.0, name: str = "dynesty"):
        if nlive < 2 or not max_seconds > 0:
            raise ValueError(f"need nlive >= 2 and max_seconds > 0, got {nlive} and {max_seconds}")
        self.nlive, self.max_seconds, self.name = int(nlive), float(max_seconds), name

    def unavailable(self) -> str | None:
        import importlib.util

        return None if importlib.util.find_spec("dynesty") else "dynesty is not installed: pip install 'restore-mcmc[compare]'"

    def run(self, problem, key: PRNGKeyArray) -> EvidenceOutput:
        import dynesty

        lower, upper = problem.box
        width = upper - lower
        logdensity = jax.jit(problem.logdensity)
        calls = 0

        def loglikelihood(x: np.ndarray) -> float:
            nonlocal calls
            calls += 1
            return float(logdensity(x))

        def prior_transform(u: np.ndarray) -> np.ndarray:
            return lower + u * width

        seed = np.asarray(jax.random.key_data(key), np.uint32).ravel().tolist()
        capped = False
        with warnings.catch_warnings(record=True) as caught, Stopwatch() as clock:
            warnings.simplefilter("always")
            sampler = dynesty.NestedSampler(
                loglikelihood, prior_transform, problem.dim, nlive=self.nlive, bound="multi", sample="auto",
                rstate=np.random.default_rng(seed),
            )
            deadline = time.perf_counter() + self.max_seconds
            remaining = math.inf
            for state in sampler.sample(dlogz=1e-3 * (self.nlive - 1) + 0.01):  # run_nested's default with live points added
                remaining = float(state.delta_logz)
                if time.perf_counter() > deadline:
                    capped = True
                    break
            for _ in sampler.add_live_points():
                pass
            results = sampler.results
        logz = float(results.logz[-1])
        weights = np.exp(np.asarray(results.logwt, np.float64) - logz)
        samples = np.asarray(results.samples, np.float64)
        mean, second = weighted_moments(samples, weights)
        notes = [f"{int(results.niter)} iterations"]
        if capped:
            notes.append(f"stopped after {self.max_seconds:g} s with dlogz {remaining:.3g} still to go")
        if caught:
            notes.append(short_notes(caught))
        return EvidenceOutput(
            log_z=logz + problem.log_box_volume, log_z_se=float(results.logzerr[-1]), mean=mean, mean_se=None,
            second_moment=second, second_moment_se=None,
            positive=right_well_share(samples, weights) if problem.has_wells else math.nan, positive_se=math.nan,
            evaluations=calls, wall_time=clock.wall, compile_time=clock.compile, status="capped" if capped else "ok",
            notes="; ".join(notes),
        )
