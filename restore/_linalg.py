"""Dense linear algebra with a lower Cholesky factor, shared by Gaussian regeneration and transfers."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float


def mahalanobis_sq(tril: Float[Array, "d d"], r: Float[Array, " d"]) -> Float[Array, ""]:
    """`r^T (L L^T)^{-1} r` via a triangular solve."""
    z = jax.scipy.linalg.solve_triangular(tril, r, lower=True)
    return jnp.sum(z**2)


def half_log_det(tril: Float[Array, "d d"]) -> Float[Array, ""]:
    """`0.5 * log det(L L^T) = sum(log diag L)`."""
    return jnp.sum(jnp.log(jnp.diag(tril)))
