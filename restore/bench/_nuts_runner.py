"""BlackJAX NUTS with window adaptation, several chains from uniform starts in the problem's box."""

from __future__ import annotations

import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import PRNGKeyArray

from ._evidence_runner import EvidenceOutput, EvidenceRunner, right_well_share
from ._timing import Stopwatch

#: Stan's and ArviZ's rule for trusting a run's summaries (Vehtari et al. 2021): every R-hat below
#: this and every bulk effective sample size above `MIN_ESS`.
MAX_RHAT = 1.01
MIN_ESS = 400.0


class NUTSRunner(EvidenceRunner):
    """`blackjax.window_adaptation(blackjax.nuts, ...)` as its users run it: `chains` chains from
    starts uniform in the box, each `warmup` steps of Stan's window adaptation (step size and a
    dense inverse mass matrix, or a diagonal one with `dense=False`) and `kept` steps kept.

    NUTS gives moments, not `log Z` (NaN in the table). Standard errors of the moments and the
    verdict are the ones its users read: ArviZ's Monte Carlo standard errors over the chains, and
    `reliable` when every R-hat is below 1.01 and every bulk ESS above 400 (where ArviZ is
    installed). Evaluations count the gradients of warm-up and kept steps (each leapfrog step
    is one).
    """

    family = "mcmc"

    def __init__(self, chains: int = 4, warmup: int = 1000, kept: int = 1000, dense: bool = True, name: str = "nuts"):
        if chains < 1 or warmup < 1 or kept < 2:
            raise ValueError(f"need chains >= 1, warmup >= 1 and kept >= 2, got {chains}, {warmup} and {kept}")
        self.chains, self.warmup, self.kept, self.dense, self.name = int(chains), int(warmup), int(kept), bool(dense), name
        self._programs: dict[str, object] = {}

    def unavailable(self) -> str | None:
        import importlib.util

        return None if importlib.util.find_spec("blackjax") else "BlackJAX is not installed: pip install 'restore-mcmc[compare]'"

    def _program(self, problem):
        """The jitted chains for `problem`, built once."""
        if problem.name in self._programs:
            return self._programs[problem.name]
        import blackjax

        logdensity, warmup, kept, dense = problem.logdensity, self.warmup, self.kept, self.dense

        def chain(key, x0):
            key_warm, key_run = jax.random.split(key)
            adaptation = blackjax.window_adaptation(blackjax.nuts, logdensity, is_mass_matrix_diagonal=not dense)
            (state, parameters), warm = adaptation.run(key_warm, x0, num_steps=warmup)
            kernel = blackjax.nuts(logdensity, **parameters)

            def step(state, key):
                state, info = kernel.step(key, state)
                return state, (state.position, info.num_integration_steps)

            _, (positions, steps) = jax.lax.scan(step, state, jax.random.split(key_run, kept))
            return positions, jnp.sum(steps) + jnp.sum(warm.info.num_integration_steps)

        program = jax.jit(jax.vmap(chain))
        self._programs[problem.name] = program
        return program

    def run(self, problem, key: PRNGKeyArray) -> EvidenceOutput:
        key_starts, key_runs = jax.random.split(key)
        with Stopwatch() as clock:
            program = self._program(problem)
            starts = problem.uniform_points(key_starts, self.chains)
            positions, gradients = jax.block_until_ready(program(jax.random.split(key_runs, self.chains), starts))
        x = np.asarray(positions, np.float64)  # (chains, kept, d)
        flat = x.reshape(-1, x.shape[-1])
        mean, second = flat.mean(axis=0), (flat * flat).mean(axis=0)
        mean_se = second_se = None
        reliable, notes = None, []
        summary = _arviz_summary(x)
        if summary is not None:
            mean_se, second_se, rhat, ess = summary
            reliable = bool(np.all(rhat < MAX_RHAT) and np.all(ess > MIN_ESS))
            notes.append(f"largest R-hat {float(np.max(rhat)):.3f}, smallest bulk ESS {float(np.min(ess)):.0f}")
        weights = np.ones(len(flat))
        return EvidenceOutput(
            log_z=math.nan, log_z_se=math.nan, mean=mean, mean_se=mean_se, second_moment=second, second_moment_se=second_se,
            positive=right_well_share(flat, weights) if problem.has_wells else math.nan, positive_se=math.nan,
            evaluations=int(np.sum(np.asarray(gradients))), wall_time=clock.wall, compile_time=clock.compile,
            reliable=reliable, notes="; ".join(notes),
        )


def _arviz_summary(x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """ArviZ's Monte Carlo standard errors of `E[x]` and `E[x^2]`, and the R-hat and bulk ESS of
    `x` (both of `x` and `x^2` for the worst), from chains `(chains, draws, d)`; `None` without ArviZ."""
    try:
        import arviz as az
    except ImportError:
        return None
    data = az.convert_to_dataset({"x": x, "x2": x * x})
    with warnings.catch_warnings(), np.errstate(divide="ignore", invalid="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)  # chains that never moved: R-hat NaN, which fails the rule
        mcse = az.mcse(data, method="mean")
        rhat = az.rhat(data)
        ess = az.ess(data, method="bulk")
    both = lambda ds: np.maximum(np.asarray(ds["x"]), np.asarray(ds["x2"]))  # noqa: E731
    lowest = np.minimum(np.asarray(ess["x"]), np.asarray(ess["x2"]))
    return np.asarray(mcse["x"]), np.asarray(mcse["x2"]), both(rhat), lowest
