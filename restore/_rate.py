"""Killing-rate arithmetic in log space, and the pilot that turns a tour length into a rate."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, PRNGKeyArray

from ._compile import jit


def log_kill_rate(log_rate: Array, log_regeneration: Array, logdensity: Array) -> Array:
    """`log gamma = log c_tilde + log u - log p`, with the edge cases made explicit.

    Zero target density gives `+inf` (kill at once), whatever `u` is; zero regeneration
    density where the target is positive gives `-inf` (never killed there).
    """
    value = log_rate + log_regeneration - logdensity
    value = jnp.where(logdensity == -jnp.inf, jnp.inf, value)
    return jnp.where(jnp.isnan(value), -jnp.inf, value)


def kill_log_probability(log_gamma: Array, log_local_rate: Array) -> Array:
    """`log(gamma / (r + gamma))`, exact for `gamma` in `[0, inf]` (never NaN)."""
    return jax.nn.log_sigmoid(log_gamma - log_local_rate)


def log_total_rate(log_gamma: Array, log_local_rate: Array) -> Array:
    """`log(r + gamma)`; the mean holding time is `exp(-log_total_rate)`."""
    return jnp.logaddexp(log_local_rate, log_gamma)


class JumpEvent(NamedTuple):
    """The next event of a lane that moves locally at rate `r` and is killed at rate `gamma`.

    Attributes:
        killed: the event is a kill (probability `gamma / (r + gamma)`), else a local move.
        holding_time: the time held before it (exponential, mean `1 / (r + gamma)`).
        expected_holding_time: `1 / (r + gamma)`, the Rao-Blackwellised weight of the state held.
    """

    killed: Array
    holding_time: Array
    expected_holding_time: Array


def jump_event(log_uniform: Array, exponential: Array, log_gamma: Array, log_local_rate: Array) -> JumpEvent:
    """The kill-or-move event of a jump-Restore lane, from its random numbers: `log_uniform`
    (the log of a uniform draw) decides a kill, `exponential` (a standard exponential draw)
    sets the holding time. The one place the event is written: the step (`Restore`) and the
    speculative steps that finish tours both use it, each drawing its numbers its own way."""
    mean_hold = jnp.exp(-log_total_rate(log_gamma, log_local_rate))
    killed = log_uniform < kill_log_probability(log_gamma, log_local_rate)
    return JumpEvent(killed, exponential * mean_hold, mean_hold)


class PilotEstimate(NamedTuple):
    """Importance-sampling estimate of `log Z` from draws of the regeneration distribution.

    Attributes:
        log_z: `log` of the mean of `p(y) / u(y)`, `y ~ nu`.
        relative_standard_error: standard error of `Z_hat / Z` (delta method).
        effective_sample_size: `(sum w)^2 / sum w^2` of the importance weights.
        num_draws: number of pilot draws.
        zero_fraction: share of draws where the target density is zero.
    """

    log_z: float
    relative_standard_error: float
    effective_sample_size: float
    num_draws: int
    zero_fraction: float


@jit(filtered=True, once=True)
def _pilot_terms(logdensity_fn, regeneration, key, num_draws: int):
    """`log p` and `log u` at `num_draws` draws of the regeneration, drawn and evaluated in one
    compiled program (per log density, regeneration structure and size; reused by later
    calibrations), where drawing outside it compiled every operation of the draw on its own.
    It draws on JAX's keys, not `unrolled_keys` (the same bits): the pilot runs once, and the
    unrolled key code compiles more slowly for mixtures."""
    draws = regeneration.sample(key, (num_draws,))
    log_p = jax.vmap(logdensity_fn)(draws)
    log_u = jax.vmap(regeneration.log_prob)(draws)
    return log_p, log_u


def pilot_log_z(
    key: PRNGKeyArray,
    logdensity_fn: Callable[[Array], Array],
    regeneration,
    num_draws: int,
) -> PilotEstimate:
    """Estimate `log Z` by importance sampling from the regeneration distribution."""
    log_p, log_u = _pilot_terms(logdensity_fn, regeneration, key, num_draws)
    log_p, log_u = np.asarray(log_p, dtype=np.float64), np.asarray(log_u, dtype=np.float64)
    invalid = np.isnan(log_p) | (log_p == np.inf)  # treated as zero density, as in the run
    log_w = np.where(invalid, -np.inf, log_p - log_u)
    log_w = np.where(np.isnan(log_w), -np.inf, log_w)
    finite = np.isfinite(log_w)
    if not finite.any():
        detail = f" (the log density was NaN or +inf at {int(invalid.sum())} of them)" if invalid.any() else ""
        raise ValueError(
            f"none of {num_draws} draws of the regeneration distribution has positive target "
            f"density{detail}: the regeneration distribution misses the target's support"
        )
    top = log_w[finite].max()
    w = np.where(finite, np.exp(log_w - top), 0.0)
    mean = w.mean()
    rel_se = float(w.std(ddof=1) / (mean * math.sqrt(num_draws))) if num_draws > 1 else math.inf
    return PilotEstimate(
        log_z=float(top + math.log(mean)),
        relative_standard_error=rel_se,
        effective_sample_size=float(w.sum() ** 2 / (w**2).sum()),
        num_draws=num_draws,
        zero_fraction=float(1.0 - finite.mean()),
    )


def log_total_kill_rate(log_transfer_rate: Array, adjoint_ratio: Array) -> tuple[Array, Array]:
    """`log gamma` for `gamma = a + exp(log_transfer_rate)` with a signed adjoint term `a = L* p / p`.

    Returns `log max(gamma, 0)` and a flag that is true when `gamma < 0`: the constant
    `c_tilde` is then too small for these dynamics there (the caller counts it; the
    rate used is zero). Stable in log space when `exp(log_transfer_rate)` would overflow.
    """
    big = log_transfer_rate
    positive = jnp.logaddexp(log_transfer_rate, jnp.log(jnp.maximum(adjoint_ratio, 0.0)))
    # a < 0: gamma = e^l (1 - |a| e^-l)
    x = jnp.log(jnp.maximum(-adjoint_ratio, 0.0)) - big
    negative_side = big + jnp.log1p(-jnp.exp(jnp.minimum(x, 0.0)))
    log_gamma = jnp.where(adjoint_ratio >= 0, positive, jnp.where(x < 0, negative_side, -jnp.inf))
    return log_gamma, (adjoint_ratio < 0) & (x > 0)
