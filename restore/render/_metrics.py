"""Image error metrics against a reference, in one place (NumPy, float64).

All metrics average over every pixel and channel of images of equal shape, e.g.
`(H, W, 3)`. Conventions for zero reference values:
- `relative_mse` regularises the denominator with `eps` (default `1e-2`, the usual
  choice in the rendering literature, e.g. Rousselle et al. 2011), so zero reference
  pixels count as absolute squared error divided by `eps`.
- `mrse` and `mape` are strict relative errors: elements where the reference is zero
  have no relative error and are left out of the mean (a `ValueError` if all are zero).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike


def _pair(image: ArrayLike, reference: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    image, reference = np.asarray(image, np.float64), np.asarray(reference, np.float64)
    if image.shape != reference.shape:
        raise ValueError(f"image and reference shapes differ: {image.shape} vs {reference.shape}")
    if image.size == 0:
        raise ValueError("empty images")
    if not np.all(np.isfinite(reference)):
        raise ValueError("the reference image has non-finite values")
    return image, reference


def l1(image: ArrayLike, reference: ArrayLike) -> float:
    """Mean absolute error `mean |I - R|`."""
    image, reference = _pair(image, reference)
    return float(np.mean(np.abs(image - reference)))


def mse(image: ArrayLike, reference: ArrayLike) -> float:
    """Mean squared error `mean (I - R)^2` (the L2 error)."""
    image, reference = _pair(image, reference)
    return float(np.mean((image - reference) ** 2))


def relative_mse(image: ArrayLike, reference: ArrayLike, eps: float = 1e-2) -> float:
    """Relative MSE `mean (I - R)^2 / (R^2 + eps)`; `eps > 0` keeps dark pixels finite."""
    if not eps > 0:
        raise ValueError(f"eps must be positive, got {eps!r}")
    image, reference = _pair(image, reference)
    return float(np.mean((image - reference) ** 2 / (reference**2 + eps)))


def _strict_relative(image: np.ndarray, reference: np.ndarray) -> np.ndarray:
    nonzero = reference != 0
    if not nonzero.any():
        raise ValueError("every reference value is zero: relative errors are undefined")
    return (image[nonzero] - reference[nonzero]) / reference[nonzero]


def mrse(image: ArrayLike, reference: ArrayLike) -> float:
    """Mean relative squared error `mean ((I - R) / R)^2` over elements with `R != 0`."""
    return float(np.mean(_strict_relative(*_pair(image, reference)) ** 2))


def mape(image: ArrayLike, reference: ArrayLike) -> float:
    """Mean absolute percentage error `100 mean |I - R| / |R|` over elements with `R != 0`."""
    return float(100.0 * np.mean(np.abs(_strict_relative(*_pair(image, reference)))))


def variance_across(images: ArrayLike) -> float:
    """Empirical variance across independent realisations, averaged over pixels and channels.

    Arguments:
        images: `(R, ...)` with `R >= 2` independent renders of the same image; the
            per-element unbiased sample variance (`ddof=1`) over axis 0 is averaged.
    """
    images = np.asarray(images, np.float64)
    if images.ndim < 2 or images.shape[0] < 2:
        raise ValueError(f"need at least two realisations stacked on axis 0, got shape {images.shape}")
    return float(np.mean(np.var(images, axis=0, ddof=1)))


def relative_variance(images: ArrayLike, reference: ArrayLike, eps: float = 1e-2) -> float:
    """The variance across realisations relative to the reference, `mean var / (R^2 + eps)`: the
    part of the expected relative MSE that is noise (`relative_mse` less the squared bias).

    Arguments:
        images: `(R, ...)` with `R >= 2` independent renders (unbiased variance, `ddof=1`).
        reference: the reference image, shaped like one render.
        eps: as in `relative_mse`.
    """
    if not eps > 0:
        raise ValueError(f"eps must be positive, got {eps!r}")
    images = np.asarray(images, np.float64)
    if images.ndim < 2 or images.shape[0] < 2:
        raise ValueError(f"need at least two realisations stacked on axis 0, got shape {images.shape}")
    _, reference = _pair(images[0], reference)
    return float(np.mean(np.var(images, axis=0, ddof=1) / (reference**2 + eps)))
