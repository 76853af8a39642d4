"""The one interface every sampler runner has: a budget in, estimates and costs out."""

from __future__ import annotations

import abc
import math
from typing import Literal, NamedTuple

import numpy as np
from jaxtyping import PRNGKeyArray


class Budget(NamedTuple):
    """How much work a run may do: a number of target evaluations, or seconds of run time.

    An evaluation is one log density (with its gradient, for kernels that need one);
    an HMC step of `L` leapfrog steps costs `L`. Time budgets exclude compilation.
    """

    kind: Literal["evaluations", "time"]
    amount: float
    fraction: float = 1.0  # the budget point, as a fraction of the full budget (for the curves)

    @classmethod
    def evaluations(cls, n: float, fraction: float = 1.0) -> Budget:
        if not n >= 1:
            raise ValueError(f"an evaluation budget must be at least 1, got {n!r}")
        return cls("evaluations", float(n), fraction)

    @classmethod
    def seconds(cls, s: float, fraction: float = 1.0) -> Budget:
        if not (s > 0 and math.isfinite(s)):
            raise ValueError(f"a time budget must be positive and finite, got {s!r}")
        return cls("time", float(s), fraction)


class RunOutput(NamedTuple):
    """Estimates of the metrics' quantities and what the run cost."""

    evaluations: int  # target evaluations actually made
    wall_time: float  # seconds, compilation included
    compile_time: float  # seconds of tracing and XLA compilation inside the run
    mode_weights: np.ndarray | None  # (k,) estimated share of each mode, or None
    mean: np.ndarray  # (d,)
    second_moment: np.ndarray  # (d,) estimates of E[x_i^2]
    draws: np.ndarray | None  # (n, d) draws for the distributional distance
    draw_weights: np.ndarray | None  # (n,) their weights (None: equal)
    ess: float = math.nan  # the sampler's own effective sample size (median over coordinates)
    notes: str = ""  # warnings raised during the run, shortened

    @property
    def run_time(self) -> float:
        """Wall time minus compilation."""
        return max(self.wall_time - self.compile_time, 0.0)


class Runner(abc.ABC):
    """A configured sampler that can be run on any problem under any budget.

    Attributes:
        name: short unique name, e.g. `"restore-rw"`, `"emcee-stretch-64"`.
        family: `"restore"`, `"mh"`, `"chains"`, `"emcee"`, `"blackjax"` or `"exact"`.
        matches: name of the jump-Restore runner whose measured evaluations and wall
            time this runner is given (`None` for jump Restore itself).
        kernel: the local kernel it shares with jump Restore (`"rw"`, `"mala"`, `"hmc"`), if any.
        time_budget: whether the suite also runs it at jump Restore's wall time.
    """

    name: str
    family: str
    matches: str | None = "restore-rw"
    kernel: str | None = None
    time_budget: bool = True

    def __init__(self) -> None:
        self._rates: dict[str, float] = {}  # problem -> evaluations per second (run time), measured

    def supports(self, problem) -> bool:
        """Whether this runner can run `problem` (e.g. emcee needs at least 2d walkers)."""
        return True

    @abc.abstractmethod
    def run(self, problem, start, key: PRNGKeyArray, budget: Budget) -> RunOutput:
        """Run on `problem` from the starting information `start` within `budget`."""

    def _record_rate(self, problem, output: RunOutput) -> None:
        if output.run_time > 0:
            self._rates[problem.name] = output.evaluations / output.run_time

    def evaluations_for(self, problem, budget: Budget) -> float:
        """Evaluations to make: the budget itself, or seconds times this runner's measured rate.

        A time budget is turned into evaluations with the rate this runner reached (run
        time, compilation excluded) in its last evaluation-budget run on the same problem;
        the actual wall time is measured and reported, so the match can be checked.
        """
        if budget.kind == "evaluations":
            return budget.amount
        rate = self._rates.get(problem.name)
        if rate is None:
            raise ValueError(f"{self.name}: run an evaluation budget on {problem.name} first, to measure its rate")
        return budget.amount * rate


def moments_from_sums(sum_x: np.ndarray, sum_x2: np.ndarray, total: float) -> tuple[np.ndarray, np.ndarray]:
    """Means and second moments from running sums over `total` (weighted) draws."""
    if not total > 0:
        nan = np.full(np.shape(sum_x), np.nan)
        return nan, nan
    return np.asarray(sum_x, np.float64) / total, np.asarray(sum_x2, np.float64) / total
