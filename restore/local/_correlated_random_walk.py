"""Random-walk Metropolis with a full proposal covariance: local moves along a target's correlations."""

from __future__ import annotations

from collections.abc import Callable
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray

from .._point import Point
from .._validation import is_concrete
from ._base import AbstractLocalKernel, LocalInfo, metropolis_accept


class CorrelatedRandomWalk(AbstractLocalKernel):
    """Gaussian random-walk Metropolis kernel, `y = x + L N(0, I)`, with `L` a `(d, d)` factor.

    A random walk whose proposal covariance `L L^T` is `(2.38^2 / d)` times the target's
    covariance mixes about `kappa` times faster than an axis-aligned one on a target with
    condition number `kappa`; the proposal is symmetric, so the test is Metropolis's.

    Arguments:
        scale_tril: the lower-triangular factor `L`, shape `(d, d)`, with a positive diagonal.
    """

    scale_tril: Float[Array, "d d"]
    proposes_from_position: ClassVar[bool] = True

    def __init__(self, scale_tril: Array):
        tril = jnp.asarray(scale_tril)
        if tril.ndim != 2 or tril.shape[0] != tril.shape[1] or not jnp.issubdtype(tril.dtype, jnp.floating):
            raise ValueError(f"scale_tril must be a square floating matrix (d, d), got {tril.dtype} {tril.shape}")
        if is_concrete(tril):  # checked on the host (an eager device check compiles programs)
            host = np.asarray(tril)
            if not (np.all(np.isfinite(host)) and np.all(np.diag(host) > 0) and np.allclose(host, np.tril(host))):
                raise ValueError("scale_tril must be finite and lower triangular with a positive diagonal")
        self.scale_tril = tril

    def check_dim(self, dim: int) -> None:
        if self.scale_tril.shape[0] != dim:
            raise ValueError(f"CorrelatedRandomWalk scale_tril is {self.scale_tril.shape} but the target has dimension {dim}")

    def propose(self, key: PRNGKeyArray, point: Point, logdensity_fn: Callable) -> tuple[Array, None]:
        x = point.position
        return x + self.scale_tril @ jax.random.normal(key, x.shape, x.dtype), None

    def accept(self, key: PRNGKeyArray, point: Point, candidate: Point, aux: None) -> tuple[Point, LocalInfo]:
        return metropolis_accept(key, point, candidate, candidate.logdensity - point.logdensity)
