"""A target seen through a rotation: the same shape, its directions no longer the coordinate axes."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from . import _checks
from ._base import AbstractTarget


def random_rotation(dim: int, seed: int) -> np.ndarray:
    """A random orthogonal matrix `(dim, dim)`, uniform (Haar) over the orthogonal group: QR of a
    Gaussian matrix with the signs of `R`'s diagonal moved into `Q` (half of them reflect as well
    as rotate, which changes nothing a sampler sees)."""
    d = _checks.integer(dim, "dim", 1)
    q, r = np.linalg.qr(np.random.default_rng(seed).standard_normal((d, d)))
    return q * np.sign(np.diag(r))


class Rotated(AbstractTarget):
    """`target` rotated by `Q`: `y = Q x` with `x` drawn from `target`.

    `log p(y) = log p_target(Q^T y)` (a rotation has unit Jacobian), so `log Z`, the tails
    and the modes' shapes are the target's, while correlations, ill-conditioning and
    double wells are no longer aligned with the axes: what a sampler with axis-wise
    steps or product-form proposals does not see. Exact moments: mean `Q m`, covariance
    `Q C Q^T`. `marginal_cdf` raises `NotImplementedError` (a marginal mixes every
    coordinate of the target).

    Attributes:
        target: the target in its own coordinates.
        rotation: the orthogonal matrix `Q`, `(d, d)`.
        dim: `d` (static).
    """

    target: AbstractTarget
    rotation: Float[Array, "d d"]
    dim: int = eqx.field(static=True)

    def __init__(self, target: AbstractTarget, rotation: ArrayLike):
        """Arguments:
            target: any analytic target.
            rotation: an orthogonal `(d, d)` matrix (`random_rotation(d, seed)`).

        Raises:
            ValueError: for a matrix of another shape, or one that is not orthogonal.
        """
        q = np.asarray(rotation, np.float64)
        d = target.dim
        if q.shape != (d, d):
            raise ValueError(f"rotation must have shape ({d}, {d}) for a {d}-d target, got {q.shape}")
        if not np.allclose(q @ q.T, np.eye(d), atol=1e-8):
            raise ValueError("rotation must be orthogonal (Q Q^T = I)")
        self.target, self.rotation, self.dim = target, jnp.asarray(q), d

    def logdensity(self, x: Float[Array, " d"]) -> Float[Array, ""]:
        y = _checks.point(x, self.dim)
        return self.target.logdensity(self.rotation.T @ y)

    @property
    def log_normalising_constant(self) -> float:
        return self.target.log_normalising_constant

    def _sample(self, key: PRNGKeyArray, n: int) -> Float[Array, "n d"]:
        return self.target._sample(key, n) @ self.rotation.T

    @property
    def mean(self) -> Float[Array, " d"]:
        return self.rotation @ self.target.mean

    @property
    def covariance(self) -> Float[Array, "d d"]:
        return self.rotation @ self.target.covariance @ self.rotation.T

    def _marginal_cdf(self, i: int, t: Float[Array, ...]) -> Float[Array, ...]:
        raise NotImplementedError("a rotated target's marginals mix its coordinates: no closed form")
