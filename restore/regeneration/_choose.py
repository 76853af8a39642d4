"""Choose a regeneration family and size from weighted draws, by held-out likelihood.

The efficiency of a Restore run depends on how close the regeneration `u` is to the
target: with pi-invariant local dynamics the kill rate is `c_tilde u / p`, constant when
`u = pi`. Closeness in Kullback-Leibler divergence `KL(pi || u)` is, up to a constant,
minus the expected `log u` under `pi`, which weighted draws of `pi` estimate. So every
candidate (family and number of components) is fitted to most of the draws and scored by
the weighted mean `log u` of the rest; draws are split by group (lane or chain), because
draws of one lane are correlated. Bigger models must earn their cost: the cheapest
candidate within `tolerance` nats of the best wins, and no candidate may cost more than
`max_cost` multiply-adds per evaluation, since a Restore step evaluates `u` every time.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from ._fit import Fit, fit_mixture, fit_product

#: The families tried by default, cheapest first.
FAMILIES = ("product", "diagonal", "diagonal-t", "full", "full-t")
#: Degrees of freedom of the Student-t families.
STUDENT_DF = 5.0


class Candidate(NamedTuple):
    """One fitted candidate and its held-out score (weighted mean log density, nats)."""

    family: str
    num_components: int
    cost: int
    score: float


class Choice(NamedTuple):
    """The chosen fit (refitted on all draws) and every candidate that was scored."""

    fit: Fit
    candidates: tuple[Candidate, ...]


def _fit(family: str, x, w, k: int, seed: int) -> Fit:
    if family == "product":
        return fit_product(x, w, k, seed=seed)
    covariance = "diagonal" if family.startswith("diagonal") else "full"
    df = STUDENT_DF if family.endswith("-t") else None
    return fit_mixture(x, w, k, covariance=covariance, df=df, seed=seed)


def _cost(family: str, k: int, d: int) -> int:
    return k * d * d if family.startswith("full") else k * d


def choose_regeneration(
    draws,
    weights,
    groups,
    *,
    families: Sequence[str] = FAMILIES,
    max_components: int = 64,
    max_cost: int | None = None,
    holdout: float = 0.25,
    tolerance: float = 0.02,
    max_draws: int = 20_000,
    seed: int = 0,
) -> Choice:
    """Fit each family with 1, 2, 4, ... components and keep the best by held-out likelihood.

    Arguments:
        draws: `(n, d)` weighted draws of the target (e.g. a Restore run's stored draws).
        weights: `(n,)` their weights.
        groups: `(n,)` group labels (lanes, chains); whole groups are held out.
        families: among `"product"`, `"diagonal"`, `"diagonal-t"`, `"full"`, `"full-t"`.
        max_components: the largest number of components tried.
        max_cost: the largest cost (multiply-adds per log density) allowed; default
            `max(4096, 64 d)`.
        holdout: share of the groups held out for scoring.
        tolerance: a costlier candidate must score this many nats better.
        max_draws: fits use at most this many draws (a random subset).
        seed: seed of the split, the subset and the initialisations.

    Returns:
        The chosen candidate refitted on all (subset) draws, and the scored candidates.
    """
    x = np.asarray(draws, np.float64)
    w = np.asarray(weights, np.float64).reshape(-1)
    g = np.asarray(groups).reshape(-1)
    d = x.shape[1]
    unknown = [f for f in families if f not in FAMILIES]
    if unknown or not families:
        raise ValueError(f"families must be a non-empty subset of {FAMILIES}, got {tuple(families)}")
    rng = np.random.default_rng(seed)
    ok = np.isfinite(w) & (w > 0) & np.all(np.isfinite(x), axis=1)
    x, w, g = x[ok], w[ok], g[ok]
    if x.shape[0] > max_draws:
        pick = rng.choice(x.shape[0], max_draws, replace=False, p=None)
        x, w, g = x[pick], w[pick], g[pick]
    labels = np.unique(g)
    if labels.size < 4:
        raise ValueError(f"need draws from at least 4 groups (lanes or chains) to hold some out, got {labels.size}")
    held = rng.choice(labels, max(1, round(holdout * labels.size)), replace=False)
    test = np.isin(g, held)
    max_cost = max(4096, 64 * d) if max_cost is None else int(max_cost)

    candidates: list[Candidate] = []
    for family in families:
        best_here = -math.inf
        k = 1
        while k <= max_components and _cost(family, k, d) <= max_cost and k <= max(1, (~test).sum() // (4 * d + 4)):
            try:
                fit = _fit(family, x[~test], w[~test], k, seed)
            except (ValueError, np.linalg.LinAlgError):
                break
            logp = fit.log_prob(x[test])
            score = float(np.sum(w[test] * logp) / np.sum(w[test])) if np.all(np.isfinite(logp)) else -math.inf
            candidates.append(Candidate(fit.family, k, fit.cost, score))
            if score < best_here + tolerance / 4:  # no longer improving: larger K will not either
                break
            best_here = max(best_here, score)
            k *= 2
    if not candidates:
        raise ValueError("no regeneration family could be fitted to these draws")
    best = max(c.score for c in candidates)
    chosen = min((c for c in candidates if c.score >= best - tolerance), key=lambda c: (c.cost, -c.score))
    family = next(f for f in families if _fit_name(f) == chosen.family)
    return Choice(_fit(family, x, w, chosen.num_components, seed), tuple(candidates))


def _fit_name(family: str) -> str:
    """The `Fit.family` label of a family name."""
    base = "diagonal" if family.startswith("diagonal") else "full" if family.startswith("full") else "product"
    return base + (f" student-t(df={STUDENT_DF:g})" if family.endswith("-t") else "")
