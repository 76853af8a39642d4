"""The film: per-pixel sums of weighted contributions `rgb / luminance`, filled by scatter-add."""

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
    contribution: Float[Array, "N 3"],
) -> Float[Array, "P 3"]:
    """Add `weight * contribution` of each lane to its pixel (a non-finite value adds nothing, never NaN).

    `contribution` is `rgb / lum` (the aux of `pss_logdensity`), zero where `lum = 0`.
    """
    value = weight[:, None] * contribution
    return film.at[pixel].add(jnp.where(jnp.isfinite(value), value, 0.0).astype(film.dtype))


def film_image(film: Float[Array, "P 3"], resolution: tuple[int, int], scale) -> Float[Array, "H W 3"]:
    """Reshape a film to `(H, W, 3)` (row `floor(u_1 H)`, column `floor(u_0 W)`) and scale it."""
    w, h = resolution
    return film.reshape(h, w, 3) * scale
