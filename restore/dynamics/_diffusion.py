"""Diffusions with a constant diffusion matrix: the generator adjoint by autodiff, and an Euler-Maruyama scheme."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray

from .._point import Point
from .._validation import as_float_array, as_scale
from ._base import AbstractDiffusion


def log_derivatives(
    logdensity_fn: Callable[[Array], Array], x: Float[Array, " d"]
) -> tuple[Float[Array, ""], Float[Array, " d"], Float[Array, "d d"]]:
    """`log p(x)`, its gradient and its Hessian, in one forward-over-reverse pass."""

    def grad_with_aux(y):
        value, grad = jax.value_and_grad(logdensity_fn)(y)
        return grad, (value, grad)

    hessian, (value, grad) = jax.jacfwd(grad_with_aux, has_aux=True)(x)
    return value, grad, hessian


def second_order_term(
    grad: Float[Array, " d"], hessian: Float[Array, "d d"], diffusion_matrix: Float[Array, "*a"]
) -> Float[Array, ""]:
    """`1/2 sum_ij a_ij (d_ij log p + d_i log p d_j log p)` for `a` a scalar, a diagonal `(d,)` or a matrix `(d, d)`."""
    a = diffusion_matrix
    if a.ndim == 2:
        return 0.5 * (jnp.sum(a * hessian) + grad @ (a @ grad))
    return 0.5 * jnp.sum(a * (jnp.diagonal(hessian) + grad * grad))


def sanitize_ratio(value: Array, logdensity: Array) -> Float[Array, ""]:
    """Make an adjoint ratio safe: `+inf` where `p` is zero or invalid, or where the value is NaN.

    `+inf` kills a tour at once, the same treatment a point of zero or invalid density gets
    in `restore._point.evaluate`; no NaN leaves this function.
    """
    bad = ~jnp.isfinite(logdensity) | jnp.isnan(value)
    return jnp.where(bad, jnp.inf, value)


def check_diffusion_matrix(value: Any, name: str = "diffusion_matrix") -> Float[Array, "*a"]:
    """A constant diffusion matrix `a`: a positive scalar (`a I`), a positive diagonal `(d,)`, or a `(d, d)` matrix.

    A matrix must be finite, symmetric and positive definite (checked with a Cholesky
    factorisation when its values are concrete).
    """
    arr = as_float_array(value, name)
    if arr.ndim <= 1:
        return as_scale(arr, name)
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1]:
        raise ValueError(f"{name} must be a scalar, a vector (d,) or a square matrix (d, d); got shape {arr.shape}")
    if not isinstance(arr, jax.core.Tracer):
        values = np.asarray(arr, dtype=np.float64)
        if not np.all(np.isfinite(values)):
            raise ValueError(f"{name} must be finite")
        asym = np.max(np.abs(values - values.T))
        if asym > 100 * np.finfo(np.float64).eps * max(np.max(np.abs(values)), 1e-300):
            raise ValueError(f"{name} must be symmetric (max asymmetry {asym:.3g})")
        try:
            np.linalg.cholesky(values)
        except np.linalg.LinAlgError:
            raise ValueError(
                f"{name} must be positive definite (eigenvalues {np.linalg.eigvalsh(values)})"
            ) from None
        return jnp.asarray(0.5 * (values + values.T), dtype=arr.dtype)
    return 0.5 * (arr + arr.T)


def diffusion_root(a: Float[Array, "*a"]) -> Float[Array, "*a"]:
    """A square root `s` of the diffusion matrix (`a = s s^T`): Cholesky factor of a matrix, `sqrt` otherwise."""
    if isinstance(a, jax.core.Tracer):
        return jnp.linalg.cholesky(a) if a.ndim == 2 else jnp.sqrt(a)
    values = np.asarray(a, dtype=np.float64)
    root = np.linalg.cholesky(values) if a.ndim == 2 else np.sqrt(values)
    return jnp.asarray(root, dtype=a.dtype)


def check_matrix_dim(a: Array, dim: int, name: str) -> None:
    """Raise if a per-coordinate vector or a matrix does not fit dimension `dim`."""
    if a.ndim >= 1 and a.shape[0] != dim:
        raise ValueError(f"{name} has shape {a.shape} but the target has dimension {dim}")


def diffusion_adjoint_ratio(
    logdensity_fn: Callable[[Array], Array],
    x: Float[Array, " d"],
    drift_fn: Callable[[Array], Array] | None,
    diffusion_matrix: Float[Array, "*a"] | float,
) -> Float[Array, ""]:
    """`(L* p)(x) / p(x)` for the diffusion `dY = b(Y) dt + s dW` with constant `a = s s^T`.

    `L* p / p = -div b - b . grad log p + 1/2 sum_ij a_ij (d_ij log p + d_i log p d_j log p)`,
    computed by autodiff: the gradient and Hessian of `log p` in one forward-over-reverse
    pass, and `div b` as the trace of the Jacobian of `b` (forward mode). The cost is `d` Jacobian-vector products,
    so it suits moderate dimensions.

    The result is a finite number or `+-inf`, never NaN, and nothing raises under `jit`
    for any value of `x`: where `p(x)` is zero or invalid (`log p` is `-inf`, `+inf` or NaN)
    or the formula gives NaN (non-finite derivatives), the result is `+inf`, so a Restore
    process kills its tour there at once.

    Arguments:
        logdensity_fn: `log p` of one point of shape `(d,)`, unnormalised is fine (the ratio
            does not depend on the normalisation); twice differentiable.
        x: the point, shape `(d,)`.
        drift_fn: the drift `b`, a map from `(d,)` to `(d,)`, differentiable; `None` for zero drift.
        diffusion_matrix: `a`, a scalar (`a I`), a diagonal `(d,)` or a matrix `(d, d)`.
            Its values are not checked here (they may be traced); `Diffusion` checks them.

    Returns:
        The scalar `L* p / p` at `x`.
    """
    x = jnp.asarray(x)
    a = jnp.asarray(diffusion_matrix)
    if x.ndim != 1:
        raise ValueError(f"x must be a single point of shape (d,), got shape {x.shape}; use jax.vmap for batches")
    if a.ndim > 2 or (a.ndim >= 1 and a.shape[0] != x.shape[0]) or (a.ndim == 2 and a.shape[1] != x.shape[0]):
        raise ValueError(
            f"diffusion_matrix must be a scalar, or have shape ({x.shape[0]},) or ({x.shape[0]}, {x.shape[0]}) "
            f"to fit x; got shape {a.shape}"
        )
    if drift_fn is not None:
        b_shape = jax.eval_shape(drift_fn, x).shape
        if b_shape != x.shape:
            raise ValueError(f"drift_fn must map a point of shape {x.shape} to shape {x.shape}, got shape {b_shape}")
    logp, grad, hessian = log_derivatives(logdensity_fn, x)
    value = second_order_term(grad, hessian, a.astype(hessian.dtype))
    if drift_fn is not None:
        b, drift_jvp = jax.linearize(drift_fn, x)
        jacobian = jax.vmap(drift_jvp)(jnp.eye(x.shape[0], dtype=x.dtype))  # row i: d b / d x_i
        value = value - jnp.trace(jacobian) - b @ grad
    return sanitize_ratio(value, logp)


def as_step_size(value: Any) -> Float[Array, ""]:
    """A positive, finite, scalar Euler step size."""
    step = as_scale(value, "step_size")
    if step.ndim != 0:
        raise ValueError(f"step_size must be a scalar, got shape {step.shape}")
    return step


def num_substeps(duration: Array, step_size: Array) -> Array:
    """`ceil(duration / step_size)` as an integer, `0` for a non-positive or non-finite duration."""
    ratio = jnp.ceil(duration / step_size)
    ratio = jnp.where(jnp.isfinite(ratio) & (ratio > 0), ratio, 0.0)
    return jnp.minimum(ratio, 2.0**30).astype(jnp.int32)  # 2^30 is exact in float32; no int32 overflow


def euler_maruyama(
    key: PRNGKeyArray,
    position: Float[Array, " d"],
    duration: Float[Array, ""],
    step_size: Float[Array, ""],
    drift: Callable[[Array], Array],
    noise: Callable[[Array], Array],
) -> Float[Array, " d"]:
    """Euler-Maruyama over `duration` in `n = ceil(duration / step_size)` equal sub-steps of length `h <= step_size`.

    `x <- x + b(x) h + sqrt(h) noise(z)`, `z ~ N(0, I)`, where `noise(z)` has covariance `a`.
    `n` is a traced number (a `while_loop`), so this works under `jit` and `vmap` with a
    different duration per lane. A negative duration does not move; a non-finite one
    gives a NaN position (which a sampler's evaluation then flags as invalid).
    """
    dtype = position.dtype
    duration = jnp.asarray(duration, dtype)
    n = num_substeps(duration, step_size.astype(dtype))
    h = jnp.where(n > 0, duration / jnp.maximum(n, 1).astype(dtype), jnp.zeros((), dtype))
    sqrt_h = jnp.sqrt(h)

    def body(i, x):
        z = jax.random.normal(jax.random.fold_in(key, i), x.shape, dtype)
        return (x + h * drift(x) + sqrt_h * noise(z)).astype(dtype)

    out = jax.lax.fori_loop(0, n, body, position)
    return jnp.where(jnp.isfinite(duration), out, jnp.full_like(out, jnp.nan))


class Diffusion(AbstractDiffusion):
    """A generic diffusion `dY = b(Y) dt + s dW` with a constant diffusion matrix `a = s s^T`.

    The adjoint `L* p / p` is exact (autodiff, see `diffusion_adjoint_ratio`); the path is
    **approximate**: `advance` runs Euler-Maruyama sub-steps of length at most `step_size`,
    whose bias in distribution shrinks like `step_size` (`is_exact = False`). Prefer
    `BrownianMotion` or `OrnsteinUhlenbeck`, which move exactly, where they fit.

    Arguments:
        drift: `b`, a differentiable map from a point `(d,)` to `(d,)`; it does not see the
            target (close over `jax.grad(logdensity)` for a Langevin-type drift).
        diffusion_matrix: `a`, a positive scalar (`a I`), a positive diagonal `(d,)`, or a
            symmetric positive-definite matrix `(d, d)`.
        step_size: the largest Euler-Maruyama sub-step, positive; smaller is more accurate
            and costs more drift evaluations.
    """

    drift: Callable[[Array], Array]
    diffusion_matrix: Float[Array, "*a"]
    noise_factor: Float[Array, "*a"]
    step_size: Float[Array, ""]

    is_exact = False

    def __init__(self, drift: Callable[[Array], Array], diffusion_matrix: float | Array, step_size: float | Array):
        if not callable(drift):
            raise TypeError(f"drift must be a callable mapping a point (d,) to (d,), got {type(drift).__name__}")
        self.drift = drift
        self.diffusion_matrix = check_diffusion_matrix(diffusion_matrix)
        self.noise_factor = diffusion_root(self.diffusion_matrix)
        self.step_size = as_step_size(step_size)

    def check_dim(self, dim: int) -> None:
        check_matrix_dim(self.diffusion_matrix, dim, "Diffusion diffusion_matrix")

    def _noise(self, z: Array) -> Array:
        factor = self.noise_factor.astype(z.dtype)
        return factor @ z if factor.ndim == 2 else factor * z

    def adjoint_ratio(self, logdensity_fn: Callable[[Array], Array], point: Point) -> Float[Array, ""]:
        value = diffusion_adjoint_ratio(logdensity_fn, point.position, self.drift, self.diffusion_matrix)
        return sanitize_ratio(value, point.logdensity)

    def advance(
        self,
        key: PRNGKeyArray,
        position: Float[Array, " d"],
        duration: Float[Array, ""],
        logdensity_fn: Callable[[Array], Array],
    ) -> Float[Array, " d"]:
        return euler_maruyama(key, position, duration, self.step_size, self.drift, self._noise)
