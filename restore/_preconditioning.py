"""The proposal factor of correlated local moves, from a regeneration's full-covariance components."""

from __future__ import annotations

import numpy as np

from .regeneration import AbstractRegeneration, Mixture


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
