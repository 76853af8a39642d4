"""A product of one-dimensional mixtures in linearly transformed coordinates."""

from __future__ import annotations

from typing import final

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from .._validation import as_float_array, check_point, check_shape
from ._base import AbstractRegeneration
from ._product_mixture import ProductMixture


@final
class RotatedProductMixture(AbstractRegeneration):
    """`x = centre + A^{-1} y` with `y` drawn from a `ProductMixture`: independent coordinates in another basis.

    `u(x) = |det A| v(A (x - centre))` with `v` the product of one-dimensional mixtures.
    A target whose modes come in product form along directions that are not the
    coordinate axes (a Many Well seen through a rotation, say) has exponentially many
    modes that no mixture of a few components covers, and that a product along the axes
    does not fit either; along the right directions a product covers all of them. The
    directions are found from draws by independent component analysis
    (`restore.regeneration.independent_axes`). An evaluation costs `O(d^2 + K d)`.

    Attributes:
        product: the distribution `v` of `y` (a `ProductMixture`).
        centre: `(d,)` the origin of the new coordinates.
        transform: `(d, d)` the matrix `A` (`y = A (x - centre)`).
        inverse: `(d, d)` its inverse.
        log_det: `log |det A|`.
        dim: the dimension `d` (static).
    """

    product: ProductMixture
    centre: Float[Array, " d"]
    transform: Float[Array, "d d"]
    inverse: Float[Array, "d d"]
    log_det: Float[Array, ""]
    dim: int = eqx.field(static=True)

    def __init__(self, product: ProductMixture, centre: ArrayLike, transform: ArrayLike):
        """Arguments:
            product: the distribution of the new coordinates `y = A (x - centre)`.
            centre: `(d,)` finite.
            transform: `(d, d)` finite and invertible, the matrix `A`.
        """
        if not isinstance(product, ProductMixture):
            raise TypeError(f"product must be a restore.regeneration.ProductMixture, got {type(product).__name__}")
        d = product.dim
        centre = check_point(centre, d, "centre", finite=True)
        transform = as_float_array(transform, "transform")
        if transform.shape != (d, d):
            raise ValueError(f"transform must have shape ({d}, {d}), got {transform.shape}")
        a = np.asarray(transform, np.float64)
        if not np.all(np.isfinite(a)):
            raise ValueError("transform must be finite")
        sign, log_det = np.linalg.slogdet(a)
        if sign == 0 or not np.isfinite(log_det) or np.linalg.cond(a) > 1e12:
            raise ValueError("transform must be invertible (its condition number is above 1e12)")
        dtype = product.means.dtype
        self.product = product
        self.centre = jnp.asarray(centre, dtype)
        self.transform = jnp.asarray(a, dtype)
        self.inverse = jnp.asarray(np.linalg.inv(a), dtype)
        self.log_det = jnp.asarray(log_det, dtype)
        self.dim = d

    def log_prob(self, x: Float[Array, " d"]) -> Float[Array, ""]:
        x = check_point(x, self.dim, "x")
        # `r @ A.T` rather than `A @ r`: the form that stays right over many lanes (tests/unit/test_many_lanes.py)
        return self.product.log_prob((x - self.centre) @ self.transform.T) + self.log_det

    def sample(self, key: PRNGKeyArray, shape: tuple[int, ...] = ()) -> Float[Array, "*shape d"]:
        shape = check_shape(shape)
        return self.centre + self.product.sample(key, shape) @ self.inverse.T
