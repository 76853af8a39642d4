"""Local moves on the torus `[0, 1)^d`: symmetric small steps (Kelemen's, a wrapped Gaussian) and MALA.

The torus is the primary sample space of light transport: a point is the vector of
random numbers a path tracer turns into a light path. Both small steps are symmetric
(`q(u -> v) = q(v -> u)`), so a Metropolis test on the density alone is exact with them.
"""

from __future__ import annotations

import abc
import math
from collections.abc import Callable
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from .._point import Point
from ._base import AbstractLocalKernel, LocalInfo, gradient_of, hastings_accept, metropolis_accept


def wrap(u: Float[Array, ...]) -> Float[Array, ...]:
    """Map onto `[0, 1)` (a tiny negative float32 value would round `u - floor(u)` to 1)."""
    y = u - jnp.floor(u)
    return jnp.where(y >= 1.0, y - 1.0, y)


class AbstractTorusMutation(eqx.Module):
    """A symmetric small step on the torus, applied to one point `(d,)`."""

    @abc.abstractmethod
    def __call__(self, key: PRNGKeyArray, u: Float[Array, " d"]) -> Float[Array, " d"]:
        """The perturbed point, wrapped into `[0, 1)`."""


class KelemenMutation(AbstractTorusMutation):
    """Kelemen et al.'s small step: each coordinate moves by `±s2 exp(-log(s2 / s1) xi)`.

    With `xi` uniform, the offset is log-uniform between `s1` and `s2`, with a random
    sign, independently per coordinate: mostly tiny steps and a few larger ones.

    Arguments:
        s1: smallest offset, `0 < s1 < s2`.
        s2: largest offset, `s2 <= 0.5`.
    """

    s1: float = eqx.field(static=True)
    s2: float = eqx.field(static=True)

    def __init__(self, s1: float = 1.0 / 1024, s2: float = 1.0 / 64):
        s1, s2 = float(s1), float(s2)
        if not (math.isfinite(s1) and math.isfinite(s2) and 0 < s1 < s2 <= 0.5):
            raise ValueError(f"KelemenMutation needs 0 < s1 < s2 <= 0.5, got s1={s1!r}, s2={s2!r}")
        self.s1, self.s2 = s1, s2

    def __call__(self, key: PRNGKeyArray, u: Float[Array, " d"]) -> Float[Array, " d"]:
        # one uniform per coordinate: its first bit is the sign, the rest the size
        # (`2v mod 1` is uniform and independent of `v < 1/2`)
        v = 2.0 * jax.random.uniform(key, u.shape, u.dtype)
        sign = jnp.where(v < 1.0, 1.0, -1.0).astype(u.dtype)
        offset = self.s2 * jnp.exp(-math.log(self.s2 / self.s1) * (v - jnp.floor(v)))
        return wrap(u + sign * offset.astype(u.dtype))


class WrappedGaussianMutation(AbstractTorusMutation):
    """Isotropic Gaussian step `u + sigma N(0, I)`, wrapped onto the torus.

    Arguments:
        sigma: standard deviation per coordinate, in `(0, 0.5]`.
    """

    sigma: float = eqx.field(static=True)

    def __init__(self, sigma: float = 1.0 / 64):
        sigma = float(sigma)
        if not (math.isfinite(sigma) and 0 < sigma <= 0.5):
            raise ValueError(f"WrappedGaussianMutation needs 0 < sigma <= 0.5, got {sigma!r}")
        self.sigma = sigma

    def __call__(self, key: PRNGKeyArray, u: Float[Array, " d"]) -> Float[Array, " d"]:
        return wrap(u + self.sigma * jax.random.normal(key, u.shape, u.dtype))


class TorusMetropolis(AbstractLocalKernel):
    """Metropolis on the torus with a symmetric small step (default Kelemen's): no Hastings term.

    Arguments:
        mutation: the small step, e.g. `KelemenMutation()` (the default).
        frozen: the number of leading coordinates the step never moves (default 0). With
            multiplexed light transport the first coordinate picks the path depth and
            strategy, which small steps must keep (`targets.mitsuba.MultiplexedBDPT`).
            The step stays symmetric, so the kernel stays reversible.
    """

    mutation: AbstractTorusMutation
    frozen: int = eqx.field(static=True)
    proposes_from_position: ClassVar[bool] = True

    def __init__(self, mutation: AbstractTorusMutation | None = None, frozen: int = 0):
        mutation = KelemenMutation() if mutation is None else mutation
        if not isinstance(mutation, AbstractTorusMutation):
            raise TypeError(
                f"mutation must be a torus mutation (e.g. KelemenMutation()), got {type(mutation).__name__}"
            )
        if isinstance(frozen, bool) or not isinstance(frozen, int) or frozen < 0:
            raise ValueError(f"frozen must be a non-negative integer, got {frozen!r}")
        self.mutation = mutation
        self.frozen = frozen

    def check_dim(self, dim: int) -> None:
        if self.frozen >= dim:
            raise ValueError(f"frozen={self.frozen} leaves no coordinate to move in dimension {dim}")

    def propose(
        self, key: PRNGKeyArray, point: Point, logdensity_fn: Callable[[Array], Array] | None = None
    ) -> tuple[Array, None]:
        """The small step from `point`; it needs no log density (`logdensity_fn` may be `None`)."""
        moved = self.mutation(key, point.position)
        if self.frozen:
            moved = moved.at[: self.frozen].set(point.position[: self.frozen])
        return moved, None

    def accept(self, key: PRNGKeyArray, point: Point, candidate: Point, aux: None) -> tuple[Point, LocalInfo]:
        return metropolis_accept(key, point, candidate, candidate.logdensity - point.logdensity)


#: Offsets `n` of the periodic images in the wrapped-normal proposal density: with the
#: offset reduced to `[0, 1)` and `sqrt(2h) <= 0.25`, the terms left out lie at least
#: 3 units away, a relative weight below `exp(-72)`: the density is exact in float32.
_IMAGES = (-3.0, -2.0, -1.0, 0.0, 1.0, 2.0)
_MAX_SCALE = 0.25


class TorusMALA(AbstractLocalKernel):
    """Metropolis-adjusted Langevin on the torus.

    Proposes `v = wrap(u + h grad log p(u) + sqrt(2h) N(0, I))`. On the torus the
    proposal density is the *wrapped* normal `sum_n N(v + n; u + h g, 2h I)`, which
    factorises over coordinates; it is evaluated with enough periodic images to be exact
    in float32 (no nearest-image approximation), so the Hastings ratio is exact however
    large the drift is. (The sampler zeroes gradients that are not finite, so the drift is
    a function of the state and the test stays exact.)

    Arguments:
        step_size: `h`, with `0 < h` and `sqrt(2h) <= 0.25`.
    """

    step_size: float = eqx.field(static=True)
    uses_gradient: ClassVar[bool] = True

    def __init__(self, step_size: float = 1e-4):
        h = float(step_size)
        if not (math.isfinite(h) and h > 0 and math.sqrt(2 * h) <= _MAX_SCALE):
            raise ValueError(
                f"TorusMALA step_size h must satisfy 0 < h and sqrt(2h) <= {_MAX_SCALE}, got {step_size!r}"
            )
        self.step_size = h

    def _mean(self, point: Point) -> Float[Array, " d"]:
        return wrap(point.position + self.step_size * gradient_of(point))

    def _log_q(self, to: Array, start: Point) -> Float[Array, ""]:
        """`log q(start -> to)` up to a constant: a wrapped normal, summed over images."""
        delta = wrap(to - self._mean(start))[..., None] + jnp.asarray(_IMAGES, to.dtype)
        return jnp.sum(jax.nn.logsumexp(-(delta**2) / (4 * self.step_size), axis=-1))

    def propose(
        self, key: PRNGKeyArray, point: Point, logdensity_fn: Callable[[Array], Array] | None = None
    ) -> tuple[Array, None]:
        """The Langevin step from `point`, from its gradient alone (`logdensity_fn` may be `None`)."""
        x = point.position
        noise = jax.random.normal(key, x.shape, x.dtype)
        return wrap(self._mean(point) + math.sqrt(2 * self.step_size) * noise), None

    def accept(self, key: PRNGKeyArray, point: Point, candidate: Point, aux: None) -> tuple[Point, LocalInfo]:
        return hastings_accept(key, point, candidate, self._log_q)
