"""Use any BlackJAX kernel as local dynamics."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, PRNGKeyArray

from .._point import Point
from ._base import AbstractLocalKernel, LocalInfo

_POINT_FIELDS = {"position", "logdensity", "logdensity_grad"}


class BlackJAXKernel(AbstractLocalKernel):
    """Adapter that runs a BlackJAX sampling algorithm as the local dynamics.

    BlackJAX kernels evaluate the density themselves, so the move cannot share its
    evaluation with a regeneration draw: a step costs the kernel's own evaluations plus
    one. When the kernel's state holds only `position`, `logdensity` and
    `logdensity_grad` (RMH, MALA, HMC, NUTS...), it is rebuilt from the current point
    without evaluating again; otherwise the kernel's `init` is called each move.

    Arguments:
        build: a function of the log density returning a BlackJAX `SamplingAlgorithm`,
            e.g. `lambda logdensity: blackjax.mala(logdensity, step_size=0.1)`.
        uses_gradient: whether the kernel's state carries `logdensity_grad` (so the
            sampler keeps gradients up to date).

    The kernel must leave the target invariant (every BlackJAX MCMC kernel does; its
    approximate samplers such as SGLD do not, and must not be used here).
    """

    build: Callable[[Callable], Any] = eqx.field(static=True)
    uses_gradient: bool = eqx.field(static=True)  # type: ignore[misc]  # read only on instances: a field may replace the ClassVar

    def __init__(self, build: Callable[[Callable], Any], uses_gradient: bool = False):
        try:
            import blackjax  # noqa: F401
        except ImportError as err:  # pragma: no cover - exercised only without blackjax
            raise ImportError("BlackJAXKernel needs blackjax: pip install 'restore-mcmc[compare]'") from err
        if not callable(build):
            raise TypeError("build must be a function of the log density returning a BlackJAX algorithm")
        self.build = build
        self.uses_gradient = bool(uses_gradient)

    def _state(self, algorithm: Any, point: Point) -> Any:
        structure = jax.eval_shape(algorithm.init, point.position)
        fields = getattr(structure, "_fields", ())
        if fields and set(fields) <= _POINT_FIELDS and ("logdensity_grad" not in fields or point.grad is not None):
            values = {"position": point.position, "logdensity": point.logdensity, "logdensity_grad": point.grad}
            return type(structure)(**{name: values[name] for name in fields})
        return algorithm.init(point.position)

    def propose(self, key: PRNGKeyArray, point: Point, logdensity_fn: Callable) -> tuple[Array, Any]:
        algorithm = self.build(logdensity_fn)
        new_state, info = algorithm.step(key, self._state(algorithm, point))
        return new_state.position, (new_state, info)

    def accept(self, key: PRNGKeyArray, point: Point, candidate: Point, aux: Any) -> tuple[Point, LocalInfo]:
        new_state, info = aux
        moved = jnp.any(new_state.position != point.position)
        grad = getattr(new_state, "logdensity_grad", None) if point.grad is not None else None
        logp = jnp.where(jnp.isnan(new_state.logdensity), -jnp.inf, new_state.logdensity)
        prob = getattr(info, "acceptance_rate", moved.astype(logp.dtype))
        return Point(new_state.position, logp, grad, candidate.aux), LocalInfo(moved, jnp.asarray(prob, logp.dtype))
