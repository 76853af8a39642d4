"""First draws where the target's mass is: short adaptive local chains from broad starts.

A regeneration fitted to a target must start from points in its high-density regions.
Starting points from what the user knows (a box, a scale, a prior) are mostly far from
them in more than a few dimensions, so each start runs a short chain of MALA (random-walk
Metropolis when the log density has no gradient) whose step size adapts on its own
acceptance rate. The chains' later states are the first draws a regeneration is fitted
to. They are not target draws (each chain stays near the mode it fell into, so the
weights of the modes are off): the Restore stages that follow correct that exactly.
No mode is needed, so targets without one (funnels) are fine.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ._compile import jit
from ._threefry import unrolled_keys

#: MALA's and random-walk Metropolis's optimal acceptance rates.
_TARGET_ACCEPTANCE = {True: 0.574, False: 0.234}


class Seeds(NamedTuple):
    """Where the seeding chains went.

    Attributes:
        positions: `(n, d)` the chains' states over the second half of their run.
        chains: `(n,)` which chain each state belongs to (for held-out splits by chain).
        evaluations: log-density evaluations spent (a value-and-gradient counts once).
        uses_gradient: whether the chains were MALA (else random-walk Metropolis).
        acceptance: mean acceptance rate over the second half.
    """

    positions: np.ndarray
    chains: np.ndarray
    evaluations: int
    uses_gradient: bool
    acceptance: float


def has_gradient(logdensity: Callable[[Array], Array], dim: int, dtype) -> bool:
    """Whether `jax.grad(logdensity)` traces (a log density through a callback may not)."""
    try:
        jax.eval_shape(jax.grad(logdensity), jax.ShapeDtypeStruct((dim,), dtype))
    except Exception:  # noqa: BLE001 - any failure to trace means: no gradient
        return False
    return True


def _safe(logdensity, x, use_gradient: bool):
    if use_gradient:
        value, grad = jax.value_and_grad(logdensity)(x)
        grad = jnp.where(jnp.isfinite(grad), grad, 0.0)
    else:
        value, grad = logdensity(x), jnp.zeros_like(x)
    value = jnp.where(jnp.isnan(value) | (value == jnp.inf), -jnp.inf, value)
    return value, grad


@jit(filtered=True)
def _chains(logdensity, starts: Array, key: Array, scales: Array, num_steps: int, keep_every: int, use_gradient: bool):
    target = _TARGET_ACCEPTANCE[use_gradient]
    half = num_steps // 2

    def one(start, key):
        value, grad = _safe(logdensity, start, use_gradient)

        def step(carry, inputs):
            x, value, grad, log_step = carry
            t, key = inputs
            k_noise, k_accept = jax.random.split(key)
            step_size = jnp.exp(log_step) * scales  # proposal standard deviation
            drift = 0.5 * step_size**2 * grad
            y = x + drift + step_size * jax.random.normal(k_noise, x.shape, x.dtype)
            new_value, new_grad = _safe(logdensity, y, use_gradient)
            back = y + 0.5 * step_size**2 * new_grad
            log_q = -0.5 * jnp.sum(((x - back) / step_size) ** 2) + 0.5 * jnp.sum(((y - x - drift) / step_size) ** 2)
            log_ratio = jnp.where(jnp.isfinite(new_value), new_value - value + log_q, -jnp.inf)
            log_ratio = jnp.where(jnp.isfinite(value), log_ratio, jnp.where(jnp.isfinite(new_value), 0.0, -jnp.inf))
            accept_prob = jnp.exp(jnp.minimum(log_ratio, 0.0))
            accept = jax.random.uniform(k_accept, dtype=x.dtype) < accept_prob
            gain = jnp.where(t < half, 1.0 / jnp.sqrt(1.0 + t / 10.0), 0.0)
            log_step = log_step + gain * (accept_prob - target)
            x, value, grad = jax.tree.map(lambda a, b: jnp.where(accept, a, b), (y, new_value, new_grad), (x, value, grad))
            return (x, value, grad, log_step), (x, accept_prob)

        keys = jax.random.split(key, num_steps)
        init = (start, value, grad, jnp.zeros((), start.dtype))
        _, (path, accept) = jax.lax.scan(step, init, (jnp.arange(num_steps, dtype=start.dtype), keys))
        kept = path[half :: keep_every]
        return kept, jnp.mean(accept[half:])

    return jax.vmap(one)(starts, jax.random.split(unrolled_keys(key), starts.shape[0]))  # JAX's bits, a faster loop


def seed_draws(
    logdensity: Callable[[Array], Array],
    starts: Array,
    key: Array,
    *,
    num_steps: int = 200,
    keep: int = 8,
    scales: Array | None = None,
) -> Seeds:
    """Run one adaptive chain from every start and keep `keep` states of each chain's second half.

    Arguments:
        logdensity: log density of one point.
        starts: `(n, d)` starting points.
        key: PRNG key.
        num_steps: steps per chain.
        keep: states kept per chain, evenly spaced over its second half.
        scales: `(d,)` relative proposal scales per coordinate (default: the spread of the
            starts); the chains adapt one overall factor on top.
    """
    starts = jnp.asarray(starts)
    n, d = starts.shape
    if scales is None:  # on the host: eager device operations would each compile a program
        scales = np.std(np.asarray(starts, np.float64), axis=0) + 1e-12
    scales = jnp.asarray(np.asarray(scales, np.float64) / math.sqrt(d), starts.dtype)
    use_gradient = has_gradient(logdensity, d, starts.dtype)
    keep_every = max(1, (num_steps - num_steps // 2) // max(keep, 1))
    kept, acceptance = _chains(logdensity, starts, key, scales, int(num_steps), keep_every, use_gradient)
    kept = np.asarray(kept)
    per_chain = kept.shape[1]
    return Seeds(
        positions=kept.reshape(-1, d),
        chains=np.repeat(np.arange(n), per_chain),
        evaluations=int(n * num_steps),
        uses_gradient=use_gradient,
        acceptance=float(np.mean(np.asarray(acceptance))),
    )
