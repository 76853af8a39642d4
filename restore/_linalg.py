"""Dense linear algebra with a lower Cholesky factor, shared by Gaussian regeneration and transfers."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float


def inverse_tril(tril: Float[Array, "d d"]) -> Float[Array, "d d"]:
    """`L^{-1}` (lower triangular), from one triangular solve against the identity."""
    return jax.scipy.linalg.solve_triangular(tril, jnp.eye(tril.shape[-1], dtype=tril.dtype), lower=True)


def mahalanobis_sq(tril: Float[Array, "d d"], r: Float[Array, " d"], inverse: Float[Array, "d d"] | None = None) -> Float[Array, ""]:
    """`r^T (L L^T)^{-1} r = |L^{-1} r|^2`, with `inverse` `= L^{-1}` if known (`inverse_tril`).

    Written for one point and `vmap`ped over lanes: each lane does `d^2` multiplications.
    The inverse depends on `L` alone; a distribution keeps it (computed once, when it is
    built), because XLA does not always hoist its solve out of a run's loops: inside the
    batches that `restore.JumpRestore.step_lanes` computes kill terms in, it was solved
    again at every step. A triangular solve per lane instead dominated a jump-Restore
    step's time on a CPU (XLA loops over the batch of solves).
    """
    inverse = inverse_tril(tril) if inverse is None else inverse
    # `r @ L^{-T}`, a matrix product. Two other forms are worse on the CPU with jax 0.10.2:
    # - `inverse @ r`, summed and vmapped over more than 16384 lanes, gives wrong float64
    #   results for the lanes past 16384 (an XLA bug; tests/unit/test_many_lanes.py);
    # - the elementwise `sum(inverse * r, -1)` becomes a YNNPACK fusion that is several
    #   times slower than this product.
    z = r @ inverse.T
    return jnp.sum(z**2)


def half_log_det(tril: Float[Array, "d d"]) -> Float[Array, ""]:
    """`0.5 * log det(L L^T) = sum(log diag L)`."""
    return jnp.sum(jnp.log(jnp.diag(tril)))
