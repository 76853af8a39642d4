"""The interfaces of local dynamics in continuous time, each with its generator's adjoint."""

from __future__ import annotations

import abc
from collections.abc import Callable
from typing import Any, ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, PRNGKeyArray

from .._point import Point, evaluate
from .._validation import check_positive
from ..local import AbstractLocalKernel, LocalInfo


class AbstractDynamics(eqx.Module):
    """Local dynamics of a Restore tour: a Markov process `Y` with generator `L`.

    A Restore process kills `Y` at rate `gamma = L* p / p + c_tilde q / p`, so besides
    how to move, dynamics must say what `L* p / p` is at a point (`adjoint_ratio`): zero
    for dynamics that leave the target invariant (`is_invariant = True`), a signed real
    number otherwise. Subclasses are either jump dynamics (`AbstractJumpDynamics`) or
    diffusions (`AbstractDiffusion`).
    """

    uses_gradient: ClassVar[bool] = False
    is_invariant: ClassVar[bool] = False
    keeps_geometry: ClassVar[bool] = False

    def evaluate_point(
        self, logdensity_fn: Callable[[Array], Any], position: Array, has_aux: bool = False
    ) -> tuple[Point, Bool[Array, ""]]:
        """The point at `position`, evaluated with what these dynamics need there (the gradient
        where they use it; a local kernel's `geometry` where it keeps one), and whether the
        evaluation was invalid."""
        return evaluate(logdensity_fn, position, self.uses_gradient, has_aux)

    @abc.abstractmethod
    def adjoint_ratio(self, logdensity_fn: Callable[[Array], Array], point: Point) -> Float[Array, ""]:
        """`(L* p)(x) / p(x)` at `point` (zero when `is_invariant`)."""

    def check_dim(self, dim: int) -> None:
        """Raise a clear `ValueError` if the parameters do not fit dimension `dim`."""


class AbstractJumpDynamics(AbstractDynamics):
    """A Markov kernel `zeta` run in continuous time: moves at the times of a Poisson process of rate `rate`.

    `L f(x) = r ∫ (f(y) - f(x)) zeta(x, dy)`, so
    `L* p / p = r (∫ p(x) zeta(x, y) dx / p(y) - 1)`. A move is split at its one new
    density evaluation (`propose`, then `accept`) like `restore.local` kernels, so the
    sampler can share the evaluation with a regeneration draw.
    """

    rate: eqx.AbstractVar[float]

    @abc.abstractmethod
    def propose(self, key: PRNGKeyArray, point: Point, logdensity_fn: Callable[[Array], Array]) -> tuple[Array, Any]:
        """Return the candidate position and what `accept` needs."""

    @abc.abstractmethod
    def accept(self, key: PRNGKeyArray, point: Point, candidate: Point, aux: Any) -> tuple[Point, LocalInfo]:
        """Return the next point and move info."""

    def log_convolution(self, position: Float[Array, " d"]) -> Float[Array, ""]:
        """`log ∫ p(x) zeta(x, y) dx` at `y = position`, in the normalisation of `p`.

        Only non-invariant kernels need it; invariant ones never call it.
        """
        raise NotImplementedError(f"{type(self).__name__} does not define log_convolution")

    def adjoint_ratio(self, logdensity_fn: Callable[[Array], Array], point: Point) -> Float[Array, ""]:
        if self.is_invariant:
            return jnp.zeros((), point.logdensity.dtype)
        log_ratio = self.log_convolution(point.position) - point.logdensity
        return self.rate * jnp.expm1(log_ratio)


class AbstractDiffusion(AbstractDynamics):
    """A diffusion `dY = b(Y) dt + s dW` with constant diffusion matrix `a = s s^T`.

    `advance` moves a point forward by a duration: exactly for dynamics with
    `is_exact = True` (Brownian motion, Ornstein-Uhlenbeck), by a documented small-step
    scheme otherwise. Killing times are simulated by Poisson thinning.
    """

    is_exact: ClassVar[bool] = True

    @abc.abstractmethod
    def advance(
        self, key: PRNGKeyArray, position: Float[Array, " d"], duration: Float[Array, ""], logdensity_fn: Callable[[Array], Array]
    ) -> Float[Array, " d"]:
        """A draw of `Y_duration` given `Y_0 = position`."""


class Jump(AbstractJumpDynamics):
    """A pi-invariant kernel from `restore.local` run in continuous time (`L* p = 0`).

    Arguments:
        kernel: e.g. `restore.local.RandomWalk(0.5)`.
        rate: rate `r > 0` of its moves (mean holding time `1/r` between moves).
    """

    kernel: AbstractLocalKernel
    rate: float = eqx.field(static=True)

    is_invariant: ClassVar[bool] = True

    def __init__(self, kernel: AbstractLocalKernel, rate: float = 1.0):
        if not isinstance(kernel, AbstractLocalKernel):
            raise TypeError(f"kernel must be a restore.local kernel, got {type(kernel).__name__}")
        if rate is None:
            raise TypeError("rate must be a positive number, got None")
        self.kernel = kernel
        self.rate = check_positive(rate, "rate")

    @property
    def uses_gradient(self) -> bool:  # type: ignore[override]  # the ClassVar is never set, so a property may replace it
        return self.kernel.uses_gradient

    @property
    def keeps_geometry(self) -> bool:  # type: ignore[override]  # the ClassVar is never set, so a property may replace it
        return self.kernel.keeps_geometry

    def evaluate_point(self, logdensity_fn, position, has_aux=False):
        return self.kernel.evaluate_point(logdensity_fn, position, has_aux)

    def check_dim(self, dim: int) -> None:
        self.kernel.check_dim(dim)

    def propose(self, key, point, logdensity_fn):
        return self.kernel.propose(key, point, logdensity_fn)

    def accept(self, key, point, candidate, aux):
        return self.kernel.accept(key, point, candidate, aux)
