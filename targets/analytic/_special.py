"""Special functions and random draws the targets need and `jax` lacks or compiles slowly."""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp
from jax.scipy.special import betainc, ndtri
from jaxtyping import Array, ArrayLike, Float, Int, PRNGKeyArray


def student_t_cdf(t: ArrayLike, df: ArrayLike) -> Float[Array, ...]:
    """CDF of the standard univariate Student-t distribution with `df` degrees of freedom.

    Uses the regularised incomplete beta function, evaluated at whichever of
    `df / (df + t^2)` and `t^2 / (df + t^2)` is smaller, so that both the centre
    and the tails are accurate.

    Arguments:
        t: where to evaluate the CDF (broadcasts against `df`).
        df: degrees of freedom, positive.
    """
    t = jnp.asarray(t)
    df = jnp.asarray(df)
    t2 = t * t
    denom = df + t2
    # P(T > |t|) = I_{df / (df + t^2)}(df / 2, 1 / 2) / 2 = (1 - I_{t^2 / (df + t^2)}(1 / 2, df / 2)) / 2.
    # One betainc call on whichever argument is smaller (the tail form for large |t|).
    use_tail = t2 > df
    x = jnp.where(use_tail, df / denom, t2 / denom)
    a = jnp.where(use_tail, 0.5 * df, 0.5)
    b = jnp.where(use_tail, 0.5, 0.5 * df)
    reg = betainc(a, b, x)
    upper = jnp.where(use_tail, 0.5 * reg, 0.5 - 0.5 * reg)
    return jnp.where(t > 0, 1.0 - upper, upper)


def safe_norm(x: Float[Array, " d"]) -> Float[Array, ""]:
    """Euclidean norm of one vector, without overflow and with zero gradient at the origin.

    Dividing by `max |x_i|` first keeps the squares finite for huge inputs; the
    double `where` keeps the gradient at `x = 0` finite (zero) instead of NaN.
    """
    big = jnp.max(jnp.abs(x))
    positive = big > 0
    safe_big = jnp.where(positive, big, 1.0)
    scaled = x / safe_big
    sum_sq = jnp.where(positive, jnp.sum(scaled * scaled), 1.0)
    return jnp.where(positive, safe_big * jnp.sqrt(sum_sq), 0.0)


def standard_normal(key: PRNGKeyArray, shape: tuple[int, ...], dtype: Any = None) -> Array:
    """`jax.random.normal(key, shape)`, drawn as a flat vector and reshaped.

    Same distribution; multi-dimensional shapes otherwise make XLA compile the
    random bit generator several times slower on CPU.
    """
    if dtype is None:
        dtype = jnp.result_type(float)
    return jax.random.normal(key, (math.prod(shape),), dtype).reshape(shape)


def categorical(key: PRNGKeyArray, weights: Float[Array, " k"], n: int) -> Int[Array, " n"]:
    """`n` exact draws of an index `k` with probability `weights[k]` (normalised weights).

    Inverse-CDF sampling: one uniform per draw, no `(n, k)` intermediate.
    """
    cdf = jnp.cumsum(weights)
    u = jax.random.uniform(key, (n,), weights.dtype) * cdf[-1]
    idx = jnp.searchsorted(cdf, u, side="right")
    return jnp.minimum(idx, weights.shape[0] - 1)


def log_gamma_variates(key: PRNGKeyArray, alpha: Float[Array, " n"]) -> Float[Array, " n"]:
    """Exact draws of `log G` with `G ~ Gamma(alpha_i, 1)` independently per entry.

    Marsaglia and Tsang's rejection sampler (a transformed normal proposal, accepting
    about 95% or more of proposals for `alpha >= 1`), vectorised: every entry redraws in
    a `jax.lax.while_loop` until it has accepted. For `alpha < 1` it draws
    `Gamma(alpha + 1)` and multiplies by `U^(1 / alpha)`, in log space so that tiny
    values do not underflow. (Much cheaper to compile than `jax.random.loggamma`.)

    Arguments:
        key: a JAX PRNG key.
        alpha: positive shape parameters, one per draw.
    """
    alpha = jnp.asarray(alpha)
    n = alpha.shape[0]
    boost = alpha < 1
    shape = jnp.where(boost, alpha + 1.0, alpha)
    d = shape - 1.0 / 3.0
    c = 1.0 / jnp.sqrt(9.0 * d)

    def redraw(state: tuple[Array, Array, Array]) -> tuple[Array, Array, Array]:
        key, log_g, accepted = state
        key, sub = jax.random.split(key)
        # One uniform array per round: the normal proposal (by inversion), the
        # acceptance uniform and the boost uniform; 1 - u lies in (0, 1], so logs are finite.
        u = jax.random.uniform(sub, (3, n), alpha.dtype)
        x = ndtri(u[0])
        base = 1.0 + c * x
        positive = base > 0
        log_v = 3.0 * jnp.log(jnp.where(positive, base, 1.0))
        v = jnp.exp(log_v)
        ok = positive & (jnp.log1p(-u[1]) < 0.5 * x * x + d - d * v + d * log_v)
        proposal = jnp.log(d) + log_v + jnp.where(boost, jnp.log1p(-u[2]) / alpha, 0.0)
        log_g = jnp.where(accepted, log_g, proposal)
        return key, log_g, accepted | ok

    init = (key, jnp.zeros((n,), alpha.dtype), jnp.zeros((n,), bool))
    return jax.lax.while_loop(lambda state: ~jnp.all(state[2]), redraw, init)[1]
