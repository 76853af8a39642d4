"""Random-walk Metropolis whose proposal covariance follows a Gaussian mixture: local steps sized to where the walk is."""

from __future__ import annotations

from collections.abc import Callable
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray

from .._point import Point
from .._validation import is_concrete
from ._base import AbstractLocalKernel, LocalInfo, hastings_accept


class GuidedRandomWalk(AbstractLocalKernel):
    """Random-walk Metropolis-Hastings with a position-dependent proposal `y = x + step P(x)^-1 N(0, I)`.

    `P(x) = sum_k r_k(x) L_k^-1` mixes the inverse factors of a guide, a Gaussian mixture
    `sum_k w_k N(m_k, L_k L_k^T)`, by the responsibilities `r_k(x)` of its components at `x`:
    a walk in a funnel's neck takes the neck component's small steps, in its mouth the
    mouth component's large ones, and on a curved ridge each piece's own correlations.
    A weighted sum of lower-triangular matrices with positive diagonals is one too, so the
    proposal is a non-degenerate Gaussian everywhere; it is not symmetric, and the test
    includes the reverse proposal's density (Metropolis-Hastings). Any guide leaves the
    target invariant; a guide close to the target makes the steps fit. A step costs the
    guide's responsibilities at both ends (`O(K d^2)`, `O(K d)` for diagonal factors) and
    one triangular solve.

    Arguments:
        log_weights: `(K,)` log weights of the guide's components (`-inf` for unused ones).
        means: `(K, d)` their means.
        scale_trils: `(K, d, d)` lower-triangular factors with positive diagonals (the
            components' covariances are `L_k L_k^T`).
        step: a positive scalar multiplying the proposal's factor (e.g. `2.38 / sqrt(d)`).
    """

    log_weights: Float[Array, " K"]
    means: Float[Array, "K d"]
    precisions: Float[Array, "K d d"] | Float[Array, "K d"]  # inverse factors `L_k^-1`, or their diagonals
    log_dets: Float[Array, " K"]  # log det of `L_k^-1`
    step: Float[Array, ""]
    diagonal: bool = eqx.field(static=True)
    proposes_from_position: ClassVar[bool] = True

    def __init__(self, log_weights: Array, means: Array, scale_trils: Array, step: float | Array = 1.0):
        log_weights, means, trils = jnp.asarray(log_weights), jnp.asarray(means), jnp.asarray(scale_trils)
        if means.ndim != 2 or trils.shape != means.shape + means.shape[-1:] or log_weights.shape != means.shape[:1]:
            raise ValueError(
                "GuidedRandomWalk needs log_weights (K,), means (K, d) and scale_trils (K, d, d), got "
                f"{log_weights.shape}, {means.shape} and {trils.shape}"
            )
        diagonal = False
        if is_concrete(trils) and is_concrete(log_weights):  # checked on the host
            host, w = np.asarray(trils), np.asarray(log_weights)
            used = np.isfinite(w)
            if not used.any() or np.any(np.isnan(w)) or np.any(w == np.inf):
                raise ValueError("GuidedRandomWalk log_weights must be finite or -inf, at least one finite")
            diagonals = np.diagonal(host[used], axis1=-2, axis2=-1)
            if not (np.all(np.isfinite(host[used])) and np.all(diagonals > 0) and np.allclose(host, np.tril(host))):
                raise ValueError("GuidedRandomWalk scale_trils must be finite and lower triangular with positive diagonals")
            diagonal = bool(np.all(host == host * np.eye(host.shape[-1])))
        if is_concrete(jnp.asarray(step)) and not float(step) > 0:
            raise ValueError(f"GuidedRandomWalk step must be positive, got {step!r}")
        scales = jnp.diagonal(trils, axis1=-2, axis2=-1)
        # unused components (weight 0) may hold any factor: they get the identity, which is invertible
        unused = ~jnp.isfinite(log_weights)[:, None]
        if diagonal:
            self.precisions = 1.0 / jnp.where(unused, 1.0, scales)
        else:
            eye = jnp.eye(trils.shape[-1], dtype=trils.dtype)
            safe = jnp.where(unused[..., None], eye, trils)
            self.precisions = jax.vmap(lambda t: jax.scipy.linalg.solve_triangular(t, eye, lower=True))(safe)
        self.log_dets = -jnp.sum(jnp.log(jnp.where(unused, 1.0, scales)), axis=-1)
        self.log_weights, self.means, self.diagonal = log_weights, means, diagonal
        self.step = jnp.asarray(step, trils.dtype)

    def check_dim(self, dim: int) -> None:
        if self.means.shape[1] != dim:
            raise ValueError(f"GuidedRandomWalk guide has dimension {self.means.shape[1]} but the target has dimension {dim}")

    def precision(self, x: Float[Array, " d"]) -> Float[Array, "d d"] | Float[Array, " d"]:
        """`P(x)`, the responsibility-weighted inverse factors at `x` (its diagonal for a diagonal guide)."""
        diff = x - self.means
        white = self.precisions * diff if self.diagonal else jnp.einsum("kij,kj->ki", self.precisions, diff)
        joint = self.log_weights + self.log_dets - 0.5 * jnp.sum(white**2, axis=-1)
        responsibilities = jax.nn.softmax(jnp.where(jnp.isnan(joint), -jnp.inf, joint))
        return jnp.tensordot(responsibilities, self.precisions, axes=1)

    def _log_q(self, to: Array, start: Point) -> Array:
        """Log density (up to a constant) of proposing `to` from `start`."""
        p, delta = self.precision(start.position), (to - start.position) / self.step
        white = p * delta if self.diagonal else p @ delta
        diagonal = p if self.diagonal else jnp.diagonal(p)
        return -0.5 * jnp.sum(white**2) + jnp.sum(jnp.log(diagonal))

    def propose(self, key: PRNGKeyArray, point: Point, logdensity_fn: Callable) -> tuple[Array, None]:
        x = point.position
        z, p = jax.random.normal(key, x.shape, x.dtype), self.precision(x)
        move = z / p if self.diagonal else jax.scipy.linalg.solve_triangular(p, z, lower=True)
        return x + self.step * move, None

    def accept(self, key: PRNGKeyArray, point: Point, candidate: Point, aux: None) -> tuple[Point, LocalInfo]:
        return hastings_accept(key, point, candidate, self._log_q)
