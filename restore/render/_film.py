"""The film: per-pixel sums of weighted `rgb / luminance`, filled by scatter-add."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float, Int


def empty_film(num_pixels: int) -> Float[Array, "P 3"]:
    """A zero film of `num_pixels` RGB sums (float32)."""
    return jnp.zeros((num_pixels, 3), jnp.float32)


def splat(
    film: Float[Array, "P 3"],
    pixel: Int[Array, " N"],
    weight: Float[Array, " N"],
    rgb: Float[Array, "N 3"],
    lum: Float[Array, " N"],
) -> Float[Array, "P 3"]:
    """Add `weight * rgb / lum` of each lane to its pixel.

    A lane with `lum == 0` (or a non-finite contribution) adds nothing, never NaN.
    """
    positive = lum > 0
    scale = jnp.where(positive, weight / jnp.where(positive, lum, 1.0), 0.0)
    value = scale[:, None] * rgb
    return film.at[pixel].add(jnp.where(jnp.isfinite(value), value, 0.0).astype(film.dtype))


def film_image(film: Float[Array, "P 3"], resolution: tuple[int, int], scale) -> Float[Array, "H W 3"]:
    """Reshape a film to `(H, W, 3)` (row `floor(u_1 H)`, column `floor(u_0 W)`) and scale it."""
    w, h = resolution
    return film.reshape(h, w, 3) * scale
