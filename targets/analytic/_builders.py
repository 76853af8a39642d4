"""Ready-made well-separated mixtures for tests and demos."""

from __future__ import annotations

import itertools
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, PRNGKeyArray

from . import _checks
from ._gaussian_mixture import GaussianMixture
from ._student_t_mixture import StudentTMixture


def separated_points(dim: int, num_points: int, distance: float) -> np.ndarray:
    """`num_points` points in R^dim, centred at the origin, pairwise at least `distance` apart.

    Deterministic. If `num_points <= dim + 1` they are the vertices of a regular
    simplex (every pair exactly `distance` apart); otherwise they are the first
    `num_points` nodes (in lexicographic order) of a cubic grid of spacing
    `distance` (in 1-D: equally spaced on a line).
    """
    k = num_points
    if k <= dim + 1:
        # Unit vectors e_1..e_k of R^k, centred, are a regular simplex with edge sqrt(2)
        # inside a (k-1)-dimensional subspace; express them in an orthonormal basis of it.
        vertices = np.eye(k) - 1.0 / k
        _, _, vt = np.linalg.svd(vertices)
        coords = vertices @ vt[: k - 1].T * (distance / math.sqrt(2.0))
        points = np.zeros((k, dim))
        points[:, : k - 1] = coords
    else:
        side = 1
        while side**dim < k:
            side += 1
        nodes = list(itertools.islice(itertools.product(range(side), repeat=dim), k))
        points = np.asarray(nodes, dtype=np.float64) * distance
    return points - points.mean(axis=0)


def _default_weights(k: int) -> np.ndarray:
    w = np.arange(1, k + 1, dtype=np.float64)
    return w / w.sum()


def _numpy_rng(key: PRNGKeyArray) -> np.random.Generator:
    # Construction-time randomness in NumPy, seeded by the JAX key: deterministic per key
    # and free of XLA compilation.
    key = jnp.asarray(key)
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        key = jax.random.key_data(key)
    return np.random.default_rng(np.asarray(key, dtype=np.uint32).ravel().tolist())


def _random_rotation(rng: np.random.Generator, dim: int) -> np.ndarray:
    q, r = np.linalg.qr(rng.standard_normal((dim, dim)))
    return q * np.where(np.diag(r) < 0, -1.0, 1.0)


def _check_common(
    dim: Any, num_modes: Any, spread: Any, scale: Any, spread_name: str = "separation"
) -> tuple[int, int, float, float]:
    return (
        _checks.integer(dim, "dim", 1),
        _checks.integer(num_modes, "num_modes", 1),
        _checks.positive_float(spread, spread_name),
        _checks.positive_float(scale, "scale"),
    )


def well_separated_gaussian_mixture(
    dim: int,
    num_modes: int = 3,
    *,
    separation: float = 8.0,
    weights: ArrayLike | None = None,
    scale: float = 1.0,
    key: PRNGKeyArray | None = None,
) -> GaussianMixture:
    """A Gaussian mixture whose modes are far apart relative to their widths.

    The means are `separated_points(dim, num_modes, separation * scale)`: a regular
    simplex (all pairs exactly `separation * scale` apart) when `num_modes <= dim + 1`,
    otherwise a cubic grid (a line in 1-D). With `key=None` the result is
    deterministic and every covariance is `scale^2 * I`. With a key the means are
    rotated at random and each covariance is `scale^2 R_k diag(lambda_k) R_k^T` with a
    random rotation `R_k` and eigenvalues `lambda_k` uniform in `[0.75, 1.25]`
    (mildly anisotropic). The default weights are unequal on purpose,
    proportional to `1, 2, ..., num_modes` (for 3 modes: 1/6, 2/6, 3/6), so a
    sampler that gets the mass of each mode wrong is caught.

    Arguments:
        dim: the dimension, `>= 1`.
        num_modes: the number of components, `>= 1`.
        separation: minimum distance between means in units of `scale`; at the
            default 8 a draw is attributed to the wrong mode with probability of
            order `Phi(-4) ~ 3e-5`, so `assign_mode` is essentially exact.
        weights: positive weights of shape `(num_modes,)`, normalised; `None` for
            the unequal default above.
        scale: the standard deviation of every component (before anisotropy).
        key: optional PRNG key for a random rotation and anisotropy.

    Raises:
        ValueError: on a non-positive dimension, mode count, separation or scale,
            or weights of the wrong shape or sign.
    """
    dim, k, separation, scale = _check_common(dim, num_modes, separation, scale)
    means = separated_points(dim, k, separation * scale)
    if key is None:
        covariances = np.full((k,), scale**2)
    else:
        rng = _numpy_rng(key)
        means = means @ _random_rotation(rng, dim).T
        eigs = rng.uniform(0.75, 1.25, size=(k, dim))
        rots = [_random_rotation(rng, dim) for _ in range(k)]
        covariances = np.stack([scale**2 * (r * e) @ r.T for r, e in zip(rots, eigs)])
    if weights is None:
        weights = _default_weights(k)
    return GaussianMixture(jnp.asarray(means), jnp.asarray(covariances), weights)


def well_separated_student_t_mixture(
    dim: int,
    num_modes: int = 3,
    *,
    separation: float = 10.0,
    df: float = 5.0,
    weights: ArrayLike | None = None,
    scale: float = 1.0,
) -> StudentTMixture:
    """A Student-t mixture whose modes are far apart relative to their scales.

    Means placed as in `well_separated_gaussian_mixture` (at least
    `separation * scale` apart), every scale matrix `scale^2 * I`, one shared `df`,
    and by default the unequal weights proportional to `1, ..., num_modes`.
    Heavy tails make mode attribution less certain than for Gaussians: for two
    modes `separation * scale` apart a draw crosses the midpoint with probability
    `P(T_df > separation / 2)` (about `2e-3` at the defaults).

    Arguments:
        dim: the dimension, `>= 1`.
        num_modes: the number of components, `>= 1`.
        separation: minimum distance between locations in units of `scale`.
        df: degrees of freedom shared by all components, positive (the mean needs
            `df > 1`, the covariance `df > 2`).
        weights: positive weights of shape `(num_modes,)`; `None` for the default.
        scale: the scale of every component.

    Raises:
        ValueError: on invalid sizes, separation, scale, `df` or weights.
    """
    dim, k, separation, scale = _check_common(dim, num_modes, separation, scale)
    df = _checks.positive_float(df, "df")
    means = separated_points(dim, k, separation * scale)
    if weights is None:
        weights = _default_weights(k)
    return StudentTMixture(jnp.asarray(means), jnp.full((k,), scale**2), df, weights)


def spread_gaussian_mixture(
    dim: int = 2,
    num_modes: int = 40,
    *,
    half_width: float = 40.0,
    scale: float = 1.0,
    key: PRNGKeyArray | None = None,
) -> GaussianMixture:
    """Many equal-weight Gaussian modes scattered uniformly at random over a box.

    The means are drawn uniformly in `[-half_width, half_width]^dim` (NumPy, seeded by
    `key`; `key=None` is `jax.random.key(0)`, so the default mixture is always the same)
    and every covariance is `scale^2 * I`. With the defaults this is the 40-mode 2-d
    mixture of the flow annealed importance sampling benchmarks (Midgley et al. 2023):
    modes of unit width tens of units apart, some of them close enough to overlap.
    Nothing keeps modes apart, so `assign_mode` can disagree with the generating
    component where two modes overlap.

    Arguments:
        dim: the dimension, `>= 1`.
        num_modes: the number of components, `>= 1`.
        half_width: the means lie in `[-half_width, half_width]^dim`, positive.
        scale: the standard deviation of every component, positive.
        key: optional PRNG key that fixes the means.

    Raises:
        ValueError: on a non-positive dimension, mode count, half width or scale.
    """
    dim, k, half_width, scale = _check_common(dim, num_modes, half_width, scale, "half_width")
    rng = _numpy_rng(jax.random.key(0) if key is None else key)
    means = rng.uniform(-half_width, half_width, size=(k, dim))
    return GaussianMixture(jnp.asarray(means), jnp.asarray(scale**2))
