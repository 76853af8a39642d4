"""Covariance parsing for the regeneration distributions."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int, PRNGKeyArray

from .._validation import as_float_array, is_concrete


def scale_tril(cov: ArrayLike, dim: int, name: str) -> Float[Array, "d d"]:
    """Lower Cholesky factor `L` (with `L @ L.T == cov`) of a covariance-like input.

    Arguments:
        cov: a scalar variance (isotropic), a `(d,)` vector of variances
            (diagonal) or a symmetric positive-definite `(d, d)` matrix.
        dim: the dimension `d`.
        name: the argument name used in error messages.
    """
    cov = as_float_array(cov, name)
    dtype = cov.dtype
    concrete = is_concrete(cov)
    if cov.ndim == 0 or cov.shape == (dim,):
        if concrete:
            c = np.asarray(cov, dtype=np.float64)
            if not (np.all(np.isfinite(c)) and np.all(c > 0)):
                raise ValueError(
                    f"`{name}` given as a scalar or a diagonal must be finite and "
                    f"strictly positive, got {c}."
                )
            return jnp.asarray(np.diag(np.broadcast_to(np.sqrt(c), (dim,))), dtype)
        return jnp.diag(jnp.broadcast_to(jnp.sqrt(cov), (dim,)))
    if cov.shape != (dim, dim):
        raise ValueError(
            f"`{name}` must be a scalar, a ({dim},) diagonal or a ({dim}, {dim}) "
            f"matrix, got shape {cov.shape}."
        )
    if not concrete:
        return jnp.linalg.cholesky(0.5 * (cov + cov.T))
    # Concrete input: validate and factorise on the host in float64, then cast.
    c = np.asarray(cov, dtype=np.float64)
    if not np.all(np.isfinite(c)):
        raise ValueError(f"`{name}` contains non-finite entries.")
    tol = math.sqrt(float(np.finfo(dtype).eps)) * max(np.abs(c).max(), 1e-300)
    if np.abs(c - c.T).max() > tol:
        raise ValueError(f"`{name}` must be a symmetric matrix.")
    try:
        tril = np.linalg.cholesky(0.5 * (c + c.T))
    except np.linalg.LinAlgError:
        raise ValueError(
            f"`{name}` must be positive definite (its Cholesky factorisation failed)."
        ) from None
    if not (np.all(np.isfinite(tril)) and np.all(np.diag(tril).astype(dtype) > 0)):
        raise ValueError(f"`{name}` is too ill-conditioned to be represented in {dtype}.")
    return jnp.asarray(tril, dtype)


def component_indices(key: PRNGKeyArray, log_weights: Float[Array, "*c K"], shape: tuple[int, ...], dtype) -> Int[Array, "*shape *c"]:
    """Mixture components drawn with the weights `exp(log_weights)` (normalised along the
    last axis), shape `shape + log_weights.shape[:-1]`: one uniform number per index,
    inverting the cumulative weights (a categorical draw takes a Gumbel number per
    component). Exact; a component of weight zero is never drawn."""
    weights = jnp.exp(log_weights - jnp.max(log_weights, axis=-1, keepdims=True))
    cumulative = jnp.cumsum(weights, axis=-1)
    cumulative = cumulative / cumulative[..., -1:]  # the last entry, and any after it of weight zero, is exactly 1 > u
    u = jax.random.uniform(key, shape + log_weights.shape[:-1], dtype=dtype)
    return jnp.sum(u[..., None] >= cumulative[..., :-1], axis=-1)
