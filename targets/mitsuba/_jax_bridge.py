"""Calling the Mitsuba tracer from jitted JAX code through `jax.pure_callback`.

Dr.Jit arrays cannot be built from JAX tracers (`dr.wrap` does not go from JAX to
Dr.Jit), so the whole batch leaves XLA once per call: the callback receives every point
at once, traces them with the frozen Dr.Jit function and returns NumPy arrays. With
`vmap_method="expand_dims"` a vmapped call is still one callback on the stacked batch.
The pixel index needs no callback: it is computed in JAX exactly as the tracer does.

Calls into the tracer are serialised by one lock: XLA may run two callbacks at once
(e.g. the lanes of two devices, or two jitted programs), and Dr.Jit's recorded
functions are not safe to enter concurrently (such runs failed with "unknown variable").
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

#: Serialises every call into the tracer (see the module docstring).
TRACER_LOCK = threading.Lock()


def wrap_unit_np(u: np.ndarray) -> np.ndarray:
    """`u mod 1` in float32, in `[0, 1)` (a value that rounds to 1 wraps to 0): the PSS is a torus."""
    u = np.asarray(u, dtype=np.float32)
    w = u - np.floor(u)
    return np.where(w >= 1, np.float32(0), w).astype(np.float32)


def wrap_unit_jax(u: jax.Array) -> jax.Array:
    """`wrap_unit_np` in JAX, bit-for-bit (float32 `floor` and subtraction are exact)."""
    u = jnp.asarray(u).astype(jnp.float32)
    w = u - jnp.floor(u)
    return jnp.where(w >= 1, jnp.float32(0), w)


def pixel_index_jax(u: jax.Array, width: int, height: int) -> jax.Array:
    """Pixel `y W + x` (int32) of points `u (..., D)`, with `x = floor(u0 W)`, `y = floor(u1 H)`."""
    film = wrap_unit_jax(u[..., 0:2])
    x = jnp.minimum(jnp.floor(film[..., 0] * jnp.float32(width)).astype(jnp.int32), width - 1)
    y = jnp.minimum(jnp.floor(film[..., 1] * jnp.float32(height)).astype(jnp.int32), height - 1)
    return y * width + x


def values_callback(evaluate: Callable[[np.ndarray], Any], dim: int) -> Callable[[jax.Array], tuple]:
    """`u (..., D) -> (luminance (...), rgb (..., 3))` as a jit- and vmap-able JAX function."""

    def host(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        batch = np.asarray(u).shape[:-1]
        with TRACER_LOCK:
            samples = evaluate(np.asarray(u).reshape(-1, dim))
        return samples.luminance.reshape(batch), samples.rgb.reshape(*batch, 3)

    def call(u: jax.Array) -> tuple[jax.Array, jax.Array]:
        u = _check_points(u, dim)
        shapes = (
            jax.ShapeDtypeStruct(u.shape[:-1], jnp.float32),
            jax.ShapeDtypeStruct((*u.shape[:-1], 3), jnp.float32),
        )
        return jax.pure_callback(host, shapes, u, vmap_method="expand_dims")

    return call


def values_pixel_callback(evaluate: Callable[[np.ndarray], Any], dim: int) -> Callable[[jax.Array], tuple]:
    """`u (..., D) -> (luminance, rgb (..., 3), pixel (...) int32)` for targets whose pixel the tracer finds."""

    def host(u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        batch = np.asarray(u).shape[:-1]
        with TRACER_LOCK:
            samples = evaluate(np.asarray(u).reshape(-1, dim))
        return (
            samples.luminance.reshape(batch),
            samples.rgb.reshape(*batch, 3),
            samples.pixel.astype(np.int32).reshape(batch),
        )

    def call(u: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
        u = _check_points(u, dim)
        shapes = (
            jax.ShapeDtypeStruct(u.shape[:-1], jnp.float32),
            jax.ShapeDtypeStruct((*u.shape[:-1], 3), jnp.float32),
            jax.ShapeDtypeStruct(u.shape[:-1], jnp.int32),
        )
        return jax.pure_callback(host, shapes, u, vmap_method="expand_dims")

    return call


def values_and_grad_callback(
    evaluate_with_grad: Callable[[np.ndarray], Any], dim: int
) -> Callable[[jax.Array], tuple]:
    """`u (..., D) -> (luminance, rgb, d log(luminance) / du (..., D))` as a JAX function."""

    def host(u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        batch = np.asarray(u).shape[:-1]
        with TRACER_LOCK:
            samples, grad = evaluate_with_grad(np.asarray(u).reshape(-1, dim))
        return samples.luminance.reshape(batch), samples.rgb.reshape(*batch, 3), grad.reshape(*batch, dim)

    def call(u: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
        u = _check_points(u, dim)
        shapes = (
            jax.ShapeDtypeStruct(u.shape[:-1], jnp.float32),
            jax.ShapeDtypeStruct((*u.shape[:-1], 3), jnp.float32),
            jax.ShapeDtypeStruct((*u.shape[:-1], dim), jnp.float32),
        )
        return jax.pure_callback(host, shapes, u, vmap_method="expand_dims")

    return call


def log_luminance_fn(values: Callable, values_and_grad: Callable) -> Callable[[jax.Array], jax.Array]:
    """`u -> log(luminance)` (`-inf` where it is 0) with a custom VJP from the gradient callback."""

    @jax.custom_vjp
    def log_luminance(u: jax.Array) -> jax.Array:
        lum, _ = values(u)
        return _safe_log(lum)

    def fwd(u: jax.Array) -> tuple[jax.Array, jax.Array]:
        lum, _, grad = values_and_grad(u)
        return _safe_log(lum), grad.astype(jnp.asarray(u).dtype)

    def bwd(grad: jax.Array, cotangent: jax.Array) -> tuple[jax.Array]:
        return (cotangent[..., None].astype(grad.dtype) * grad,)

    log_luminance.defvjp(fwd, bwd)
    return log_luminance


def _safe_log(lum: jax.Array) -> jax.Array:
    return jnp.where(lum > 0, jnp.log(jnp.where(lum > 0, lum, 1.0)), -jnp.inf)


def _check_points(u: Any, dim: int) -> jax.Array:
    u = jnp.asarray(u)
    if u.ndim < 1 or u.shape[-1] != dim:
        raise ValueError(f"points must have shape (..., {dim}), got {u.shape}")
    if not jnp.issubdtype(u.dtype, jnp.floating):
        u = u.astype(jnp.float32)
    return u
