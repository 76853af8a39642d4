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

What the search costs is kept small: products of one-dimensional mixtures are fitted to
every draw (their EM runs on binned coordinates; the rotated products' directions are
found once, from the training draws), mixtures over all coordinates to a random subset of
`mixture_draws`, the Student-t families only from the size that their Gaussian family
scored best with, and candidates are scored on at most `mixture_draws` held-out draws.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import NamedTuple

import numpy as np

from ._conditional_fit import conditional_cost, fit_conditional
from ._fit import Fit, ProductData, fit_binned_product, fit_mixture, product_data, rotated
from ._independent_axes import independent_axes

#: The families tried by default, cheapest first.
FAMILIES = ("product", "diagonal", "diagonal-t", "rotated-product", "conditional", "conditional-t", "full", "full-t")
#: The families fitted as products of one-dimensional mixtures (on binned coordinates).
PRODUCTS = ("product", "rotated-product")
#: Degrees of freedom of the Student-t families.
STUDENT_DF = 5.0
#: A fit is padded to the size a run was compiled for (`sizes`) when that is at most this many
#: times its own number of components (beyond that, padding costs more per step than compiling).
PAD_LIMIT = 4
#: With `sizes`, a candidate that no run has been compiled for must score this many nats
#: better than the best one that runs on a compiled program (compiling a run takes seconds).
RECOMPILE_GAIN = 0.1
#: A family's search stops (from 4 components on) when it trails the best candidate by more
#: than this many times its largest gain per doubling so far, over every doubling it has left.
HOPELESS = 3.0


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


#: A rotated product is fitted beside the plain product only when its directions are expected to
#: raise the mean log density by at least this many nats (`IndependentAxes.gain`, a low
#: estimate; the measurements behind the value are in docs/how-to/regeneration.md).
AXES_GAIN = 0.25

#: The Student-t version of the conditional family is fitted only when the Gaussian one trails the
#: best candidate by at most this many nats per coordinate (on 8,000 draws of 10-d Student-t
#: targets with 2.5, 3 and 5 degrees of freedom, its tails gained 0.49, 0.23 and 0.04 nats per
#: coordinate; on exact Many-Well-32 draws the Gaussian one trails the product by 0.67).
TAIL_GAIN = 0.5

#: After a choice, a later one (`autosample`'s next stage) fits again only the families whose best
#: candidate trailed the best one by at most this many nats per coordinate, and the families built
#: on those (`close_families`). On Many-Well-32 the Gaussian and conditional families trail the
#: product by 0.63-0.69 nats per coordinate on the seeding chains' draws; on Neal's funnel every
#: family stays within 0.06 of the best through its twelve stages.
FAMILY_GAIN = 0.5

#: EM iterations of a mixture candidate during the search (the chosen one is refitted to convergence).
SEARCH_ITERATIONS = 30


class _Products(NamedTuple):
    """The draws as the product families fit them: binned (training draws, all draws) and, for
    the rotated products, the directions `(centre, A)` found from the training draws."""

    train: ProductData
    all: ProductData
    axes: tuple[np.ndarray, np.ndarray] | None = None


def _products(x: np.ndarray, w: np.ndarray, test: np.ndarray, axes: tuple[np.ndarray, np.ndarray] | None = None) -> _Products:
    """Every training draw, and every draw, binned once (after one sort), in the coordinates `axes` gives."""
    if axes is not None:
        x = (x - axes[0]) @ axes[1].T
    order = np.argsort(x, axis=0)
    kept = (~test)[order]  # (n, d): whether each coordinate's next draw in order is a training draw
    rank = np.cumsum(~test) - 1  # a draw's index among the training draws
    train_order = rank[order.T[kept.T].reshape(x.shape[1], -1).T]
    return _Products(product_data(x[~test], w[~test], train_order), product_data(x, w, order), axes)


def _fit(family: str, x, w, k: int, seed: int, start: Fit | None = None, binned: ProductData | None = None, iterations: int = 100,
         axes: tuple[np.ndarray, np.ndarray] | None = None) -> Fit:  # fmt: skip
    """A fit of `family` with `k` components (`start`: a fit to start a mixture's EM from;
    `binned`: the draws binned for a product, in the coordinates of `axes` for a rotated one)."""
    if family in PRODUCTS:
        if family == "rotated-product" and (binned is None or axes is None):
            raise ValueError("a rotated product is fitted to binned draws in its own coordinates")
        fit = fit_binned_product(product_data(x, w) if binned is None else binned, k, seed=seed, start=start)
        return fit if axes is None else rotated(fit, *axes)
    if family.startswith("conditional"):
        return fit_conditional(x, w, df=STUDENT_DF if family.endswith("-t") else None)
    covariance = "diagonal" if family.startswith("diagonal") else "full"
    df = STUDENT_DF if family.endswith("-t") else None
    init: dict = {}
    if start is not None and start.parameters is not None:
        p = start.parameters
        init = dict(init_means=p["means"], init_covariances=p["covariances"], init_weights=p["weights"])
    return fit_mixture(x, w, k, covariance=covariance, df=df, seed=seed, iterations=iterations, **init)


def _cost(family: str, k: int, d: int) -> int:
    if family == "rotated-product":
        return d * d + k * d
    if family.startswith("conditional"):
        return conditional_cost(d)
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
    max_draws: int = 100_000,
    mixture_draws: int = 8192,
    sizes: Mapping[str, int] | None = None,
    extra: Sequence[Fit] = (),
    seed: int = 0,
) -> Choice:
    """Fit each family with 1, 2, 4, ... components and keep the best by held-out likelihood.

    Arguments:
        draws: `(n, d)` weighted draws of the target (e.g. a Restore run's stored draws).
        weights: `(n,)` their weights.
        groups: `(n,)` group labels (lanes, chains); whole groups are held out.
        families: among `"product"`, `"diagonal"`, `"diagonal-t"`, `"rotated-product"`
            (a product along the directions in which the draws are most nearly
            independent: `RotatedProductMixture`), `"conditional"`, `"conditional-t"`
            (each coordinate Gaussian, or Student-t, given the earlier ones, a curved fit:
            `ConditionalGaussian`; one component), `"full"`, `"full-t"`.
            A Student-t family is tried from the number of components its Gaussian family
            scored best with (when that family is tried too), doubling while it improves;
            so is a rotated product from the product's.
        max_components: the largest number of components tried.
        max_cost: the largest cost (multiply-adds per log density) allowed; default
            `max(4096, 64 d)`.
        holdout: share of the groups held out for scoring.
        tolerance: a costlier candidate must score this many nats better.
        max_draws: at most this many draws are used (a random subset); products of
            one-dimensional mixtures are fitted to all of them.
        mixture_draws: mixtures over all coordinates are fitted to at most this many
            draws (a random subset), and candidates scored on at most this many.
        sizes: for some `Fit.family` labels, a number of components a run has been compiled
            for already (`Fit.padded`): a candidate of that family that would be padded to
            it (`padded_size`) costs as much as that many components, so among those the
            best scoring one is chosen; and any other candidate must score `RECOMPILE_GAIN`
            nats better than the best of those to be chosen.
        extra: fits made elsewhere (e.g. `laplace_fit` of a target's modes), scored on the
            same held-out draws and chosen by the same rules; chosen, one is returned as it
            is (it was not fitted to these draws, so it is not refitted).
        seed: seed of the split, the subsets and the initialisations.

    Returns:
        The chosen candidate refitted on all (subset) draws, and the scored candidates.
    """
    unknown = [f for f in families if f not in FAMILIES]
    if unknown or not families:
        raise ValueError(f"families must be a non-empty subset of {FAMILIES}, got {tuple(families)}")
    split = _split(draws, weights, groups, holdout, max_draws, mixture_draws, seed)
    x, w, test, train, rng = split.x, split.w, split.test, split.train, split.rng
    d = x.shape[1]
    max_cost = default_max_cost(d) if max_cost is None else int(max_cost)
    sizes = dict(sizes or {})

    def cost(family: str, k: int) -> int:
        return _cost(family, padded_size(k, sizes.get(_fit_name(family))), d)

    candidates: list[Candidate] = []
    fits: dict[tuple[str, int], Fit] = {}
    products: dict[str, _Products] = {}
    if "product" in families:
        products["product"] = _products(x, w, test)
    if "rotated-product" in families:
        try:
            axes = independent_axes(x[~test], w[~test], seed=seed)
        except (ValueError, np.linalg.LinAlgError):
            axes = None  # draws that span too few directions
        # tried unless the plain product has the same structure (or a full covariance has it),
        # or the rotation is not expected to gain much over the coordinate axes
        plain = "product" in families and (axes is None or axes.along_coordinates() or axes.gain < AXES_GAIN)
        if axes is not None and not plain:
            products["rotated-product"] = _products(x, w, test, (axes.centre, axes.transform))
    for family in families:
        if family in PRODUCTS and family not in products:
            continue
        on = np.flatnonzero(~test) if family in PRODUCTS else train
        prepared = products.get(family)
        largest = 1 if family.startswith("conditional") else min(max_components, max(1, on.size // (4 * d + 4)))
        base = _base(family)
        k, start = 1, None
        if base != family and base in families:  # the Student-t version from the size its Gaussian family liked best
            scored_base = [c for c in candidates if c.family == _fit_name(base)]
            if scored_base:
                k = max(scored_base, key=lambda c: c.score).num_components
                start = fits.get((base, k)) if family.endswith("-t") else None  # (a rotated product fits other coordinates)
        if family == "conditional-t" and _far_behind([c for c in candidates if c.family == "conditional"], candidates, d):
            continue  # heavier tails will not close the gap
        best_here, gain = -math.inf, 0.0
        while k <= largest and _cost(family, k, d) <= max_cost:
            try:
                fit = _fit(
                    family, x[on], w[on], k, seed, start=start, binned=None if prepared is None else prepared.train,
                    iterations=SEARCH_ITERATIONS, axes=None if prepared is None else prepared.axes,
                )  # fmt: skip
            except (ValueError, np.linalg.LinAlgError):
                break
            start = None
            score = split.score(fit)
            candidates.append(Candidate(fit.family, k, cost(family, k), score))
            fits[family, k] = fit
            if score < best_here + tolerance / 4:  # no longer improving: larger K will not either
                break
            gain = max(gain, score - best_here) if math.isfinite(best_here) else 0.0
            best_here = score
            ahead = max(c.score for c in candidates)
            doublings = math.floor(math.log2(largest / k))
            if k >= 4 and ahead - score > HOPELESS * gain * doublings + tolerance:
                break  # even gains several times its best so far would leave this family behind
            k *= 2
    given = {}
    for fit in extra:
        score = split.score(fit)
        k = fit.num_components
        size = padded_size(k, sizes.get(fit.family))
        candidate = Candidate(fit.family, k, fit.cost * size // k, score)
        if candidate.cost <= max_cost and math.isfinite(score):
            candidates.append(candidate)
            given[candidate] = fit
    if not candidates:
        raise ValueError("no regeneration family could be fitted to these draws")
    admissible = candidates
    free = [c for c in candidates if c.family in sizes and padded_size(c.num_components, sizes[c.family]) == sizes[c.family]]
    if free:  # a candidate that needs a program compiled anew must be clearly better
        bar = max(c.score for c in free) + RECOMPILE_GAIN
        admissible = [c for c in candidates if c in free or c.score >= bar]
    best = max(c.score for c in admissible)
    chosen = min((c for c in admissible if c.score >= best - tolerance), key=lambda c: (c.cost, -c.score))
    if chosen in given:
        return Choice(given[chosen], tuple(candidates))
    family = next(f for f in families if _fit_name(f) == chosen.family)
    k = chosen.num_components
    # Refitted to all the draws it may use, started from the candidate.
    every = np.arange(x.shape[0]) if family in PRODUCTS else _at_most(np.arange(x.shape[0]), mixture_draws, rng)
    prepared = products.get(family)
    fit = _fit(
        family, x[every], w[every], k, seed, start=fits[family, k], binned=None if prepared is None else prepared.all,
        axes=None if prepared is None else prepared.axes,
    )  # fmt: skip
    return Choice(fit, tuple(candidates))


def refit_regeneration(
    fit: Fit, draws, weights, groups, *, holdout: float = 0.25, max_draws: int = 100_000, mixture_draws: int = 8192, seed: int = 0
) -> Choice:
    """`fit`'s family with as many components fitted again to these draws (a mixture's EM
    started from `fit`), and whichever of the two scores better on the held-out groups.

    For a regeneration chosen from draws that were not the target's (e.g. chains that had not
    equilibrated), once draws of the target are at hand. The arguments are those of
    `choose_regeneration`. A fit of no family of `FAMILIES` (e.g. `laplace_fit`), or a rotated
    product (whose directions would have to be found again), is returned as it is.

    Returns:
        The better fit (the new one refitted on all the draws it may use) and the two candidates.
    """
    family = _family_of(fit)
    if family is None or family == "rotated-product":
        return Choice(fit, ())
    split = _split(draws, weights, groups, holdout, max_draws, mixture_draws, seed)
    x, w, k = split.x, split.w, fit.num_components
    prepared = _products(x, w, split.test) if family in PRODUCTS else None
    on = np.flatnonzero(~split.test) if family in PRODUCTS else split.train
    try:
        new = _fit(family, x[on], w[on], k, seed, start=fit, binned=None if prepared is None else prepared.train, iterations=SEARCH_ITERATIONS)
    except (ValueError, np.linalg.LinAlgError):
        return Choice(fit, ())
    old_score, new_score = split.score(fit), split.score(new)
    candidates = (Candidate(fit.family, k, fit.cost, old_score), Candidate(new.family, k, new.cost, new_score))
    if not new_score > old_score:
        return Choice(fit, candidates)
    every = np.arange(x.shape[0]) if family in PRODUCTS else _at_most(np.arange(x.shape[0]), mixture_draws, split.rng)
    final = _fit(family, x[every], w[every], k, seed, start=new, binned=None if prepared is None else prepared.all)
    return Choice(final, candidates)


class _Split(NamedTuple):
    """Draws split by group: the finite ones of positive weight (at most `max_draws`), which are
    held out (`test`), the training draws a mixture is fitted to and the held-out draws it is
    scored on (at most `mixture_draws` each), and the generator that made the split."""

    x: np.ndarray
    w: np.ndarray
    test: np.ndarray
    train: np.ndarray
    scored: np.ndarray
    rng: np.random.Generator

    def score(self, fit: Fit) -> float:
        """The weighted mean log density of the held-out draws under `fit` (`-inf` where it vanishes)."""
        logp = fit.log_prob(self.x[self.scored])
        w = self.w[self.scored]
        return float(np.sum(w * logp) / np.sum(w)) if np.all(np.isfinite(logp)) else -math.inf


def _split(draws, weights, groups, holdout: float, max_draws: int, mixture_draws: int, seed: int) -> _Split:
    x = np.asarray(draws, np.float64)
    w = np.asarray(weights, np.float64).reshape(-1)
    g = np.asarray(groups).reshape(-1)
    rng = np.random.default_rng(seed)
    ok = np.isfinite(w) & (w > 0) & np.all(np.isfinite(x), axis=1)
    x, w, g = x[ok], w[ok], g[ok]
    if x.shape[0] > max_draws:
        pick = rng.choice(x.shape[0], max_draws, replace=False)
        x, w, g = x[pick], w[pick], g[pick]
    labels = np.unique(g)
    if labels.size < 4:
        raise ValueError(f"need draws from at least 4 groups (lanes or chains) to hold some out, got {labels.size}")
    held = rng.choice(labels, max(1, round(holdout * labels.size)), replace=False)
    test = np.isin(g, held)
    train, scored = _at_most(np.flatnonzero(~test), mixture_draws, rng), _at_most(np.flatnonzero(test), mixture_draws, rng)
    return _Split(x, w, test, train, scored, rng)


def _far_behind(family: list[Candidate], candidates: list[Candidate], d: int) -> bool:
    """Whether a family's candidates all trail the best candidate by more than `TAIL_GAIN` nats per coordinate."""
    return bool(family) and max(c.score for c in family) < max(c.score for c in candidates) - TAIL_GAIN * d


def close_families(families: Sequence[str], candidates: Sequence[Candidate], d: int) -> tuple[str, ...]:
    """The families of `families` still worth fitting after a choice among `candidates` (of `d`-dimensional draws).

    A family is dropped when its best candidate trailed the best of all by more than
    `FAMILY_GAIN` nats per coordinate; one that had no candidate is kept where the family its
    search starts from (`_base`) is kept. A fit made elsewhere (`extra` of
    `choose_regeneration`) is not judged here: a Laplace fit scored on seeding draws that have
    not spread along a target's long directions trails the fits to those draws, and is still
    the one that answers (`tests/statistical/test_autosample.py`).
    """
    if not candidates:
        return tuple(families)
    bar = max(c.score for c in candidates) - FAMILY_GAIN * d
    best: dict[str, float] = {}
    for c in candidates:
        best[c.family] = max(best.get(c.family, -math.inf), c.score)
    kept: list[str] = []
    for family in families:
        own = best.get(_fit_name(family))
        if own is not None:
            if own >= bar:
                kept.append(family)
        elif _base(family) == family or _base(family) in kept or _base(family) not in families:
            kept.append(family)
    return tuple(kept)


def default_max_cost(d: int) -> int:
    """The largest cost (multiply-adds per log density) a candidate may have by default."""
    return max(4096, 64 * int(d))


def padded_size(num_components: int, size: int | None) -> int:
    """The number of components a fit of `num_components` runs with, given a run compiled for
    `size` of its family (or `None`): `size` if that is at least `num_components` and at most
    `PAD_LIMIT` times it, else `num_components`."""
    k = int(num_components)
    return int(size) if size is not None and k <= size <= PAD_LIMIT * k else k


def _at_most(indices: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """`indices`, or a random subset of `n` of them (in order)."""
    return indices if indices.size <= n else np.sort(rng.choice(indices, n, replace=False))


def _base(family: str) -> str:
    """The family whose best size a family's search starts from: the Gaussian family of a
    Student-t one (`"diagonal-t"` -> `"diagonal"`), the product of a rotated product."""
    return "product" if family == "rotated-product" else family.removesuffix("-t")


def _family_of(fit: Fit) -> str | None:
    """The family of `FAMILIES` whose fits `fit` is one of, or `None` (a fit made elsewhere, e.g. `laplace_fit`)."""
    return next((f for f in FAMILIES if _fit_name(f) == fit.family), None)


def _fit_name(family: str) -> str:
    """The `Fit.family` label of a family name."""
    if family == "rotated-product":
        return "rotated product"
    base = next((b for b in ("diagonal", "full", "conditional") if family.startswith(b)), "product")
    return base + (f" student-t(df={STUDENT_DF:g})" if family.endswith("-t") else "")
