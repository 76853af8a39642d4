"""Laplace approximations at found modes as a candidate of the held-out family competition.

`find_modes` gives each mode of a target and its Hessian: for a Gaussian target that is the
target itself, and for a near-Gaussian one it is closer than any fit to a few thousand
draws of a poorly mixed chain can be. As a `Fit` (Student-t components with the Laplace
scale matrices, weighted by their Laplace evidence), `choose_regeneration` scores it on the
same held-out draws as the fitted families and takes it only where it wins. With Gaussian
components it is exact for a Gaussian target; with Student-t ones it forgives a Hessian
that understates the spread.
"""

from __future__ import annotations

import numpy as np

from ._fit import Fit, _mixture_fit
from ._laplace import LaplaceModes

#: Degrees of freedom of the Laplace candidate's Student-t components.
LAPLACE_DF = 5.0


def laplace_fit(modes: LaplaceModes, *, df: float | None = LAPLACE_DF, max_components: int | None = None) -> Fit:
    """The Laplace mixture of `modes` as a `Fit` labelled `"laplace"` (or `"laplace student-t(df=...)"`).

    Arguments:
        modes: the output of `find_modes`.
        df: degrees of freedom of the Student-t components (their scale matrices are the
            Laplace covariances), or `None` for Gaussian components.
        max_components: keep at most this many modes, those of largest Laplace evidence.
    """
    if not isinstance(modes, LaplaceModes):
        raise TypeError(f"modes must be a LaplaceModes (from find_modes), got {type(modes).__name__}")
    log_evidence = modes._log_evidences_np()
    order = np.argsort(-log_evidence, kind="stable")
    if max_components is not None:
        order = order[: max(1, int(max_components))]
    weights = np.exp(log_evidence[order] - log_evidence[order].max())
    weights = np.maximum(weights / weights.sum(), np.finfo(np.float64).tiny)
    means = np.asarray(modes.locations, np.float64)[order]
    covariances = np.asarray(modes.covariances, np.float64)[order]
    fit = _mixture_fit(weights / weights.sum(), means, 0.5 * (covariances + np.swapaxes(covariances, 1, 2)), df, diagonal=False)
    return fit._replace(family=fit.family.replace("full", "laplace", 1))
