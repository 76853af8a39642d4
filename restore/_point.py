"""A position together with its evaluated log density (and gradient, and the log density's extra output, when needed)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float


class Point(NamedTuple):
    """A position with its log density, and the gradient for gradient-based kernels.

    `logdensity` is `-inf` for a point of zero density, and also for a point where the
    user's log density returned NaN or `+inf` (see `evaluate`). `grad` is `None` when
    no kernel needs it. `aux` is what a log density built with `has_aux` returns beside
    its value (e.g. a light path's colour), `None` otherwise. `geometry` is what a local
    kernel derives at the point besides the gradient and keeps with it, so that it is
    computed once per point (`TorusH2MC`: its proposal's Gaussian), `None` otherwise.
    """

    position: Float[Array, " d"]
    logdensity: Float[Array, ""]
    grad: Float[Array, " d"] | None
    aux: Any = None
    geometry: Any = None


def evaluate(
    logdensity_fn: Callable[[Array], Any], position: Array, with_grad: bool, has_aux: bool = False
) -> tuple[Point, Bool[Array, ""]]:
    """Evaluate the log density (and gradient) at one position, made safe.

    A NaN or `+inf` log density, or a non-finite gradient, is an *invalid* evaluation:
    the point gets log density `-inf` (zero density: a local move there is rejected, a
    tour started there is killed at once with weight zero) and a zero gradient, and the
    returned flag is true so that callers can count it. No NaN travels further.

    The value and gradient are cast to the dtype of `position` (the sampler's dtype), so a
    log density that computes in another precision cannot change the dtypes of a state.

    Arguments:
        logdensity_fn: log density of one point of shape `(d,)`, returning a scalar, or
            with `has_aux` a pair `(scalar, aux)` (aux any pytree of arrays, zeroed at an
            invalid evaluation).
        position: the point.
        with_grad: also compute the gradient (one `value_and_grad` call).
        has_aux: the log density returns `(value, aux)`, as in `jax.value_and_grad`.

    Returns:
        The evaluated `Point` and a boolean flag that is true when the evaluation was invalid.
    """
    dtype = position.dtype
    aux = None
    if with_grad:
        value, grad = jax.value_and_grad(logdensity_fn, has_aux=has_aux)(position)
        logp, aux = value if has_aux else (value, None)
        logp, grad = jnp.asarray(logp).astype(dtype), grad.astype(dtype)
        bad = jnp.isnan(logp) | (logp == jnp.inf) | ~jnp.all(jnp.isfinite(grad))
        bad = bad & ~(logp == -jnp.inf)
        grad = jnp.where(jnp.isfinite(logp) & ~bad, grad, jnp.zeros_like(grad))
    else:
        value = logdensity_fn(position)
        logp, aux = value if has_aux else (value, None)
        logp = jnp.asarray(logp).astype(dtype)
        bad = jnp.isnan(logp) | (logp == jnp.inf)
        grad = None
    logp = jnp.where(bad, -jnp.inf, logp)
    if aux is not None:
        aux = jax.tree.map(lambda a: jnp.where(bad, jnp.zeros_like(a), a), aux)
    return Point(position, logp, grad, aux), bad
