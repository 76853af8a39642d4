"""Local moves on the torus: Metropolis with a small step, and MALA; the Metropolis test.

A local kernel is split at its one evaluation, so a renderer can evaluate the candidates
of all lanes (and fresh draws of regenerating lanes) in a single batch call: `propose`
returns candidate positions, the renderer evaluates them, `log_correction` gives the
Hastings term `log q(v -> u) - log q(u -> v)`.
"""

from __future__ import annotations

import abc
import math
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, PRNGKeyArray

from ._mutations import AbstractMutation, KelemenMutation, normal_block, wrap
from ._pss import PSSPoint


def metropolis_test(
    uniform: Float[Array, " N"], current: PSSPoint, candidate: PSSPoint, log_correction: Float[Array, " N"]
) -> tuple[Bool[Array, " N"], Float[Array, " N"]]:
    """Accept with probability `a = min(1, lum' / lum * q(v -> u) / q(u -> v))`, per lane.

    `uniform` is one uniform per lane (best from `fine_uniform`, so that tiny `a` are
    exact). Returns the decisions and `a`. A candidate of zero luminance is never accepted; a
    current state of zero luminance accepts any candidate of positive luminance.
    """
    log_ratio = jnp.log(candidate.lum) - jnp.log(current.lum) + log_correction
    log_ratio = jnp.where(current.lum > 0, log_ratio, jnp.inf)
    log_ratio = jnp.where((candidate.lum > 0) & ~jnp.isnan(log_ratio), log_ratio, -jnp.inf)
    alpha = jnp.exp(jnp.minimum(log_ratio, 0.0))
    accept = jnp.log(uniform) < log_ratio
    return accept, alpha


class AbstractLocalKernel(eqx.Module):
    """A luminance-invariant Markov kernel on the torus, batch-level."""

    uses_gradient: ClassVar[bool] = False

    @abc.abstractmethod
    def propose(self, key: PRNGKeyArray, current: PSSPoint) -> Float[Array, "N D"]:
        """Candidate positions, in `[0, 1)`."""

    @abc.abstractmethod
    def log_correction(self, current: PSSPoint, candidate: PSSPoint) -> Float[Array, " N"]:
        """`log q(candidate -> current) - log q(current -> candidate)`."""


class MetropolisKernel(AbstractLocalKernel):
    """Metropolis with a symmetric small step (default Kelemen's), so no Hastings term.

    Arguments:
        mutation: the small step, e.g. `KelemenMutation()`.
    """

    mutation: AbstractMutation

    def __init__(self, mutation: AbstractMutation | None = None):
        mutation = KelemenMutation() if mutation is None else mutation
        if not isinstance(mutation, AbstractMutation):
            raise TypeError(f"mutation must be a restore.render mutation, got {type(mutation).__name__}")
        self.mutation = mutation

    def propose(self, key: PRNGKeyArray, current: PSSPoint) -> Float[Array, "N D"]:
        return self.mutation(key, current.u)

    def log_correction(self, current: PSSPoint, candidate: PSSPoint) -> Float[Array, " N"]:
        return jnp.zeros_like(current.lum)


#: Offsets `n` of the periodic images in the wrapped-normal proposal density: with the
#: offset reduced to `[0, 1)` and `sqrt(2h) <= 0.25`, the terms left out lie at least
#: 3 units away, a relative weight below `exp(-72)`: the density is exact in float32.
_IMAGES = (-3.0, -2.0, -1.0, 0.0, 1.0, 2.0)
_MAX_SCALE = 0.25


class MALAKernel(AbstractLocalKernel):
    """Metropolis-adjusted Langevin on the torus.

    Proposes `v = wrap(u + h grad log lum(u) + sqrt(2h) N(0, I))`. On the torus the
    proposal density is the *wrapped* normal `sum_n N(v + n; u + h g, 2h I)`, which
    factorises over coordinates; it is evaluated with enough periodic images to be exact
    in float32 (no nearest-image approximation), so the Hastings ratio is exact however
    large the drift is. Gradients that are not finite count as zero (the drift is then a
    deterministic function of the state either way, so the test stays exact).

    Arguments:
        step_size: `h > 0` with `sqrt(2h) <= 0.25`.
    """

    step_size: float = eqx.field(static=True)
    uses_gradient: ClassVar[bool] = True

    def __init__(self, step_size: float = 1e-4):
        h = float(step_size)
        if not (math.isfinite(h) and h > 0 and math.sqrt(2 * h) <= _MAX_SCALE):
            raise ValueError(f"MALA step_size h must satisfy 0 < h and sqrt(2h) <= {_MAX_SCALE}, got {step_size!r}")
        self.step_size = h

    def _mean(self, point: PSSPoint) -> Float[Array, "N D"]:
        return wrap(point.u + self.step_size * point.grad)

    def propose(self, key: PRNGKeyArray, current: PSSPoint) -> Float[Array, "N D"]:
        noise = normal_block(key, current.u.shape)
        return wrap(self._mean(current) + math.sqrt(2 * self.step_size) * noise)

    def _log_q(self, to: Array, start: PSSPoint) -> Float[Array, " N"]:
        """`log q(start -> to)` up to a constant: wrapped normal, summed over images."""
        delta = wrap(to - self._mean(start))[..., None] + jnp.asarray(_IMAGES, jnp.float32)
        per_coord = jax.nn.logsumexp(-(delta**2) / (4 * self.step_size), axis=-1)
        return jnp.sum(per_coord, axis=-1)

    def log_correction(self, current: PSSPoint, candidate: PSSPoint) -> Float[Array, " N"]:
        return self._log_q(current.u, candidate) - self._log_q(candidate.u, current)
