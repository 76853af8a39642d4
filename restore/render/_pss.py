"""The primary-sample-space (PSS) target interface, and evaluation of a batch of points.

A PSS target is an image-forming integrand on the torus `[0, 1)^D`: a point `u` is a
vector of random numbers that a path tracer turns into a light path; its luminance is
the (unnormalised) density the renderers sample and its RGB value is what they splat.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol, runtime_checkable

import jax.numpy as jnp
from jaxtyping import Array, Float, Int


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


class PSSPoint(NamedTuple):
    """A batch of evaluated points.

    Attributes:
        u: positions on the torus, `(N, D)`.
        lum: luminance `(N,)`, zero where the target returned a negative, NaN or
            infinite value (such a point is treated as having zero density).
        rgb: colour `(N, 3)`, zero where `lum` is zero.
        grad: gradient of `log lum`, `(N, D)`, zero where it is not finite; `None` when
            the renderer does not use gradients.
    """

    u: Float[Array, "N D"]
    lum: Float[Array, " N"]
    rgb: Float[Array, "N 3"]
    grad: Float[Array, "N D"] | None


def evaluate(target: PSSTarget, u: Float[Array, "N D"], with_grad: bool = False) -> PSSPoint:
    """Evaluate the target once on a batch (one batch call), in float32, with bad values cleaned."""
    u = jnp.asarray(u, jnp.float32)
    if with_grad:
        lum, rgb, grad = target.jax_evaluate_with_grad(u)
        grad = jnp.asarray(grad, jnp.float32)
        grad = jnp.where(jnp.isfinite(grad), grad, 0.0)
    else:
        lum, rgb = target.jax_evaluate(u)
        grad = None
    lum, rgb = jnp.asarray(lum, jnp.float32), jnp.asarray(rgb, jnp.float32)
    good = jnp.isfinite(lum) & (lum > 0)
    lum = jnp.where(good, lum, 0.0)
    rgb = jnp.where(good[:, None] & jnp.isfinite(rgb), rgb, 0.0)
    return PSSPoint(u, lum, rgb, grad)


def select(mask: Array, a: PSSPoint, b: PSSPoint) -> PSSPoint:
    """Lane-wise `a where mask else b`."""

    def pick(x, y):
        if x is None:
            return None
        m = mask.reshape(mask.shape + (1,) * (x.ndim - 1))
        return jnp.where(m, x, y)

    return PSSPoint(*(pick(x, y) for x, y in zip(a, b)))
