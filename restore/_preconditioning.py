"""The proposal factors of local moves, from a regeneration's components: one typical factor
(`typical_scale_tril`), or every component's, for moves sized to where the walk is (`guide_components`)."""

from __future__ import annotations

import numpy as np

from .regeneration import AbstractRegeneration, DiagonalMixture, Gaussian, Mixture, StudentT, UniformBox


def typical_scale_tril(regeneration: AbstractRegeneration, scales: np.ndarray) -> np.ndarray | None:
    """A lower-triangular `L` with `L L^T = D R D`, or `None` when there are no correlations to follow.

    `R` is the correlation matrix of the weighted mean within-component covariance (scale
    matrix) of the regeneration's full-covariance components, and `D = diag(scales)` the
    typical per-coordinate scales (`typical_scale`, a weighted median that a few broad
    components cannot inflate). For one Gaussian or Student-t component, `L L^T` is its
    covariance (scale matrix). `None` for families without full covariances (diagonal
    mixtures, products), whose local moves stay axis-aligned.
    """
    components = regeneration.components if isinstance(regeneration, Mixture) else (regeneration,)
    trils = [getattr(c, "scale_tril", None) for c in components]
    if any(t is None for t in trils):
        return None
    weights = np.asarray(regeneration.weights, np.float64) if isinstance(regeneration, Mixture) else np.ones(1)
    factors = np.asarray(np.stack([np.asarray(t, np.float64) for t in trils]))
    within = np.einsum("k,kij,klj->il", weights / weights.sum(), factors, factors)
    sd = np.sqrt(np.diag(within))
    correlation = within / np.outer(sd, sd)
    covariance = correlation * np.outer(scales, scales)
    try:
        tril = np.linalg.cholesky(0.5 * (covariance + covariance.T))
    except np.linalg.LinAlgError:
        return None
    return tril if np.all(np.isfinite(tril)) else None


def guide_components(regeneration: AbstractRegeneration) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """`(log_weights (K,), means (K, d), scale_trils (K, d, d))` of a regeneration's components, or `None`.

    Mixtures (nested ones too) are flattened, their weights multiplied; a Gaussian or
    Student-t component gives its location and scale factor, a diagonal mixture one
    diagonal factor per component, a uniform box a Gaussian of the box's mean and
    standard deviations. `None` for families with no per-component factors (products of
    one-dimensional mixtures); the guide of `restore.local.GuidedRandomWalk`.
    """
    if isinstance(regeneration, Mixture):
        parts = []
        for component, outer in zip(regeneration.components, np.asarray(regeneration.log_weights, np.float64), strict=True):
            part = guide_components(component)
            if part is None:
                return None
            parts.append((part[0] + outer, part[1], part[2]))
        weights, locations, factors = zip(*parts, strict=True)
        return np.concatenate(weights), np.concatenate(locations), np.concatenate(factors)
    if isinstance(regeneration, DiagonalMixture):
        scales = np.asarray(regeneration.scales, np.float64)
        trils = scales[:, :, None] * np.eye(scales.shape[1])
        return np.asarray(regeneration.log_weights, np.float64), np.asarray(regeneration.means, np.float64), trils
    if isinstance(regeneration, (Gaussian, StudentT)):
        mean = regeneration.mean if isinstance(regeneration, Gaussian) else regeneration.loc
        return np.zeros(1), np.asarray(mean, np.float64)[None], np.asarray(regeneration.scale_tril, np.float64)[None]
    if isinstance(regeneration, UniformBox):
        low, high = np.asarray(regeneration.low, np.float64), np.asarray(regeneration.high, np.float64)
        return np.zeros(1), (0.5 * (low + high))[None], np.diag((high - low) / np.sqrt(12.0))[None]
    return None
