"""Private helpers: dtype handling, input validation and covariance parsing."""

from __future__ import annotations

import math
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float


def as_float_array(x: ArrayLike, name: str | None = None) -> Array:
    """Convert to a JAX array of a floating dtype.

    Floating inputs keep their dtype; integer/bool inputs become the default
    float dtype (float32, or float64 under `jax_enable_x64`). Anything else (strings,
    `None`, complex numbers, ragged lists) raises a `TypeError` naming the argument.
    """
    label = f"`{name}`" if name else "the value"
    try:
        x = jnp.asarray(x)
    except (TypeError, ValueError) as err:
        raise TypeError(f"{label} must be an array of real numbers, got {repr(x)[:80]}") from err
    if jnp.issubdtype(x.dtype, jnp.complexfloating):
        raise TypeError(f"{label} must be real, got dtype {x.dtype}")
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(x.dtype, float))
    return x


def is_concrete(*xs) -> bool:
    """True if none of `xs` is a tracer, i.e. values can be inspected."""
    return not any(isinstance(x, jax.core.Tracer) for x in xs)


def as_shape(shape: int | Sequence[int]) -> tuple[int, ...]:
    """Normalise a sample shape; an int `n` means `(n,)`."""
    if isinstance(shape, (int, np.integer)):
        shape = (int(shape),)
    try:
        shape = tuple(int(s) for s in shape)
    except TypeError:
        raise ValueError(
            f"`shape` must be a tuple of non-negative ints, got {shape!r}."
        ) from None
    if any(s < 0 for s in shape):
        raise ValueError(f"`shape` must contain non-negative ints, got {shape}.")
    return shape


def check_point(x: ArrayLike, dim: int) -> Array:
    """Validate the (static) shape of a single point passed to `log_prob`."""
    x = as_float_array(x)
    if x.shape != (dim,):
        raise ValueError(
            f"log_prob expects a single point of shape ({dim},), got shape "
            f"{x.shape}; use jax.vmap for batches."
        )
    return x


def vector(x: ArrayLike, name: str) -> Array:
    """A floating 1-D array with at least one entry."""
    x = as_float_array(x, name)
    if x.ndim != 1 or x.shape[0] == 0:
        raise ValueError(f"`{name}` must be a non-empty 1-D array, got shape {x.shape}.")
    return x


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


def mahalanobis_sq(tril: Float[Array, "d d"], r: Float[Array, " d"]) -> Float[Array, ""]:
    """`r^T (L L^T)^{-1} r` via a triangular solve."""
    z = jax.scipy.linalg.solve_triangular(tril, r, lower=True)
    return jnp.sum(z**2)


def half_log_det(tril: Float[Array, "d d"]) -> Float[Array, ""]:
    """`0.5 * log det(L L^T) = sum(log diag L)`."""
    return jnp.sum(jnp.log(jnp.diag(tril)))
