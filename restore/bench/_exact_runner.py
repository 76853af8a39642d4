"""The ideal sampler: exact independent draws, one per evaluation. It gives the error floor of a budget."""

from __future__ import annotations

import jax
import numpy as np
from jaxtyping import PRNGKeyArray

from ._runner import Budget, Runner, RunOutput
from ._timing import Stopwatch


class ExactRunner(Runner):
    """Exact draws of the target (`target.sample`), as many as the evaluation budget.

    Not a competitor: it shows the error an ideal sampler would make with the same
    number of draws, and checks the metrics (its errors must be near zero). At most
    `max_draws` draws are made. Only evaluation budgets apply.
    """

    name, family, time_budget = "exact", "exact", False

    def __init__(self, max_draws: int = 2_000_000, block: int = 16384):
        super().__init__()
        self.max_draws, self.block = int(max_draws), int(block)

    def run(self, problem, start, key: PRNGKeyArray, budget: Budget) -> RunOutput:
        n = int(min(max(round(self.evaluations_for(problem, budget)), 2), self.max_draws))
        with Stopwatch() as clock:
            # Fixed-size blocks: one compilation per problem whatever the budget.
            blocks = [problem.target.sample(jax.random.fold_in(key, i), self.block) for i in range(-(-n // self.block))]
            x = np.concatenate([np.asarray(b, np.float64) for b in blocks])[:n]
            modes = problem.mode_counts(x) / n if problem.multimodal else None
        return RunOutput(
            evaluations=n, wall_time=clock.wall, compile_time=clock.compile, mode_weights=modes,
            mean=x.mean(0), second_moment=(x**2).mean(0), draws=x, draw_weights=None, ess=float(n),
        )
