"""The primary-sample-space (PSS) target interface, and evaluation of a batch of points.

A PSS target is an image-forming integrand on the torus `[0, 1)^D`: a point `u` is a
vector of random numbers that a path tracer turns into a light path; its luminance is
the (unnormalised) density the renderers sample and its RGB value is what they splat.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from .._point import Point, evaluate


@runtime_checkable
class PSSTarget(Protocol):
    """What a renderer needs from a target.

    Attributes:
        dim: `D`, the number of primary sample coordinates.
        resolution: `(W, H)` in pixels.
        num_pixels: `W * H`.

    The density is `p(u) = luminance(u)` on the torus; the image is
    `I_j = W H ∫ rgb(u) 1{pixel(u) = j} du = W H Z E_p[rgb / luminance 1{pixel = j}]`.
    """

    dim: int
    resolution: tuple[int, int]

    @property
    def num_pixels(self) -> int: ...

    def jax_evaluate(self, u: Float[Array, "N D"]) -> tuple[Float[Array, " N"], Float[Array, "N 3"]]:
        """Luminance `(N,)` and RGB `(N, 3)` of a batch; batch-level and jit-compatible."""
        ...

    def jax_evaluate_with_grad(
        self, u: Float[Array, "N D"]
    ) -> tuple[Float[Array, " N"], Float[Array, "N 3"], Float[Array, "N D"]]:
        """Luminance, RGB and the gradient of `log luminance` with respect to `u`."""
        ...

    def pixel_index(self, u: Float[Array, "N D"]) -> Int[Array, " N"]:
        """`floor(u_0 W) + W floor(u_1 H)` (int32), in pure JAX."""
        ...


def check_target(target: object, *, needs_gradient: bool = False) -> None:
    """Raise a clear error if `target` does not provide the `PSSTarget` interface."""
    members = ("dim", "resolution", "num_pixels", "jax_evaluate", "pixel_index")
    members += ("jax_evaluate_with_grad",) if needs_gradient else ()
    missing = [m for m in members if not hasattr(target, m)]
    if missing:
        raise TypeError(f"{type(target).__name__} is not a PSS target: it lacks {', '.join(missing)}")
    dim, res = target.dim, target.resolution  # type: ignore[attr-defined]
    if isinstance(dim, bool) or not isinstance(dim, int) or dim < 2:
        raise ValueError(f"target.dim must be an integer >= 2 (two image coordinates), got {dim!r}")
    if not (isinstance(res, tuple) and len(res) == 2 and all(isinstance(r, int) and r >= 1 for r in res)):
        raise ValueError(f"target.resolution must be a pair of positive integers (W, H), got {res!r}")
    if target.num_pixels != res[0] * res[1]:  # type: ignore[attr-defined]
        raise ValueError(f"target.num_pixels is {target.num_pixels}, but W * H = {res[0] * res[1]}")  # type: ignore[attr-defined]


def pss_logdensity(target: PSSTarget) -> Callable[[Array], tuple[Array, Array]]:
    """The target as a log density of one point for the core samplers, with the colour as aux.

    `u (D,) -> (log lum(u), rgb(u) / lum(u))`: the value is `-inf` where the luminance is
    zero, negative or not finite (zero density), and the aux (the contribution per unit
    density that every MCMC renderer splats) is then zero, as are non-finite colours.
    Samplers built with `has_aux=True` carry it beside the state at no second evaluation.
    Under `vmap` the target's batch call is made once for all lanes. Differentiating the
    value calls `target.jax_evaluate_with_grad` (a custom VJP), so gradient-based kernels
    (`restore.local.TorusMALA`) also cost one batch call per step.
    """

    def clean(lum: Array, rgb: Array) -> tuple[Array, Array]:
        lum, rgb = jnp.asarray(lum, jnp.float32), jnp.asarray(rgb, jnp.float32)
        good = jnp.isfinite(lum) & (lum > 0)
        safe = jnp.where(good, lum, 1.0)
        contribution = jnp.where(good & jnp.isfinite(rgb), rgb / safe, 0.0)
        contribution = jnp.where(jnp.isfinite(contribution), contribution, 0.0)
        return jnp.where(good, jnp.log(safe), -jnp.inf), contribution

    @jax.custom_vjp
    def logdensity(u: Array) -> tuple[Array, Array]:
        lum, rgb = target.jax_evaluate(jnp.asarray(u, jnp.float32)[None])
        return clean(lum[0], rgb[0])

    def forward(u: Array):
        lum, rgb, grad = target.jax_evaluate_with_grad(jnp.asarray(u, jnp.float32)[None])
        grad = jnp.asarray(grad[0]).astype(jnp.asarray(u).dtype)
        return clean(lum[0], rgb[0]), jnp.where(jnp.isfinite(grad), grad, 0.0)

    def backward(grad: Array, cotangent: tuple[Array, Array]) -> tuple[Array]:
        return (cotangent[0].astype(grad.dtype) * grad,)

    logdensity.defvjp(forward, backward)
    return logdensity


def evaluate_points(target: PSSTarget, u: Float[Array, "N D"], with_grad: bool = False) -> Point:
    """Evaluate a batch of points (one batch call) as the core samplers do: a `Point` of arrays
    with `aux = rgb / lum`, float32."""
    logdensity = pss_logdensity(target)
    u = jnp.asarray(u, jnp.float32)
    return jax.vmap(lambda x: evaluate(logdensity, x, with_grad, has_aux=True)[0])(u)


def luminance(point: Point) -> Float[Array, "*N"]:
    """The luminance of evaluated points (`exp` of their log density; zero where it is `-inf`)."""
    return jnp.exp(point.logdensity)


def empty_points(n: int, dim: int) -> Point:
    """`n` placeholder points (zero positions and contributions, zero density) of a state
    that is filled by the first step."""
    return Point(
        jnp.zeros((n, dim), jnp.float32), jnp.full((n,), -jnp.inf, jnp.float32), None, jnp.zeros((n, 3), jnp.float32)
    )
