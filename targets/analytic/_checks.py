"""Input validation shared by the analytic targets.

Value checks (positivity, positive definiteness, ...) need concrete inputs; they
are skipped when a constructor is called inside a JAX transformation with traced
arguments, while shape checks always run.
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float


def concrete(x: Any) -> np.ndarray | None:
    """`x` as a NumPy array, or `None` when it is a tracer (no value to check)."""
    if isinstance(x, jax.core.Tracer):
        return None
    return np.asarray(x)


def float_array(x: Any, name: str) -> Array:
    """`jnp.asarray(x)`, cast to the default float dtype if it is not floating already."""
    try:
        arr = jnp.asarray(x)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{name} must be array-like, got {type(x).__name__}") from err
    if not jnp.issubdtype(arr.dtype, jnp.floating):
        arr = arr.astype(jnp.result_type(float))
    return arr


def check_finite(arr: Array, name: str) -> None:
    values = concrete(arr)
    if values is not None and not np.all(np.isfinite(values)):
        raise ValueError(f"{name} must be finite")


def positive_float(value: Any, name: str) -> float:
    """A finite, strictly positive Python scalar."""
    out = _python_float(value, name)
    if not out > 0:
        raise ValueError(f"{name} must be positive, got {out}")
    return out


def finite_float(value: Any, name: str) -> float:
    """A finite Python scalar."""
    return _python_float(value, name)


def _python_float(value: Any, name: str) -> float:
    if isinstance(value, jax.core.Tracer):
        raise ValueError(f"{name} must be a concrete Python/NumPy scalar, not a traced value")
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{name} must be a real scalar, got {value!r}") from err
    if arr.shape != ():
        raise ValueError(f"{name} must be a scalar, got shape {arr.shape}")
    out = float(arr)
    if not math.isfinite(out):
        raise ValueError(f"{name} must be finite, got {out}")
    return out


def integer(value: Any, name: str, minimum: int) -> int:
    """A Python integer `>= minimum` (bools rejected)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    if value < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {value}")
    return int(value)


def coordinate(i: Any, dim: int) -> int:
    """A coordinate index in `[0, dim)`."""
    if isinstance(i, bool) or not isinstance(i, (int, np.integer)):
        raise ValueError(f"coordinate index i must be a Python integer, got {i!r}")
    if not 0 <= i < dim:
        raise ValueError(f"coordinate index i must lie in [0, {dim}), got {i}")
    return int(i)


def sample_count(n: Any) -> int:
    """A number of draws: a non-negative Python integer (it fixes an output shape)."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)):
        raise ValueError(f"n (the number of samples) must be a Python integer, got {n!r}")
    if n < 0:
        raise ValueError(f"n (the number of samples) must be >= 0, got {n}")
    return int(n)


def point(x: Any, dim: int) -> Float[Array, " d"]:
    """One point of shape `(dim,)` (shapes are static, so this also works under `jit`)."""
    arr = jnp.asarray(x)
    if arr.shape != (dim,):
        raise ValueError(
            f"x must be a single point of shape ({dim},), got shape {arr.shape}; "
            "use jax.vmap for batches"
        )
    if not jnp.issubdtype(arr.dtype, jnp.floating):
        arr = arr.astype(jnp.result_type(float))
    return arr


def mixture_means(means: Any) -> Float[Array, "k d"]:
    """Component means: a finite `(k, d)` array with `k, d >= 1`."""
    arr = float_array(means, "means")
    if arr.ndim != 2 or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise ValueError(
            "means must have shape (num_components, dim) with both >= 1, got shape "
            f"{arr.shape}; for a single component use means[None]"
        )
    check_finite(arr, "means")
    return arr


def mixture_weights(weights: Any, k: int, dtype: Any) -> Float[Array, " k"]:
    """Positive finite weights of shape `(k,)`, normalised to sum to one.

    `None` means equal weights.
    """
    if weights is None:
        return jnp.full((k,), 1.0 / k, dtype=dtype)
    arr = float_array(weights, "weights")
    if arr.shape != (k,):
        raise ValueError(
            f"weights must have shape ({k},) (one per component), got shape {arr.shape}"
        )
    values = concrete(arr)
    if values is not None and not (np.all(np.isfinite(values)) and np.all(values > 0)):
        raise ValueError(f"weights must be finite and strictly positive, got {values}")
    arr = arr.astype(dtype)
    return arr / jnp.sum(arr)


def matrix_stack(value: Any, k: int, d: int, name: str, dtype: Any) -> Float[Array, "k d d"]:
    """Symmetric positive-definite matrices, one per component, as a `(k, d, d)` array.

    Accepted forms: a scalar (the same `s * I` for every component), `(k,)` (a scalar
    `s_k * I` per component), `(k, d)` (diagonals) or `(k, d, d)` (full matrices).
    """
    arr = float_array(value, name)
    if arr.ndim == 0:
        arr = jnp.broadcast_to(arr, (k,))
    if arr.shape == (k,):
        _check_positive_entries(arr, name)
        mats = arr[:, None, None] * jnp.eye(d, dtype=arr.dtype)
    elif arr.shape == (k, d):
        _check_positive_entries(arr, name)
        mats = jax.vmap(jnp.diag)(arr)
    elif arr.shape == (k, d, d):
        check_finite(arr, name)
        values = concrete(arr)
        if values is not None:
            asym = np.max(np.abs(values - np.swapaxes(values, -1, -2)))
            tol = 100 * np.finfo(values.dtype).eps * max(np.max(np.abs(values)), 1e-300)
            if asym > tol:
                raise ValueError(f"{name} must be symmetric (max asymmetry {asym:.3g})")
        mats = 0.5 * (arr + jnp.swapaxes(arr, -1, -2))
    else:
        raise ValueError(
            f"{name} must be a scalar, or have shape ({k},) (one scalar per component), "
            f"({k}, {d}) (diagonals) or ({k}, {d}, {d}) (full matrices); got shape {arr.shape}"
        )
    return mats.astype(dtype)


def cholesky_stack(mats: Float[Array, "k d d"], name: str) -> Float[Array, "k d d"]:
    """Lower Cholesky factors; a `ValueError` if a matrix is not positive definite.

    With concrete inputs the factorisation is done once in float64 NumPy (which is
    also the positive-definiteness check) and cast to the dtype of `mats`.
    """
    values = concrete(mats)
    if values is None:
        return jnp.linalg.cholesky(mats)
    values = np.asarray(values, dtype=np.float64)
    chol = np.empty_like(values)
    for j, m in enumerate(values):
        try:
            chol[j] = np.linalg.cholesky(m)
        except np.linalg.LinAlgError:
            raise ValueError(
                f"{name}[{j}] is not positive definite (eigenvalues {np.linalg.eigvalsh(m)})"
            ) from None
    out = jnp.asarray(chol, dtype=mats.dtype)
    diag = np.diagonal(np.asarray(out), axis1=-2, axis2=-1)
    if not np.all(np.isfinite(diag) & (diag > 0)):
        raise ValueError(
            f"{name} is positive definite but too ill-conditioned to be represented in "
            f"{mats.dtype}"
        )
    return out


def _check_positive_entries(arr: Array, name: str) -> None:
    values = concrete(arr)
    if values is not None and not (np.all(np.isfinite(values)) and np.all(values > 0)):
        raise ValueError(f"{name} must be finite and strictly positive, got {values}")
