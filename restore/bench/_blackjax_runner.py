"""BlackJAX random-walk Metropolis and NUTS: many chains, vmapped, in one jitted loop."""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import PRNGKeyArray

from ._runner import Budget, Runner, RunOutput, moments_from_sums
from ._timing import Stopwatch

ALGORITHMS = ("rmh", "nuts")


class _Loop(NamedTuple):
    step: int
    states: object
    evaluations: jnp.ndarray
    sums: jnp.ndarray
    num_summed: jnp.ndarray
    kept: jnp.ndarray
    num_kept: jnp.ndarray


class BlackJAXRunner(Runner):
    """Parallel BlackJAX chains started at draws of the regeneration distribution.

    `"rmh"`: `normal_random_walk` with jump Restore's random-walk scale, first `burn_in`
    share of the steps discarded. `"nuts"`: per-chain `window_adaptation` for
    `warmup_steps` steps (its gradient evaluations count towards the budget; it is the
    burn-in), then NUTS until the evaluation budget is spent. Chains run in lockstep
    under `vmap`, so a NUTS step costs as much wall time as the longest trajectory among
    the chains, while the evaluations counted are the leapfrog steps actually taken.
    ESS: BlackJAX's multi-chain estimate on `kept_per_chain` thinned draws per chain.
    """

    family = "blackjax"

    def __init__(self, algorithm: str, chains: int, burn_in: float = 0.5, warmup_steps: int = 200, kept_per_chain: int = 32):
        super().__init__()
        if algorithm not in ALGORITHMS:
            raise ValueError(f"algorithm must be one of {ALGORITHMS}, got {algorithm!r}")
        if chains < 2 or warmup_steps < 10 or kept_per_chain < 4:
            raise ValueError("need chains >= 2, warmup_steps >= 10 and kept_per_chain >= 4")
        self.algorithm, self.chains, self.burn_in = algorithm, int(chains), float(burn_in)
        self.warmup_steps, self.kept_per_chain = int(warmup_steps), int(kept_per_chain)
        self.name = f"blackjax-{algorithm}"
        self._programs: dict[str, tuple] = {}

    def _compiled(self, problem):
        """Jitted warm-up and sampling loops for `problem`, built once (sizes are traced, not static)."""
        if problem.name in self._programs:
            return self._programs[problem.name]
        import blackjax

        logdensity = problem.logdensity
        functions = tuple(problem.observables.values())
        observe = lambda x: jnp.concatenate([jnp.ravel(fn(x)) for fn in functions])  # noqa: E731

        if self.algorithm == "nuts":
            adaptation = blackjax.window_adaptation(blackjax.nuts, logdensity)

            def warm_one(key, x):
                (state, params), info = adaptation.run(key, x, num_steps=self.warmup_steps)
                return state, params, jnp.sum(info.info.num_integration_steps)

            def step(key, state, params):
                state, info = blackjax.nuts(logdensity, **params).step(key, state)
                return state, info.num_integration_steps

            warmup = jax.jit(jax.vmap(warm_one))
        else:
            rmh = blackjax.additive_step_random_walk.normal_random_walk(logdensity, jnp.full((problem.dim,), problem.rw_scale))

            def step(key, state, params):
                state, _ = rmh.step(key, state)
                return state, jnp.ones((), jnp.int32)

            warmup = jax.jit(jax.vmap(rmh.init))

        kept = self.kept_per_chain

        @jax.jit
        def loop(key, states, params, max_evaluations, burn, thin):
            size = observe(jnp.zeros(problem.dim)).size
            chains = jax.tree.leaves(states)[0].shape[0]

            def body(c: _Loop) -> _Loop:
                keys = jax.random.split(jax.random.fold_in(key, c.step), chains)
                states, evals = jax.vmap(step)(keys, c.states, params)
                post = c.step >= burn
                values = jax.vmap(observe)(states.position).sum(0)
                slot = (c.step - burn) // thin
                store = post & ((c.step - burn) % thin == 0) & (slot < kept)
                kept_draws = jnp.where(store, c.kept.at[jnp.minimum(slot, kept - 1)].set(states.position), c.kept)
                return _Loop(
                    c.step + 1, states, c.evaluations + jnp.sum(evals),
                    c.sums + jnp.where(post, values, 0.0), c.num_summed + jnp.where(post, chains, 0),
                    kept_draws, c.num_kept + store,
                )

            init = _Loop(
                jnp.zeros((), jnp.int32), states, jnp.zeros((), jnp.int64), jnp.zeros(size), jnp.zeros((), jnp.int64),
                jnp.zeros((kept, chains, problem.dim)), jnp.zeros((), jnp.int32),
            )
            return jax.lax.while_loop(lambda c: c.evaluations < max_evaluations, body, init)

        self._programs[problem.name] = (warmup, loop)
        return warmup, loop

    def run(self, problem, start, key: PRNGKeyArray, budget: Budget) -> RunOutput:
        budget_evals = self.evaluations_for(problem, budget)
        k_init, k_warm, k_run = jax.random.split(key, 3)
        positions = jnp.asarray(start.initial_points(k_init, self.chains))
        C = self.chains
        with Stopwatch() as clock:
            warmup, loop = self._compiled(problem)
            if self.algorithm == "nuts":
                states, params, warm_evals = warmup(jax.random.split(k_warm, C), positions)
                spent = int(jnp.sum(warm_evals)) + C
                per_step = max(spent / (C * self.warmup_steps), 1.0)
                burn = 0
            else:
                states, params, spent, per_step = warmup(positions), {}, C, 1.0
                burn = int(self.burn_in * budget_evals / C)
            remaining = max(budget_evals - spent, 1.0)
            expected_steps = remaining / (C * per_step)
            thin = max(1, int((expected_steps - burn) // self.kept_per_chain))
            out = jax.block_until_ready(loop(k_run, states, params, jnp.asarray(remaining), burn, thin))
        n = int(out.num_summed)
        sums = np.asarray(out.sums, np.float64)
        d = problem.dim
        mean, m2 = moments_from_sums(sums[:d], sums[d : 2 * d], n)
        modes = sums[2 * d :] / n if problem.multimodal and n else None
        draws = np.asarray(out.kept[: int(out.num_kept)])  # (kept, chains, d)
        ess = math.nan
        if draws.shape[0] >= 4:
            import blackjax

            ess = float(np.median(np.asarray(blackjax.diagnostics.effective_sample_size(np.swapaxes(draws, 0, 1)))))
        output = RunOutput(
            evaluations=int(spent + int(out.evaluations)), wall_time=clock.wall, compile_time=clock.compile,
            mode_weights=modes, mean=mean, second_moment=m2, draws=draws.reshape(-1, d), draw_weights=None, ess=ess,
            notes="" if n else "budget spent in warm-up",
        )
        if budget.kind == "evaluations":
            self._record_rate(problem, output)
        return output
