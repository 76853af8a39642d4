"""Checks of user input that fail early with a clear message instead of deep inside XLA.

This is the bottom layer of the package: it imports nothing else from `restore`, and every
other module takes its argument checks from here.

One rule decides the error type, everywhere:

- `TypeError` when the argument is of the wrong kind: not a number where a number is
  asked (a string, `None`, a boolean, a complex number, a ragged list), not an integer
  type where a count is asked and the value is not integral-looking at all, not callable
  where a function is asked.
- `ValueError` when the kind is right but the value is not: out of range (zero, negative,
  too large), not integral (`2.5` for a count), not finite, or of the wrong shape or length.

So `check_integer("3", ...)` and `check_integer(True, ...)` raise `TypeError`, while
`check_integer(2.5, ...)` and `check_integer(0, ...)` raise `ValueError`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, overload

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

_NUMBER_TYPES = (int, float, np.integer, np.floating)


def is_concrete(*xs: Any) -> bool:
    """True if none of `xs` is a tracer, i.e. their values can be inspected."""
    return not any(isinstance(x, jax.core.Tracer) for x in xs)


def _is_number(value: Any) -> bool:
    """A real Python or NumPy scalar that is not a boolean."""
    return isinstance(value, _NUMBER_TYPES) and not isinstance(value, (bool, np.bool_))


def check_integer(value: Any, name: str, minimum: int = 1) -> int:
    """An integer setting (a count or a size): a Python or NumPy integer, or an integral float,
    at least `minimum`; booleans, NaN, infinities and strings are refused with a message naming it."""
    wanted = {0: "a non-negative integer", 1: "a positive integer"}.get(minimum, f"an integer >= {minimum}")
    if not _is_number(value):
        raise TypeError(f"{name} must be {wanted}, got {value!r}")
    if not math.isfinite(value) or int(value) != value or value < minimum:
        raise ValueError(f"{name} must be {wanted}, got {value!r}")
    return int(value)


@overload
def check_positive(value: None, name: str) -> None: ...
@overload
def check_positive(value: Any, name: str) -> float: ...
def check_positive(value: Any, name: str) -> float | None:
    """A positive, finite real number (a rate, a length), or `None`.

    The value must be one real number (a Python or NumPy scalar, or a 0-d array); booleans,
    strings and traced values are refused with a `TypeError`, arrays with more than one
    entry, zero, negative and non-finite values with a `ValueError`.
    """
    if value is None:
        return None
    if isinstance(value, (bool, np.bool_, str, bytes)):
        raise TypeError(f"{name} must be a positive number, got {value!r}")
    try:
        arr = np.asarray(value)
    except Exception as err:  # e.g. a traced value: these are static settings
        raise TypeError(f"{name} must be a concrete positive number, got {type(value).__name__}") from err
    if arr.dtype.kind not in "iuf":
        raise TypeError(f"{name} must be a positive number, got {value!r}")
    if arr.ndim != 0:
        raise ValueError(f"{name} must be a scalar, got shape {arr.shape}")
    number = float(arr)
    if not math.isfinite(number) or number <= 0:
        raise ValueError(f"{name} must be positive and finite, got {value!r}")
    return number


def check_interval(seconds: Any, name: str = "checkpoint_seconds") -> float | None:
    """A time between checkpoints: a positive, finite number of seconds, or `None` (no timed saves)."""
    if seconds is None:
        return None
    if not _is_number(seconds):
        raise TypeError(f"{name} must be a positive number or None, got {seconds!r}")
    if not (math.isfinite(seconds) and seconds > 0):
        raise ValueError(f"{name} must be a positive number or None, got {seconds!r}")
    return float(seconds)


def as_float_array(x: ArrayLike, name: str | None = None) -> Array:
    """Convert to a JAX array of a floating dtype.

    Floating inputs keep their dtype; integer/bool inputs become the default
    float dtype (float32, or float64 under `jax_enable_x64`). Anything else (strings,
    `None`, complex numbers, ragged lists) raises a `TypeError` naming the argument.
    """
    label = f"`{name}`" if name else "the value"
    try:
        arr = jnp.asarray(x)
    except (TypeError, ValueError) as err:
        raise TypeError(f"{label} must be an array of real numbers, got {repr(x)[:80]}") from err
    if jnp.issubdtype(arr.dtype, jnp.complexfloating):
        raise TypeError(f"{label} must be real, got dtype {arr.dtype}")
    if not jnp.issubdtype(arr.dtype, jnp.floating):
        arr = arr.astype(jnp.result_type(arr.dtype, float))
    return arr


def check_point(x: ArrayLike, dim: int, name: str, *, finite: bool = False) -> Array:
    """One point: a floating array of shape `(dim,)` (integers are converted).

    The shape is static, so it is checked under `jit` too; with `finite=True` a concrete
    point must also be finite (a traced one cannot be inspected).
    """
    arr = as_float_array(x, name)
    if arr.shape != (dim,):
        raise ValueError(
            f"{name} must have shape ({dim},) (a single point of shape (d,); use jax.vmap for batches), "
            f"got shape {arr.shape}"
        )
    if finite and is_concrete(arr) and not bool(jnp.all(jnp.isfinite(arr))):
        raise ValueError(f"{name} must be finite")
    return arr


def check_vector(x: ArrayLike, name: str) -> Array:
    """A floating 1-D array with at least one entry."""
    arr = as_float_array(x, name)
    if arr.ndim != 1 or arr.shape[0] == 0:
        raise ValueError(f"`{name}` must be a non-empty 1-D array, got shape {arr.shape}.")
    return arr


def check_shape(shape: Any) -> tuple[int, ...]:
    """A sample shape: a non-negative int `n` (meaning `(n,)`) or a sequence of them."""
    if _is_number(shape):
        return (check_integer(shape, "`shape`", minimum=0),)
    if isinstance(shape, (str, bytes)):
        raise TypeError(f"`shape` must be a tuple of non-negative ints, got {shape!r}.")
    try:
        entries = tuple(shape)
    except TypeError:
        raise TypeError(f"`shape` must be a tuple of non-negative ints, got {shape!r}.") from None
    return tuple(check_integer(s, f"`shape` {shape!r}: every entry", minimum=0) for s in entries)


def as_scale(value: Any, name: str) -> Array:
    """A step-size-like argument: positive and finite, a scalar or a vector `(d,)`."""
    try:
        arr = jnp.asarray(value)
    except (TypeError, ValueError) as err:
        raise TypeError(f"{name} must be a positive number or a vector of them, got {value!r}") from err
    if arr.dtype == bool or not (jnp.issubdtype(arr.dtype, jnp.floating) or jnp.issubdtype(arr.dtype, jnp.integer)):
        raise TypeError(f"{name} must be a positive number or a vector of them, got dtype {arr.dtype}")
    if not jnp.issubdtype(arr.dtype, jnp.floating):
        arr = arr.astype(float)
    if arr.ndim > 1:
        raise ValueError(f"{name} must be a scalar or a vector of shape (d,), got shape {arr.shape}")
    if is_concrete(arr):  # checked on the host (an eager device check compiles programs)
        host = np.asarray(arr)
        # XLA flushes subnormal numbers to zero, so a step size below the smallest normal one is zero
        if not bool(np.all(np.isfinite(host) & (host >= np.finfo(host.dtype).tiny))):
            raise ValueError(f"{name} must be positive and finite (at least {np.finfo(host.dtype).tiny:.3g}), got {value!r}")
    return arr


def check_vector_dim(arr: Array, dim: int, name: str) -> None:
    """Raise if a per-coordinate parameter (a scalar or a vector) has the wrong length."""
    if arr.ndim == 1 and arr.shape[0] != dim:
        raise ValueError(f"{name} has length {arr.shape[0]} but the target has dimension {dim}")


def check_scalar_fn(fn: Any, dim: int, dtype: Any, name: str) -> None:
    """`fn` maps one point of shape `(dim,)` and dtype `dtype` to a real floating scalar."""
    if not callable(fn):
        raise TypeError(f"`{name}` must be callable, got {type(fn).__name__}.")
    out = jax.eval_shape(fn, jax.ShapeDtypeStruct((dim,), dtype))
    if not (isinstance(out, jax.ShapeDtypeStruct) and out.shape == () and jnp.issubdtype(out.dtype, jnp.floating)):
        raise ValueError(f"`{name}` must map one point of shape ({dim},) to a real floating scalar, got {out}.")


def check_logdensity(
    logdensity: Callable[[Array], Any], dim: int, with_grad: bool = False, has_aux: bool = False
) -> None:
    """Trace `logdensity` once on a `(dim,)` point: it must return one real scalar, or with
    `has_aux` a pair `(scalar, aux)` (and, for gradient-based dynamics, be differentiable by
    `jax.grad`)."""
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
    if has_aux:
        if not (isinstance(out, tuple) and len(out) == 2):
            raise ValueError(
                f"with has_aux=True, logdensity must return a pair (log density, aux), got {type(out).__name__}"
            )
        out = out[0]
    elif isinstance(out, tuple):
        raise ValueError(
            f"logdensity returned a tuple of {len(out)}; if it returns (log density, aux), pass has_aux=True"
        )
    if not hasattr(out, "shape") or out.shape != ():
        shape = getattr(out, "shape", type(out).__name__)
        raise ValueError(
            f"logdensity must return a scalar for one point of shape ({dim},), got {shape}; "
            "write it for a single point (the samplers vmap it)"
        )
    if not jnp.issubdtype(out.dtype, jnp.floating):
        raise ValueError(f"logdensity must return a floating-point scalar, got dtype {out.dtype}")
    if with_grad:
        value = (lambda x: logdensity(x)[0]) if has_aux else logdensity
        try:
            jax.eval_shape(jax.grad(lambda x: jnp.asarray(value(x)).astype(probe.dtype)), probe)
        except Exception as err:
            raise ValueError(
                "the local dynamics use the gradient of logdensity, but jax.grad failed on it (a "
                "jax.pure_callback or other code without a derivative rule?); use a gradient-free kernel "
                f"such as restore.local.RandomWalk, or give logdensity a custom_jvp: {err}"
            ) from err


def check_key(key: Any, name: str = "key") -> None:
    """A JAX random key: a typed key (`jax.random.key(0)`) or a raw one (`jax.random.PRNGKey(0)`,
    `uint32` of shape `(2,)`); anything else (an int seed, a batch of keys) is refused by name."""
    if isinstance(key, jax.Array) and jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        if key.shape != ():
            raise ValueError(f"{name} must be one random key, got a batch of shape {key.shape}")
        return
    if isinstance(key, (jax.Array, np.ndarray)) and key.dtype == np.uint32 and key.shape == (2,):
        return
    shown = f"{key!r}" if isinstance(key, (int, float, str)) else f"{type(key).__name__} of shape {getattr(key, 'shape', '?')}"
    raise TypeError(f"{name} must be a JAX random key such as jax.random.key(0), got {shown}")
