"""The primary-sample-space (PSS) target interface, and evaluation of a batch of points.

A PSS target is an image-forming integrand on the torus `[0, 1)^D`: a point `u` is a
vector of random numbers that a path tracer turns into a light path; its luminance is
the (unnormalised) density the renderers sample and its RGB value is what they splat.
Two optional attributes adapt the renderers to multiplexed targets
(`targets.mitsuba.MultiplexedBDPT`): `frozen_coordinates` (small steps keep them) and
`pixel_from_evaluation` (the tracer finds the pixel, and the splats take it from there).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple, Protocol, cast, runtime_checkable

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from .._point import Point, evaluate
from ..local import AbstractLocalKernel, AbstractTorusMutation, TorusMetropolis


@runtime_checkable
class PSSTarget(Protocol):
    """What a renderer needs from a target.

    Attributes:
        dim: `D`, the number of primary sample coordinates.
        resolution: `(W, H)` in pixels.
        num_pixels: `W * H`.

    Optional attributes (read with `frozen_coordinates` and `pixel_from_evaluation`):
        frozen_coordinates: how many leading coordinates small steps never move (default 0).
            A multiplexed target picks the path's depth and strategy from them; large
            steps and regenerations still draw every coordinate uniformly.
        pixel_from_evaluation: `True` if the pixel of a point is found by tracing it (light
            tracing lands anywhere on the film). The target then offers
            `jax_evaluate_with_pixel(u) -> (luminance, rgb, pixel)`, the log density carries
            the pixel in its aux, and every splat reads it there (one trace per point).

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


class PixelTracingTarget(PSSTarget, Protocol):
    """A `PSSTarget` with `pixel_from_evaluation`: the tracer finds each point's pixel."""

    def jax_evaluate_with_pixel(
        self, u: Float[Array, "N D"]
    ) -> tuple[Float[Array, " N"], Float[Array, "N 3"], Int[Array, " N"]]:
        """Luminance `(N,)`, RGB `(N, 3)` and the pixel index `(N,)` of a batch."""
        ...


class EvaluatedPixel(NamedTuple):
    """The aux of `pss_logdensity` for a target with `pixel_from_evaluation`: the
    contribution `rgb / lum` and the pixel the tracer found for the point."""

    contribution: Float[Array, "*N 3"]
    pixel: Int[Array, "*N"]


def frozen_coordinates(target: object) -> int:
    """The target's `frozen_coordinates` (0 if it has none)."""
    return getattr(target, "frozen_coordinates", 0)


def pixel_from_evaluation(target: object) -> bool:
    """Whether the target's pixels come from its evaluation (`False` if it does not say)."""
    return bool(getattr(target, "pixel_from_evaluation", False))


def small_step(mutation: AbstractTorusMutation, target: object) -> TorusMetropolis:
    """Metropolis with the small step `mutation`, never moving the target's frozen coordinates."""
    return TorusMetropolis(mutation, frozen=frozen_coordinates(target))


def check_target(target: object, *, needs_gradient: bool = False) -> None:
    """Raise a clear error if `target` does not provide the `PSSTarget` interface."""
    members: tuple[str, ...] = ("dim", "resolution", "num_pixels", "jax_evaluate", "pixel_index")
    members += ("jax_evaluate_with_pixel",) if pixel_from_evaluation(target) else ()
    missing = [m for m in members if not hasattr(target, m)]
    if missing:
        raise TypeError(f"{type(target).__name__} is not a PSS target: it lacks {', '.join(missing)}")
    if needs_gradient and not hasattr(target, "jax_evaluate_with_grad"):
        raise TypeError(
            f"this renderer needs gradients of the luminance (jax_evaluate_with_grad), which "
            f"{type(target).__name__} does not offer; use a renderer without gradients (e.g. MetropolisRestore)"
        )
    checked = cast(PSSTarget, target)  # only its members found above are read: dim, resolution, num_pixels
    dim, res = checked.dim, checked.resolution
    if isinstance(dim, bool) or not isinstance(dim, int) or dim < 2:
        raise ValueError(f"target.dim must be an integer >= 2 (two image coordinates), got {dim!r}")
    if not (isinstance(res, tuple) and len(res) == 2 and all(isinstance(r, int) and r >= 1 for r in res)):
        raise ValueError(f"target.resolution must be a pair of positive integers (W, H), got {res!r}")
    if checked.num_pixels != res[0] * res[1]:
        raise ValueError(f"target.num_pixels is {checked.num_pixels}, but W * H = {res[0] * res[1]}")
    frozen = frozen_coordinates(target)
    if isinstance(frozen, bool) or not isinstance(frozen, int) or not 0 <= frozen < dim:
        raise ValueError(f"target.frozen_coordinates must be an integer in [0, dim), got {frozen!r}")


def pss_logdensity(target: PSSTarget) -> Callable[[Array], tuple[Array, Array | EvaluatedPixel]]:
    """The target as a log density of one point for the core samplers, with the colour as aux.

    `u (D,) -> (log lum(u), rgb(u) / lum(u))`: the value is `-inf` where the luminance is
    zero, negative or not finite (zero density), and the aux (the contribution per unit
    density that every MCMC renderer splats) is then zero, as are non-finite colours.
    Samplers built with `has_aux=True` carry it beside the state at no second evaluation.
    Under `vmap` the target's batch call is made once for all lanes. Differentiating the
    value calls `target.jax_evaluate_with_grad` (a custom VJP), so gradient-based kernels
    (`restore.local.TorusMALA`) also cost one batch call per step.

    With `target.pixel_from_evaluation` the aux is an `EvaluatedPixel` (the contribution
    and the traced pixel, from one `jax_evaluate_with_pixel` call) and the log density has
    no gradient.
    """

    def clean(lum: Array, rgb: Array) -> tuple[Array, Array]:
        lum, rgb = jnp.asarray(lum, jnp.float32), jnp.asarray(rgb, jnp.float32)
        good = jnp.isfinite(lum) & (lum > 0)
        safe = jnp.where(good, lum, 1.0)
        contribution = jnp.where(good & jnp.isfinite(rgb), rgb / safe, 0.0)
        contribution = jnp.where(jnp.isfinite(contribution), contribution, 0.0)
        return jnp.where(good, jnp.log(safe), -jnp.inf), contribution

    if pixel_from_evaluation(target):
        tracer = cast(PixelTracingTarget, target)  # a target that says so offers `jax_evaluate_with_pixel` (`PSSTarget`)

        def with_pixel(u: Array) -> tuple[Array, EvaluatedPixel]:
            lum, rgb, pixel = tracer.jax_evaluate_with_pixel(jnp.asarray(u, jnp.float32)[None])
            value, contribution = clean(lum[0], rgb[0])
            return value, EvaluatedPixel(contribution, jnp.asarray(pixel[0], jnp.int32))

        return with_pixel

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


def evaluate_points(
    target: PSSTarget, u: Float[Array, "N D"], with_grad: bool = False, kernel: AbstractLocalKernel | None = None
) -> Point:
    """Evaluate a batch of points (one batch call) as the core samplers do: a `Point` of arrays
    with the aux of `pss_logdensity` (`rgb / lum`, or an `EvaluatedPixel`), float32; with a
    `kernel`, with all it needs at a point (`evaluate_point`: a gradient, its `geometry`)."""
    logdensity = pss_logdensity(target)
    u = jnp.asarray(u, jnp.float32)
    if kernel is not None:
        return jax.vmap(lambda x: kernel.evaluate_point(logdensity, x, has_aux=True)[0])(u)
    return jax.vmap(lambda x: evaluate(logdensity, x, with_grad, has_aux=True)[0])(u)


def luminance(point: Point) -> Float[Array, "*N"]:
    """The luminance of evaluated points (`exp` of their log density; zero where it is `-inf`)."""
    return jnp.exp(point.logdensity)


def contributions(aux: Array | EvaluatedPixel) -> Float[Array, "*N 3"]:
    """The contributions `rgb / lum` held in aux of `pss_logdensity`."""
    return aux.contribution if isinstance(aux, EvaluatedPixel) else aux


def pixels(target: PSSTarget, position: Float[Array, "*N D"], aux: Array | EvaluatedPixel) -> Int[Array, "*N"]:
    """The pixels to splat points at: the evaluated ones if the aux holds them, else
    `target.pixel_index(position)`."""
    return aux.pixel if isinstance(aux, EvaluatedPixel) else target.pixel_index(position)


def empty_points(target: PSSTarget, n: int) -> Point:
    """`n` placeholder points (zero positions, contributions and pixels, zero density) of a
    state that is filled by the first step."""
    contribution = jnp.zeros((n, 3), jnp.float32)
    aux = EvaluatedPixel(contribution, jnp.zeros((n,), jnp.int32)) if pixel_from_evaluation(target) else contribution
    return Point(jnp.zeros((n, target.dim), jnp.float32), jnp.full((n,), -jnp.inf, jnp.float32), None, aux)
