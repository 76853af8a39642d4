"""Checks of user input that fail early with a clear message instead of deep inside XLA."""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jaxtyping import Array


def check_logdensity(logdensity: Callable[[Array], Array], dim: int) -> None:
    """Trace `logdensity` once on a `(dim,)` point: it must return one real scalar."""
    if not callable(logdensity):
        raise TypeError(f"logdensity must be callable, got {type(logdensity).__name__}")
    probe = jax.ShapeDtypeStruct((dim,), jnp.zeros(()).dtype)
    try:
        out = jax.eval_shape(logdensity, probe)
    except Exception as err:
        raise ValueError(
            f"logdensity failed on a point of shape ({dim},) (the regeneration distribution's "
            f"dimension); it must take one point of shape (d,) and return a scalar: {err}"
        ) from err
    if not hasattr(out, "shape") or out.shape != ():
        shape = getattr(out, "shape", type(out).__name__)
        raise ValueError(
            f"logdensity must return a scalar for one point of shape ({dim},), got {shape}; "
            "write it for a single point (the samplers vmap it)"
        )
    if not jnp.issubdtype(out.dtype, jnp.floating):
        raise ValueError(f"logdensity must return a floating-point scalar, got dtype {out.dtype}")


def check_position(position: Array, dim: int) -> Array:
    """A starting point: shape `(dim,)`, floating point, finite."""
    arr = jnp.asarray(position)
    if not jnp.issubdtype(arr.dtype, jnp.floating):
        arr = arr.astype(jnp.zeros(()).dtype)
    if arr.shape != (dim,):
        raise ValueError(f"position must have shape ({dim},), got {arr.shape}")
    if not isinstance(arr, jax.core.Tracer) and not bool(jnp.all(jnp.isfinite(arr))):
        raise ValueError("position must be finite")
    return arr


def check_parts(logdensity: Callable[[Array], Array], local, regeneration) -> None:
    """A sampler's parts: a restore.local kernel, a regeneration distribution, and a
    log density and kernel that fit its dimension."""
    from .local import AbstractLocalKernel
    from .regeneration import AbstractRegeneration

    if not isinstance(local, AbstractLocalKernel):
        raise TypeError(f"local must be a restore.local kernel, got {type(local).__name__}")
    if not isinstance(regeneration, AbstractRegeneration):
        raise TypeError(f"regeneration must be a restore.regeneration distribution, got {type(regeneration).__name__}")
    check_logdensity(logdensity, regeneration.dim)
    local.check_dim(regeneration.dim)
