"""A defensive mixture on the unit torus: uniform, or a narrow kernel around one of `K` centres."""

from __future__ import annotations

import math
from typing import final

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import logsumexp
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from .._validation import as_float_array, check_point, check_shape, is_concrete
from ._base import AbstractRegeneration
from ._utils import component_indices


@final
class TorusKernelMixture(AbstractRegeneration):
    """With probability `uniform_share` a uniform draw on `[0, 1)^d`, else a kernel draw
    around centre `k` (chosen with probability `exp(log_weights[k])`).

    The kernel adds to each coordinate of the centre a `N(0, bandwidth^2)` variable
    truncated to `[-1/2, 1/2)` and wraps the sum onto `[0, 1)`. On the torus the offset of a
    point from a centre within `[-1/2, 1/2)` is unique, so the density is exact with no sum
    over images: `prod_j phi(o_j / h) / (h Z)`, with `o` the nearest-image offset and
    `Z = erf(1 / (2 sqrt(2) h))` the truncation's mass (1 to float precision for `h < 0.1`).
    The uniform share keeps the density at least `uniform_share` everywhere, so a Restore
    sampler regenerating from it kills at least that fraction of the uniform rate: where the
    kernels miss the target's mass it behaves as with uniform regeneration (defensive
    importance sampling, Hesterberg 1995).

    Restore renderers learn such a mixture from their bootstrap paths
    (`restore.render.LearnedRegeneration`): centres drawn in proportion to luminance, so tours
    that start on bright paths are killed at a rate closer to the uniform average, and no
    longer last thousands of events.

    Attributes:
        centres: `(K, d)` kernel centres in `[0, 1)^d`.
        log_weights: `(K,)` normalised log weights of the centres.
        bandwidth: `h`, the kernels' standard deviation before truncation.
        uniform_share: the probability of a uniform draw, in `(0, 1)`.
        dim: `d` (static).
    """

    centres: Float[Array, "K d"]
    log_weights: Float[Array, " K"]
    bandwidth: Float[Array, ""]
    uniform_share: Float[Array, ""]
    dim: int = eqx.field(static=True)

    def __init__(self, centres: ArrayLike, bandwidth: ArrayLike, uniform_share: ArrayLike = 0.5, log_weights: ArrayLike | None = None):
        """Arguments:
            centres: `(K, d)` points of `[0, 1)^d`.
            bandwidth: the kernels' standard deviation, in `(0, 1/2]`.
            uniform_share: the probability of a uniform draw, in `(0, 1)`.
            log_weights: `(K,)` log weights of the centres (normalised here); default equal.

        Raises:
            ValueError: for centres that are not `(K, d)` with `K, d >= 1`, or (when concrete)
                outside `[0, 1)`, a bandwidth outside `(0, 1/2]`, a share outside `(0, 1)`, or
                log weights of another shape or not finite.
        """
        centres = as_float_array(centres, "centres")
        if centres.ndim != 2 or 0 in centres.shape:
            raise ValueError(f"`centres` must have shape (K, d) with K, d >= 1, got {centres.shape}.")
        dtype = centres.dtype
        bandwidth = jnp.asarray(bandwidth, dtype)
        uniform_share = jnp.asarray(uniform_share, dtype)
        if log_weights is None:
            log_weights = jnp.full((centres.shape[0],), -math.log(centres.shape[0]), dtype)
        else:
            log_weights = as_float_array(log_weights, "log_weights").astype(dtype)
            if log_weights.shape != centres.shape[:1]:
                raise ValueError(f"`log_weights` must have shape {centres.shape[:1]}, got {log_weights.shape}.")
        if is_concrete(centres, bandwidth, uniform_share, log_weights):
            c = np.asarray(centres)
            if not (np.all(c >= 0) and np.all(c < 1)):
                raise ValueError("`centres` must lie in [0, 1)^d.")
            if not 0 < float(bandwidth) <= 0.5:
                raise ValueError(f"`bandwidth` must be in (0, 1/2], got {float(bandwidth)!r}.")
            if not 0 < float(uniform_share) < 1:
                raise ValueError(f"`uniform_share` must be in (0, 1), got {float(uniform_share)!r}.")
            if not np.all(np.isfinite(np.asarray(log_weights))):
                raise ValueError("`log_weights` must be finite.")
        self.centres = centres
        self.log_weights = log_weights - logsumexp(log_weights)
        self.bandwidth = bandwidth
        self.uniform_share = uniform_share
        self.dim = centres.shape[1]

    @property
    def num_components(self) -> int:
        return self.centres.shape[0]

    def _half_width(self) -> Array:
        """The truncation point in units of the bandwidth: `1 / (2 h)`."""
        return 0.5 / self.bandwidth

    def sample(self, key: PRNGKeyArray, shape: tuple[int, ...] = ()) -> Float[Array, "*shape d"]:
        """Exact draws: uniform with probability `uniform_share`, else a wrapped truncated-normal kernel draw."""
        shape = check_shape(shape)
        dtype = self.centres.dtype
        k_pick, k_centre, k_offset, k_uniform = jax.random.split(key, 4)
        uniform = jax.random.uniform(k_uniform, shape + (self.dim,), dtype)
        centre = self.centres[component_indices(k_centre, self.log_weights, shape, dtype)]
        a = self._half_width()
        offset = self.bandwidth * jax.random.truncated_normal(k_offset, -a, a, shape + (self.dim,), dtype)
        kernel = centre + offset
        kernel = kernel - jnp.floor(kernel)
        kernel = jnp.where(kernel >= 1, 0.0, kernel)  # `x - floor(x)` rounds up to 1 for tiny negative x
        pick_uniform = jax.random.uniform(k_pick, shape, dtype) < self.uniform_share
        return jnp.where(pick_uniform[..., None], uniform, kernel)

    def log_prob(self, x: Float[Array, " d"]) -> Float[Array, ""]:
        """`log(s + (1 - s) sum_k w_k kernel_k(x))` on `[0, 1)^d`, exactly `-inf` outside."""
        x = check_point(x, self.dim, "x")
        offset = x - self.centres
        offset = offset - jnp.round(offset)  # the nearest image, in [-1/2, 1/2]
        h = self.bandwidth
        a = self._half_width()
        log_norm = jnp.log(h) + 0.5 * math.log(2 * math.pi) + jnp.log(jax.scipy.special.erf(a / math.sqrt(2)))
        log_kernels = -0.5 * jnp.sum((offset / h) ** 2, axis=-1) - self.dim * log_norm
        log_kernel = logsumexp(self.log_weights + log_kernels)
        value = jnp.logaddexp(jnp.log(self.uniform_share), jnp.log1p(-self.uniform_share) + log_kernel)
        inside = jnp.all((x >= 0) & (x < 1))
        return jnp.where(inside, value, -jnp.inf)
