"""Checks of user input that fail early with a clear message instead of deep inside XLA."""

from __future__ import annotations

import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array


def check_logdensity(logdensity: Callable[[Array], Array], dim: int, with_grad: bool = False) -> None:
    """Trace `logdensity` once on a `(dim,)` point: it must return one real scalar (and, for
    gradient-based dynamics, be differentiable by `jax.grad`)."""
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
    if with_grad:
        try:
            jax.eval_shape(jax.grad(lambda x: jnp.asarray(logdensity(x)).astype(probe.dtype)), probe)
        except Exception as err:
            raise ValueError(
                "the local dynamics use the gradient of logdensity, but jax.grad failed on it (a "
                "jax.pure_callback or other code without a derivative rule?); use a gradient-free kernel "
                f"such as restore.local.RandomWalk, or give logdensity a custom_jvp: {err}"
            ) from err


def check_integer(value, name: str, minimum: int = 1) -> int:
    """An integer setting (a count or a size): a Python or NumPy integer, or an integral float,
    at least `minimum`; booleans, NaN, infinities and strings are refused with a message naming it."""
    wanted = {0: "a non-negative integer", 1: "a positive integer"}.get(minimum, f"an integer >= {minimum}")
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{name} must be {wanted}, got {value!r}")
    if not math.isfinite(value) or int(value) != value or value < minimum:
        raise ValueError(f"{name} must be {wanted}, got {value!r}")
    return int(value)


def check_position(position: Array, dim: int) -> Array:
    """A starting point: shape `(dim,)`, floating point, finite."""
    try:
        arr = jnp.asarray(position)
    except (TypeError, ValueError) as err:
        message = f"position must be an array of numbers of shape ({dim},), got {type(position).__name__}"
        raise TypeError(message) from err
    if jnp.issubdtype(arr.dtype, jnp.complexfloating):
        raise TypeError(f"position must be real, got dtype {arr.dtype}")
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
    check_logdensity(logdensity, regeneration.dim, with_grad=local.uses_gradient)
    local.check_dim(regeneration.dim)
