"""Directions along which weighted draws are most nearly independent (whitening, then FastICA)."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

#: At most this many draws (a random subset, weights kept) are used to find the directions.
AXES_DRAWS = 16384
#: Fixed-point iterations of FastICA per contrast (fewer when every direction stops moving).
AXES_ITERATIONS = 30
#: Hyvarinen's weights of the two terms of his negentropy approximation (odd and even contrast).
_K_ODD, _K_EVEN = 36.0 / (8.0 * math.sqrt(3.0) - 9.0), 24.0 / (16.0 * math.sqrt(3.0) - 27.0)
#: The standard deviations of `u exp(-u^2/2)` and `exp(-u^2/2)` for a standard normal `u`,
#: and the mean of the latter: what a Gaussian direction's statistics come to.
_SD_ODD, _SD_EVEN, _MEAN_EVEN = math.sqrt(3.0**-1.5), math.sqrt(3.0**-0.5 - 0.5), math.sqrt(0.5)
#: A direction whose odd or even statistic is this many standard errors from a Gaussian's is non-Gaussian.
NON_GAUSSIAN_Z = 5.0

Contrast = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


def _log_cosh(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`g = G'` and `g'` of `G = log cosh`: sensitive to any departure from a Gaussian's tails or peak."""
    g = np.tanh(u)
    return g, 1.0 - g**2


def _skew(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`g = G'` and `g'` of `G = u^3 / 3`: sensitive to asymmetry (a double well with unequal wells)."""
    return u**2, 2.0 * u


class IndependentAxes(NamedTuple):
    """New coordinates `y = transform (x - centre)`, white and as independent as FastICA makes them.

    Attributes:
        centre: `(d,)` the draws' weighted mean.
        transform: `(d, d)` the matrix from `x - centre` to `y`.
        non_gaussian: `(d,)` which coordinates of `y` are clearly not Gaussian (the ones
            FastICA identifies; the others are any basis of what is left).
        gain: how much more the draws' mean log density under a product along these axes
            should be than under a product along the coordinate axes of `x` (nats; from
            Hyvarinen's negentropy approximation, which falls short of the true negentropy:
            a rough, low estimate). A product's expected log density in linear coordinates
            is the sum of its coordinates' negentropies less their Gaussian entropies, so
            the gain is the negentropies along these axes less those along the coordinate
            axes, plus the correlations' share (minus half the log determinant of the
            correlation matrix).
    """

    centre: np.ndarray
    transform: np.ndarray
    non_gaussian: np.ndarray
    gain: float = math.inf

    def along_coordinates(self, cosine: float = 0.99) -> bool:
        """Whether every non-Gaussian direction lies along a coordinate axis of `x` (then a
        product along the axes has the same structure), or there is none (draws that look
        Gaussian: one full covariance has it)."""
        rows = self.transform[self.non_gaussian]
        if rows.size == 0:
            return True
        return bool(np.all(np.max(np.abs(rows), axis=1) >= cosine * np.linalg.norm(rows, axis=1)))


def independent_axes(draws, weights, *, max_draws: int = AXES_DRAWS, iterations: int = AXES_ITERATIONS, seed: int = 0) -> IndependentAxes:
    """New coordinates `y = A (x - centre)` with unit weighted covariance, as independent as
    symmetric FastICA can make them.

    The draws are whitened (weighted mean and covariance), then rotated by symmetric FastICA
    (Hyvarinen and Oja 2000), weighted, so that each coordinate's distribution is as far from
    Gaussian as it can be (a double well is found as one coordinate). Two schedules are run
    from no rotation: the `log cosh` contrast alone, and the skewness contrast followed by
    `log cosh` (unequal wells, whose `log cosh` contrast can be weak, are found by their
    skewness first); the one whose directions have the larger total negentropy (Hyvarinen's
    approximation) is kept. Directions along which the draws are Gaussian cannot be told
    apart and are left as they come, which costs nothing to a product fit (any rotation of a
    white Gaussian is a product). Draws independent along the axes keep their axes.

    Raises:
        ValueError: for fewer than two draws, or draws that do not span every dimension.
    """
    x = np.asarray(draws, np.float64)
    w = np.asarray(weights, np.float64).reshape(-1)
    keep = np.isfinite(w) & (w > 0) & np.all(np.isfinite(x), axis=1)
    x, w = x[keep], w[keep]
    if x.shape[0] < 2:
        raise ValueError("need at least 2 draws with positive weight to find independent axes")
    if x.shape[0] > max_draws:
        pick = np.random.default_rng(seed).choice(x.shape[0], max_draws, replace=False)
        x, w = x[pick], w[pick]
    p = w / w.sum()
    centre = p @ x
    r = x - centre
    covariance = (r * p[:, None]).T @ r
    values, vectors = np.linalg.eigh(0.5 * (covariance + covariance.T))
    if not values[0] > 1e-12 * values[-1]:
        raise ValueError("the draws do not span every dimension: no independent axes")
    whiten = (vectors / np.sqrt(values)) @ vectors.T  # symmetric: no rotation of its own
    z = r @ whiten.T
    start = np.eye(x.shape[1])
    plain = _fastica(z, p, start, _log_cosh, iterations)
    skewed = _fastica(z, p, _fastica(z, p, start, _skew, iterations), _log_cosh, iterations)
    (odd, even), (odd_s, even_s) = _statistics(z @ plain.T, p), _statistics(z @ skewed.T, p)
    negentropy = lambda odd, even: float(np.sum(_K_ODD * odd**2 + _K_EVEN * even**2))  # noqa: E731
    rotation, odd, even = (skewed, odd_s, even_s) if negentropy(odd_s, even_s) > negentropy(odd, even) else (plain, odd, even)
    noise = math.sqrt(float(np.sum(p**2)))  # the standard error of a weighted mean, per unit standard deviation
    non_gaussian = (np.abs(odd) > NON_GAUSSIAN_Z * _SD_ODD * noise) | (np.abs(even) > NON_GAUSSIAN_Z * _SD_EVEN * noise)
    sd = np.sqrt(np.diag(covariance))
    correlation_share = -0.5 * float(np.linalg.slogdet(covariance / np.outer(sd, sd))[1])
    gain = negentropy(odd, even) - negentropy(*_statistics(r / sd, p)) + correlation_share
    return IndependentAxes(centre, rotation @ whiten, non_gaussian, gain)


def _fastica(z: np.ndarray, p: np.ndarray, rotation: np.ndarray, contrast: Contrast, iterations: int) -> np.ndarray:
    """Symmetric FastICA's fixed-point iterations from `rotation` (weights `p`), with the contrast's `g` and `g'`."""
    for _ in range(iterations):
        g, slope = contrast(z @ rotation.T)
        updated = (g * p[:, None]).T @ z - (p @ slope)[:, None] * rotation
        s, v = np.linalg.eigh(updated @ updated.T)
        updated = (v / np.sqrt(s)) @ v.T @ updated  # (W W^T)^{-1/2} W: the nearest rotation
        if not np.all(np.isfinite(updated)):  # a degenerate update: keep the last rotation
            break
        moved = np.max(np.abs(np.abs(np.sum(updated * rotation, axis=1)) - 1.0))
        rotation = updated
        if moved < 1e-10:
            break
    return rotation


def _statistics(u: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per direction, the weighted means of `u exp(-u^2/2)` (0 for a Gaussian) and of
    `exp(-u^2/2)` less a Gaussian's (`1/sqrt 2`): the two terms of the negentropy approximation."""
    e = np.exp(-0.5 * u**2)
    return p @ (u * e), p @ e - _MEAN_EVEN
