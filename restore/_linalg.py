"""Dense linear algebra with a lower Cholesky factor, shared by Gaussian regeneration and transfers."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float


def mahalanobis_sq(tril: Float[Array, "d d"], r: Float[Array, " d"]) -> Float[Array, ""]:
    """`r^T (L L^T)^{-1} r = |L^{-1} r|^2`, with `L^{-1}` from one triangular solve against the identity.

    Written for one point and `vmap`ped over lanes: the inverse depends on `L` alone, so it
    is computed once for all lanes and each lane does `d^2` multiplications. A triangular
    solve per lane instead was more than half of a jump-Restore step's time on a CPU (XLA
    loops over the batch of solves).
    """
    inverse = jax.scipy.linalg.solve_triangular(tril, jnp.eye(tril.shape[-1], dtype=tril.dtype), lower=True)
    # Elementwise, not `inverse @ r`: summed and vmapped over more than 16384 lanes, that product
    # gives wrong float64 results for the lanes past 16384 on the CPU with jax 0.10.2 (an XLA bug
    # in a matrix-vector product followed by a reduction; tests/unit/test_many_lanes.py).
    z = jnp.sum(inverse * r[..., None, :], axis=-1)
    return jnp.sum(z**2)


def half_log_det(tril: Float[Array, "d d"]) -> Float[Array, ""]:
    """`0.5 * log det(L L^T) = sum(log diag L)`."""
    return jnp.sum(jnp.log(jnp.diag(tril)))
