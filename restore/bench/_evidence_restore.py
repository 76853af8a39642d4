"""Restore in the evidence benchmark: the hand-built recipe, and the one-call `restore.autosample`."""

from __future__ import annotations

import math
import warnings
from typing import Any

import jax
import numpy as np
from jaxtyping import PRNGKeyArray

from ._evidence_runner import CountedDensity, EvidenceOutput, EvidenceRunner
from ._restore_runners import short_notes
from ._timing import Stopwatch


def _estimate(result, name: str):
    """`result.estimate(name)` as float64 arrays `(value, standard_error)`, or `(None, None)` if it cannot be formed."""
    try:
        est = result.estimate(name)
    except (ValueError, KeyError):
        return None, None
    return np.asarray(est.value, np.float64), np.asarray(est.standard_error, np.float64)


def read_result(result, problem, evaluations: int, clock: Stopwatch, caught) -> EvidenceOutput:
    """An `EvidenceOutput` from a Restore result: `log Z` from the tours with its tail shape
    `k_hat` and reliability, estimates with standard errors."""
    log_z = result.normalising_constant()
    mean, mean_se = _estimate(result, "x")
    second, second_se = _estimate(result, "x**2")
    positive, positive_se = _estimate(result, "positive") if problem.has_wells else (None, None)
    return EvidenceOutput(
        log_z=float(log_z.value), log_z_se=float(log_z.standard_error), mean=mean, mean_se=mean_se,
        second_moment=second, second_moment_se=second_se,
        positive=math.nan if positive is None else float(positive), positive_se=math.nan if positive_se is None else float(positive_se),
        evaluations=int(evaluations), wall_time=clock.wall, compile_time=clock.compile,
        k_hat=float(log_z.k_hat), reliable=bool(log_z.reliable),
        notes=short_notes(caught),
    )


class LaplaceRestoreRunner(EvidenceRunner):
    """Jump Restore with a hand-built regeneration: a Laplace mixture from uniform starts, a random walk.

    `num_starts` starts uniform in the problem's box; `laplace_mixture(..., tails="student_t",
    df=5)` at the modes found from them; `RandomWalk(2.38 / sqrt(d))`; `tour_length`; `lanes`
    lanes of `steps` steps. Evaluations: those of the mode finding (counted in a separate,
    untimed run of the same deterministic optimisation), the pilot that turns the tour
    length into a rate, each lane's starting point and every lane step, including the steps
    that finish the tours still open at the end. Where the target has no mode (the funnel),
    `laplace_mixture` raises and the suite records the failure.
    """

    family = "restore"

    def __init__(self, lanes: int = 1024, steps: int = 1000, num_starts: int = 256, tour_length: float = 10.0, name: str = "restore-laplace"):
        if lanes < 2 or steps < 2 or num_starts < 1 or not tour_length > 0:
            raise ValueError(f"need lanes >= 2, steps >= 2, num_starts >= 1 and tour_length > 0; got {lanes}, {steps}, {num_starts}, {tour_length}")
        self.lanes, self.steps, self.num_starts, self.tour_length, self.name = int(lanes), int(steps), int(num_starts), float(tour_length), name

    def run(self, problem, key: PRNGKeyArray) -> EvidenceOutput:
        from .. import JumpRestore, SaveDraws, regeneration, sample
        from ..local import RandomWalk

        k_starts, k_run = jax.random.split(key)
        starts = problem.uniform_points(k_starts, self.num_starts)
        # The mode finding is deterministic: a counted run (untimed, its callbacks are slow) gives its evaluations.
        counted = CountedDensity(problem.logdensity)
        regeneration.laplace_mixture(counted, starts, tails="student_t", df=5.0)
        with warnings.catch_warnings(record=True) as caught, Stopwatch() as clock:
            warnings.simplefilter("always")
            nu = regeneration.laplace_mixture(problem.logdensity, starts, tails="student_t", df=5.0)
            sampler = JumpRestore(problem.logdensity, RandomWalk(2.38 / math.sqrt(problem.dim)), nu, tour_length=self.tour_length)
            result = sample(sampler, k_run, num_lanes=self.lanes, num_steps=self.steps, observables=problem.observables, save=SaveDraws(self.lanes), progress=False)
        lanes = self.lanes * (1 + result.num_steps + result.finishing_steps)  # each lane's start, then one per step
        out = read_result(result, problem, counted.count + result.pilot.num_draws + lanes, clock, caught)
        return out._replace(notes="; ".join(n for n in (f"{len(nu.components)} modes", out.notes) if n))


class AutosampleRunner(EvidenceRunner):
    """`restore.autosample` given the problem's box: Restore's one-call path, every stage counted by itself."""

    family = "restore"

    def __init__(self, lanes: int = 1024, steps: int = 1000, max_stages: int | None = None, name: str = "restore-autosample"):
        if lanes < 4 or steps < 2 or (max_stages is not None and max_stages < 1):
            raise ValueError(f"need lanes >= 4, steps >= 2 and max_stages >= 1 (or None: autosample's default), got {lanes}, {steps} and {max_stages}")
        self.lanes, self.steps, self.name = int(lanes), int(steps), name
        self.max_stages = None if max_stages is None else int(max_stages)

    def run(self, problem, key: PRNGKeyArray) -> EvidenceOutput:
        import restore

        lower, upper = problem.box
        stages: dict[str, Any] = {} if self.max_stages is None else {"max_stages": self.max_stages}
        with warnings.catch_warnings(record=True) as caught, Stopwatch() as clock:
            warnings.simplefilter("always")
            result = restore.autosample(
                problem.logdensity, key, box=(lower, upper), num_lanes=self.lanes, num_steps=self.steps,
                observables=problem.observables, progress=False, **stages,
            )
        return read_result(result, problem, int(result.evaluations), clock, caught)
