"""BlackJAX adaptive tempered SMC with HMC moves, from a uniform prior on the problem's box."""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, PRNGKeyArray

from ._evidence_runner import EvidenceOutput, EvidenceRunner, right_well_share, weighted_moments
from ._timing import Stopwatch


class _Loop(NamedTuple):
    key: Array
    state: Any  # blackjax's TemperedSMCState (blackjax has no type information)
    log_z: Array
    temperatures: Array
    step_size: Array
    inverse_mass: Array
    acceptance: Array


class TemperedSMCRunner(EvidenceRunner):
    """`blackjax.adaptive_tempered_smc` from the uniform prior on the box, HMC moves tuned from the particles.

    The path `prior(x) L(x)^beta` runs from the uniform prior on the box (`beta = 0`) to
    `prior(x) L(x) ∝ p(x)` on the box (`beta = 1`), with `L = p / prior`; the next `beta`
    keeps the effective sample size at `target_ess` of the particles, and `log Z` is the
    sum of the log likelihood increments (the prior is normalised, so nothing is added).
    Every temperature moves each particle with `mcmc_steps` HMC steps of
    `problem.hmc_steps` leapfrog steps, with the usual particle-based tuning between
    temperatures: the inverse mass matrix is the particles' diagonal covariance (their full
    covariance with `dense=True`, for correlated targets), and the step size (in those
    whitened units) is multiplied by `exp(2 (acceptance - 0.65))`.

    Evaluations: per temperature and particle, one for the ESS solve, one for the HMC
    state at the start of the moves, `mcmc_steps * hmc_steps` leapfrog gradients and one
    for the incremental weight. Runs that hit `max_temperatures` before `beta = 1` are
    marked `capped`. One run gives no standard error of `log Z` or of the moments.
    """

    family = "smc"

    def __init__(
        self, particles: int = 4096, mcmc_steps: int = 5, target_ess: float = 0.5, max_temperatures: int = 500,
        dense: bool = False, name: str = "smc-hmc",
    ):
        if particles < 2 or mcmc_steps < 1 or not 0 < target_ess < 1 or max_temperatures < 1:
            raise ValueError(
                f"need particles >= 2, mcmc_steps >= 1, 0 < target_ess < 1 and max_temperatures >= 1; "
                f"got {particles}, {mcmc_steps}, {target_ess}, {max_temperatures}"
            )
        self.particles, self.mcmc_steps, self.target_ess = int(particles), int(mcmc_steps), float(target_ess)
        self.max_temperatures, self.dense, self.name = int(max_temperatures), bool(dense), name
        self._programs: dict[str, object] = {}

    def unavailable(self) -> str | None:
        import importlib.util

        return None if importlib.util.find_spec("blackjax") else "BlackJAX is not installed: pip install 'restore-mcmc[compare]'"

    def evaluations_per_temperature(self, problem) -> int:
        """Log density evaluations (gradients included) of one tempering step over all particles."""
        return self.particles * (self.mcmc_steps * problem.hmc_steps + 3)

    def _program(self, problem):
        """The jitted tempering loop for `problem`, built once."""
        if problem.name in self._programs:
            return self._programs[problem.name]
        import blackjax
        from blackjax.smc import resampling
        from blackjax.smc.adaptive_tempered import build_kernel
        from blackjax.smc.tempered import init as smc_init

        lower, upper = (jnp.asarray(b) for b in problem.box)
        log_volume = problem.log_box_volume
        logdensity = problem.logdensity

        def logprior(x):
            inside = jnp.all((x >= lower) & (x <= upper))
            return jnp.where(inside, -log_volume, -jnp.inf)

        def loglikelihood(x):
            return logdensity(x) + log_volume  # log p - log prior inside the box

        kernel = build_kernel(
            logprior, loglikelihood, blackjax.hmc.build_kernel(), blackjax.hmc.init, resampling.systematic, self.target_ess
        )
        steps, mcmc_steps, cap, dense = problem.hmc_steps, self.mcmc_steps, self.max_temperatures, self.dense

        def inverse_mass(particles, weights):
            """The particles' weighted variances, or with `dense` their covariance (a small ridge keeps it positive)."""
            mean = weights @ particles
            centred = particles - mean
            if not dense:
                return jnp.maximum(weights @ centred**2, 1e-12)
            return (centred.T * weights) @ centred + 1e-12 * jnp.eye(particles.shape[1])

        @jax.jit
        def loop(key, particles):
            d = particles.shape[1]

            def body(c: _Loop) -> _Loop:
                key, sub = jax.random.split(c.key)
                params = {
                    "step_size": c.step_size[None],
                    "inverse_mass_matrix": c.inverse_mass[None],
                    "num_integration_steps": jnp.full((1,), steps, jnp.int32),
                }
                state, info = kernel(sub, c.state, mcmc_steps, params)
                acceptance = jnp.mean(info.update_info.acceptance_rate)
                return _Loop(
                    key, state, c.log_z + info.log_likelihood_increment, c.temperatures + 1,
                    c.step_size * jnp.exp(2.0 * (acceptance - 0.65)), inverse_mass(state.particles, state.weights), acceptance,
                )

            def going(c: _Loop) -> Array:
                return (c.state.tempering_param < 1.0) & (c.temperatures < cap)

            uniform = jnp.full(particles.shape[:1], 1.0 / particles.shape[0], particles.dtype)
            start = inverse_mass(particles, uniform) if dense else jnp.var(particles, axis=0)
            init = _Loop(
                key, smc_init(particles), jnp.zeros(()), jnp.zeros((), jnp.int32), jnp.asarray(0.5 * d**-0.25), start, jnp.zeros(()),
            )
            return jax.lax.while_loop(going, body, init)

        self._programs[problem.name] = loop
        return loop

    def run(self, problem, key: PRNGKeyArray) -> EvidenceOutput:
        k_prior, k_run = jax.random.split(key)
        with Stopwatch() as clock:
            loop = self._program(problem)
            particles = problem.uniform_points(k_prior, self.particles)
            out = jax.block_until_ready(loop(k_run, particles))
        temperatures = int(out.temperatures)
        beta = float(out.state.tempering_param)
        x = np.asarray(out.state.particles, np.float64)
        w = np.asarray(out.state.weights, np.float64)
        mean, second = weighted_moments(x, w)
        notes = [f"{temperatures} temperatures", f"last acceptance {float(out.acceptance):.2f}"]
        if beta < 1.0:
            notes.append(f"stopped at beta = {beta:.3g} after {self.max_temperatures} temperatures")
        return EvidenceOutput(
            log_z=float(out.log_z), log_z_se=math.nan, mean=mean, mean_se=None, second_moment=second, second_moment_se=None,
            positive=right_well_share(x, w) if problem.has_wells else math.nan, positive_se=math.nan,
            evaluations=temperatures * self.evaluations_per_temperature(problem), wall_time=clock.wall, compile_time=clock.compile,
            status="ok" if beta >= 1.0 else "capped", notes="; ".join(notes),
        )
