"""Weighted maximum-likelihood fits of regeneration families to weighted draws (NumPy, float64).

Each fit returns the fitted distribution together with NumPy code for its log density, so
that candidates can be scored on held-out draws without compiling anything. The fits are
expectation-maximisation with a weak prior that keeps every component alive and every
covariance positive definite:

- `fit_mixture`: `K` Gaussian or Student-t components (fixed `df`), full or diagonal.
- `fit_product`: a product of one-dimensional Gaussian mixtures. Its EM runs on each
  coordinate's draws gathered into `PRODUCT_BINS` groups of consecutive values (their
  weighted counts, sums and sums of squares, which make the M-step exact for
  responsibilities that are constant within a group), so its cost does not grow with the
  number of draws beyond sorting them.
- `fit_rotated_product`: the same product along the directions in which the draws are
  most nearly independent (`independent_axes`).

Weights are normalised to the effective sample size `(sum w)^2 / sum w^2`, so the prior
counts as a fixed number of pseudo-draws whatever the scale of the weights.

Every fit can build its distribution padded with components of zero weight
(`Fit.padded`): the padded distribution has the same density and draws, and its arrays
have the shapes of the larger size, so a Restore run compiled for one fit runs every fit
of the same family with at most that many components.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import Literal, NamedTuple

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from scipy.special import gammaln
from threadpoolctl import ThreadpoolController

from .._linalg import inverse_tril
from ._diagonal_mixture import DiagonalMixture, check_df
from ._gaussian import Gaussian
from ._independent_axes import independent_axes
from ._mixture import Mixture
from ._product_mixture import ProductMixture
from ._rotated_product import RotatedProductMixture
from ._student_t import StudentT

Covariance = Literal["full", "diagonal"]

#: Pseudo-draws of the prior on each component's covariance (towards a small multiple of the
#: draws' overall covariance) and on its weight.
PRIOR_DRAWS = 1.0
#: The prior covariance of a component, as a share of the overall covariance.
PRIOR_SHARE = 1e-2
#: Groups of consecutive values per coordinate that a product fit's EM runs on.
PRODUCT_BINS = 512


class Fit(NamedTuple):
    """A fitted regeneration distribution and its NumPy log density (for scoring).

    The JAX distribution is built when `distribution` is first read: a candidate that is
    only scored never builds it.
    """

    build: Callable[[int], object]  # makes the distribution with that many components, once per size
    log_prob: Callable[[np.ndarray], np.ndarray]  # (n, d) float64 -> (n,)
    family: str
    num_components: int
    cost: int  # multiply-adds of one log density: what each Restore step pays for it
    parameters: dict | None = None  # the fitted arrays (NumPy), e.g. to start another fit from

    @property
    def distribution(self):
        """The fitted distribution (a `restore.regeneration` distribution)."""
        return self.build(self.num_components)

    def padded(self, size: int):
        """The fitted distribution with `size >= num_components` components, the extra ones
        of weight zero (log weight `-inf`): the same density and draws, in arrays of the
        shapes of `size` components, so that one compiled program runs every fit of this
        family with at most `size` components."""
        if int(size) < self.num_components:
            raise ValueError(f"cannot pad {self.num_components} components to {size}")
        return self.build(int(size))


def logsumexp(a: np.ndarray, axis: int) -> np.ndarray:
    """`log sum exp` along `axis` (a lean version of SciPy's, which dominated the fits' time)."""
    top, _, total = _shifted_exp(a, axis)
    with np.errstate(divide="ignore"):
        return np.squeeze(np.log(total) + top, axis=axis)


def normalise(a: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """`(log sum exp a, exp(a - log sum exp a))` along `axis`, with one exponential of `a`:
    the log normaliser of the components' joint log densities and their responsibilities.

    The fits keep components on the first axes and draws on the last, so that the sums over
    the few components run elementwise across draws, not over short rows.
    """
    top, e, total = _shifted_exp(a, axis)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.squeeze(np.log(total) + top, axis=axis), e / total


def _shifted_exp(a: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The largest finite entry along `axis` (0 if none), `exp(a - top)` and its sum."""
    top = np.max(a, axis=axis, keepdims=True)
    top = np.where(np.isfinite(top), top, 0.0)
    e = np.exp(a - top)
    return top, e, np.sum(e, axis=axis, keepdims=True)


def single_threaded(fit):
    """Run a fit with one BLAS thread: its matrices are small, and spinning BLAS threads that
    compete with each other and with XLA made these fits many times slower on two cores."""

    @functools.wraps(fit)
    def wrapped(*args, **kwargs):
        with _thread_pools().limit(limits=1, user_api="blas"):
            return fit(*args, **kwargs)

    return wrapped


@functools.cache
def _thread_pools() -> ThreadpoolController:
    """The process's thread pools, found once: looking for them again at every fit scans every
    loaded library (milliseconds each time in a process that has loaded JAX)."""
    return ThreadpoolController()


def _prepare(x, w) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(x, np.float64)
    w = np.asarray(w, np.float64).reshape(-1)
    if x.ndim != 2 or x.shape[0] != w.shape[0]:
        raise ValueError(f"draws must have shape (n, d) and weights (n,), got {x.shape} and {w.shape}")
    keep = np.isfinite(w) & (w > 0) & np.all(np.isfinite(x), axis=1)
    x, w = x[keep], w[keep]
    if x.shape[0] < 2:
        raise ValueError("need at least 2 draws with positive weight to fit a regeneration distribution")
    return x, w * (w.sum() / np.sum(w**2))  # sums to the effective sample size


def _seeds(x: np.ndarray, w: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """Weighted k-means++ seeding: `k` well-spread draws."""
    p = w / w.sum()
    centres = [x[rng.choice(len(x), p=p)]]
    scale = np.var(x, axis=0) + 1e-300
    dist = np.sum((x - centres[0]) ** 2 / scale, axis=1)
    for _ in range(1, k):
        q = p * dist
        total = q.sum()
        centres.append(x[rng.choice(len(x), p=q / total)] if total > 0 else x[rng.choice(len(x), p=p)])
        dist = np.minimum(dist, np.sum((x - centres[-1]) ** 2 / scale, axis=1))
    return np.array(centres)


def _student_const(df: float, d: int) -> float:
    return gammaln(0.5 * (df + d)) - gammaln(0.5 * df) - 0.5 * d * math.log(df * math.pi)


def _component_terms(x, means, chol_or_scales, df, diagonal: bool):
    """`log p_k(x_i)` `(K, n)` and the squared Mahalanobis distances `(K, n)`."""
    n, d = x.shape
    if diagonal:
        inv2 = 1.0 / chol_or_scales**2
        # |x - m|^2 / s^2 expanded, so no (K, n, d) array is formed
        z2 = inv2 @ (x**2).T - 2.0 * (means * inv2) @ x.T + np.sum(means**2 * inv2, axis=1)[:, None]
        z2 = np.maximum(z2, 0.0)
        log_det = np.sum(np.log(chol_or_scales), axis=1)
    else:
        inv = np.linalg.inv(chol_or_scales)  # (K, d, d), lower triangular
        z = inv @ x.T - (inv @ means[:, :, None])  # (K, d, n)
        z2 = np.sum(z**2, axis=1)
        log_det = np.sum(np.log(np.diagonal(chol_or_scales, axis1=1, axis2=2)), axis=1)
    log_det = log_det[:, None]
    if df is None:
        return -0.5 * z2 - log_det - 0.5 * d * math.log(2 * math.pi), z2
    return _student_const(df, d) - log_det - 0.5 * (df + d) * np.log1p(z2 / df), z2


@single_threaded
def fit_mixture(
    draws,
    weights,
    num_components: int,
    *,
    covariance: Covariance = "full",
    df: float | None = None,
    seed: int = 0,
    iterations: int = 100,
    tolerance: float = 1e-5,
    init_means: np.ndarray | None = None,
    init_covariances: np.ndarray | None = None,
    init_weights: np.ndarray | None = None,
) -> Fit:
    """Weighted EM for a mixture of `num_components` Gaussian (or Student-t) components.

    Arguments:
        draws: `(n, d)` draws, e.g. a Restore run's stored draws.
        weights: `(n,)` their non-negative weights (the run's holding times).
        num_components: `K`.
        covariance: `"full"` matrices or `"diagonal"` ones.
        df: `None` for Gaussian components, else fixed Student-t degrees of freedom.
        seed: seed of the k-means++ initialisation.
        iterations: most EM iterations.
        tolerance: stop when the mean log likelihood improves by less than this.
        init_means: optional `(K, d)` starting locations (e.g. the previous fit's).
        init_covariances: optional `(K, d, d)` starting covariances (scale matrices), with
            `init_means`.
        init_weights: optional `(K,)` starting weights, with `init_means`.
    """
    x, w = _prepare(draws, weights)
    df = check_df(df)
    d = x.shape[1]
    k = int(num_components)
    if k < 1:
        raise ValueError(f"num_components must be at least 1, got {num_components!r}")
    diagonal = covariance == "diagonal"
    if covariance not in ("full", "diagonal"):
        raise ValueError(f"covariance must be 'full' or 'diagonal', got {covariance!r}")
    rng = np.random.default_rng(seed)
    overall = np.cov(x.T, aweights=w).reshape(d, d) + 1e-12 * np.eye(d)
    prior_cov = PRIOR_SHARE * (np.diag(np.diag(overall)) if diagonal else overall)
    means = np.array(init_means, np.float64) if init_means is not None else _seeds(x, w, k, rng)
    k = means.shape[0]
    mix = np.full(k, 1.0 / k) if init_weights is None else np.asarray(init_weights, np.float64) / np.sum(init_weights)
    covs = np.broadcast_to(overall / k ** (2.0 / d) if init_covariances is None else init_covariances, (k, d, d)).copy()
    if diagonal:
        covs = covs * np.eye(d)
    total = w.sum()
    previous = -np.inf
    xt, x2 = x.T, x**2
    for _ in range(iterations):
        factor = np.sqrt(np.diagonal(covs, axis1=1, axis2=2)) if diagonal else np.linalg.cholesky(covs)
        logp, z2 = _component_terms(x, means, factor, df, diagonal)
        norm, r = normalise(np.log(mix)[:, None] + logp, axis=0)
        current = float(w @ norm / total)
        r *= w  # weighted responsibilities (K, n)
        nk = r.sum(axis=1)
        mix = (nk + PRIOR_DRAWS / k) / (total + PRIOR_DRAWS)
        ru = r if df is None else r * ((df + d) / (df + z2))  # times the latent precision scales
        ru_sum = ru.sum(axis=1)
        ru_x = ru @ x
        means = ru_x / np.maximum(ru_sum, 1e-300)[:, None]
        if diagonal:  # E[r u (x - m)^2] expanded
            spread = ru @ x2 - 2.0 * means * ru_x + means**2 * ru_sum[:, None]
            covs = np.zeros((k, d, d))
            idx = np.arange(d)
            covs[:, idx, idx] = (np.maximum(spread, 0.0) + PRIOR_DRAWS * np.diag(prior_cov)) / (nk + PRIOR_DRAWS)[:, None]
        else:
            scatter = (ru[:, None, :] * xt) @ x  # (K, d, d), one batched product
            scatter -= np.einsum("ki,kj,k->kij", means, means, ru_sum)
            covs = (scatter + PRIOR_DRAWS * prior_cov) / (nk + PRIOR_DRAWS)[:, None, None]
            covs = 0.5 * (covs + np.swapaxes(covs, 1, 2))
        if current - previous < tolerance:
            break
        previous = current
    return _mixture_fit(mix, means, covs, df, diagonal)


def _padded_log_weights(log_w: np.ndarray, size: int, axis: int = -1) -> np.ndarray:
    """`log_w` normalised along `axis` and extended to `size` entries there with `-inf`."""
    log_w = log_w - np.log(np.sum(np.exp(log_w), axis=axis, keepdims=True))
    pad = [(0, 0)] * log_w.ndim
    pad[axis] = (0, size - log_w.shape[axis])
    return np.pad(log_w, pad, constant_values=-np.inf)


def _repeat_first(a: np.ndarray, size: int, axis: int = 0) -> np.ndarray:
    """`a` extended to `size` entries along `axis` with copies of its first entry (the
    parameters of zero-weight components: any valid values do)."""
    extra = size - a.shape[axis]
    return np.concatenate([a, np.repeat(np.take(a, [0], axis=axis), extra, axis=axis)], axis=axis)


def _mixture_fit(mix, means, covs, df, diagonal: bool) -> Fit:
    k, d = means.shape
    dtype = jnp.result_type(float)
    if diagonal:
        factor = np.sqrt(np.diagonal(covs, axis1=1, axis2=2))
        cost = k * d
    else:
        factor = np.linalg.cholesky(covs)
        cost = k * d * d
    log_mix = np.log(mix)

    @functools.cache
    def build(size: int):
        log_w = jnp.asarray(_padded_log_weights(log_mix, size), dtype)
        m, f = _repeat_first(means, size), _repeat_first(factor, size)
        if diagonal:  # built with placeholder weights (the constructor refuses zeros), then given the padded ones
            out = DiagonalMixture(np.ones(size), jnp.asarray(m, dtype), jnp.asarray(f, dtype), df)
            return eqx.tree_at(lambda u: u.log_weights, out, log_w)
        # Components from one checked template, with the Cholesky factors computed here; the
        # mixture from one component, then given all of them (it would trace every one's sampler).
        template = Gaussian(jnp.asarray(means[0], dtype), covs[0]) if df is None else StudentT(jnp.asarray(means[0], dtype), covs[0], df)
        where = (lambda c: (c.mean, c.scale_tril, c.inverse_tril)) if df is None else (lambda c: (c.loc, c.scale_tril, c.inverse_tril))
        trils = [jnp.asarray(f[i], dtype) for i in range(size)]
        components = tuple(eqx.tree_at(where, template, (jnp.asarray(m[i], dtype), t, inverse_tril(t))) for i, t in enumerate(trils))
        mixture = Mixture([template])
        return eqx.tree_at(lambda u: (u.components, u.log_weights), mixture, (components, log_w))

    def log_prob(y):
        logp, _ = _component_terms(np.asarray(y, np.float64), means, factor, df, diagonal)
        return logsumexp(log_mix[:, None] + logp, axis=0)

    family = ("diagonal" if diagonal else "full") + ("" if df is None else f" student-t(df={df:g})")
    return Fit(build, log_prob, family, k, int(cost), dict(weights=mix, means=means, covariances=covs))


def _bins(x: np.ndarray, w: np.ndarray, bins: int, order: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Each coordinate's draws sorted (`order`, if given: `np.argsort(x, axis=0)`) and gathered
    into `bins` groups of consecutive values (or one group per draw, when there are no more
    draws than that): the groups' weights, weighted sums, weighted sums of squares and
    weighted means, each `(d, m)`."""
    n = x.shape[0]
    order = np.argsort(x, axis=0) if order is None else order
    xs = np.take_along_axis(x, order, axis=0).T  # (d, n), ascending
    ws = w[order].T
    if n <= bins:
        return ws, ws * xs, ws * xs**2, xs
    starts = (np.arange(bins) * n) // bins
    weight = np.add.reduceat(ws, starts, axis=1)
    total = np.add.reduceat(ws * xs, starts, axis=1)
    squares = np.add.reduceat(ws * xs**2, starts, axis=1)
    return weight, total, squares, total / weight


class ProductData(NamedTuple):
    """Weighted draws as a product fit uses them: each coordinate's draws in groups of
    consecutive values (`_bins`), each `(d, m)`, with their total weight and variances."""

    weight: np.ndarray
    first: np.ndarray
    second: np.ndarray
    centre: np.ndarray
    total: float
    variance: np.ndarray  # (d,)


def product_data(draws, weights, order: np.ndarray | None = None) -> ProductData:
    """The draws binned for `fit_binned_product` (bin once, fit several sizes). `order`:
    `np.argsort(draws, axis=0)`, if known (the draws must all be finite with positive weights)."""
    if order is None:
        x, w = _prepare(draws, weights)
    else:
        x = np.asarray(draws, np.float64)
        w = np.asarray(weights, np.float64)
        w = w * (w.sum() / np.sum(w**2))
    d = x.shape[1]
    variance = np.cov(x.T, aweights=w).reshape(d, d).diagonal() + 1e-300
    return ProductData(*_bins(x, w, PRODUCT_BINS, order), total=float(w.sum()), variance=variance)


@single_threaded
def fit_product(draws, weights, num_components: int, *, seed: int = 0, iterations: int = 100, tolerance: float = 1e-6) -> Fit:
    """Weighted EM for a product of one-dimensional `num_components`-component Gaussian mixtures.

    Every coordinate is fitted separately (and all at once, vectorised): the fit is the
    product of the weighted marginals' mixture fits. The EM runs on each coordinate's
    draws gathered into `PRODUCT_BINS` groups of consecutive values (the responsibilities
    of a group are those of its weighted mean; the M-step uses the groups' exact weighted
    sums and sums of squares).
    """
    data = product_data(draws, weights)
    return fit_binned_product(data, num_components, seed=seed, iterations=iterations, tolerance=tolerance)


@single_threaded
def fit_binned_product(
    data: ProductData, num_components: int, *, seed: int = 0, iterations: int = 100, tolerance: float = 1e-6, start: Fit | None = None
) -> Fit:
    """`fit_product` of draws binned by `product_data` (`start`: a product fit of as many
    components to start the EM from)."""
    k = int(num_components)
    if k < 1:
        raise ValueError(f"num_components must be at least 1, got {num_components!r}")
    weight, first, second, centre, total, var = data
    d, m = centre.shape
    rng = np.random.default_rng(seed)
    if start is not None and start.parameters is not None and start.num_components == k:
        mix, means, scales = (np.array(start.parameters[name]) for name in ("weights", "means", "scales"))
    else:  # start at weighted quantiles of each coordinate, with a little jitter
        qs = (np.arange(k) + 0.5) / k
        cw = np.cumsum(weight, axis=1) / total
        means = np.stack([centre[j, np.minimum(np.searchsorted(cw[j], qs), m - 1)] for j in range(d)])
        means = means + 1e-3 * np.sqrt(var)[:, None] * rng.standard_normal(means.shape)
        scales = np.broadcast_to(np.sqrt(var)[:, None] / k, (d, k)).copy()
        mix = np.full((d, k), 1.0 / k)
    prior_var = PRIOR_SHARE * var[:, None]
    previous = -np.inf
    c = centre[:, None, :]  # (d, 1, m): coordinates, components, groups
    for _ in range(iterations):
        z = (c - means[:, :, None]) / scales[:, :, None]
        joint = (np.log(mix) - np.log(scales) - 0.5 * math.log(2 * math.pi))[:, :, None] - 0.5 * z**2
        norm, r = normalise(joint, axis=1)  # (d, m), (d, k, m)
        current = float(np.sum(norm * weight) / total)
        nk = (r @ weight[:, :, None])[..., 0]  # (d, k)
        means = (r @ first[:, :, None])[..., 0] / np.maximum(nk, 1e-300)
        spread = (r @ second[:, :, None])[..., 0] - means**2 * nk
        mix = (nk + PRIOR_DRAWS / k) / (total + PRIOR_DRAWS)
        scales = np.sqrt((np.maximum(spread, 0.0) + PRIOR_DRAWS * prior_var) / (nk + PRIOR_DRAWS))
        if current - previous < tolerance * d:
            break
        previous = current
    return _product_fit(mix, means, scales)


def _product_fit(mix: np.ndarray, means: np.ndarray, scales: np.ndarray) -> Fit:
    d, k = means.shape
    dtype = jnp.result_type(float)
    log_mix = np.log(mix)

    @functools.cache
    def build(size: int):
        out = ProductMixture(np.ones((d, size)), jnp.asarray(_repeat_first(means, size, 1), dtype), jnp.asarray(_repeat_first(scales, size, 1), dtype))
        return eqx.tree_at(lambda u: u.log_weights, out, jnp.asarray(_padded_log_weights(log_mix, size), dtype))

    offset = (log_mix - np.log(scales) - 0.5 * math.log(2 * math.pi))[:, :, None]

    def log_prob(y):
        yt = np.asarray(y, np.float64).T[:, None, :]
        z = (yt - means[:, :, None]) / scales[:, :, None]
        return logsumexp(offset - 0.5 * z**2, axis=1).sum(axis=0)

    return Fit(build, log_prob, "product", k, int(k * d), dict(weights=mix, means=means, scales=scales))


@single_threaded
def fit_rotated_product(draws, weights, num_components: int, *, seed: int = 0, iterations: int = 100, tolerance: float = 1e-6) -> Fit:
    """`fit_product` along the directions in which the draws are most nearly independent:
    `y = A (x - centre)` from `independent_axes`, a product of one-dimensional mixtures
    fitted to `y` (a `RotatedProductMixture`)."""
    x, w = _prepare(draws, weights)
    axes = independent_axes(x, w, seed=seed)
    centre, transform = axes.centre, axes.transform
    product = fit_product((x - centre) @ transform.T, w, num_components, seed=seed, iterations=iterations, tolerance=tolerance)
    return rotated(product, centre, transform)


def rotated(product: Fit, centre: np.ndarray, transform: np.ndarray) -> Fit:
    """A product fit to `y = A (x - centre)` (`transform` `A`) as a fit in `x`: a `RotatedProductMixture`."""
    d, k = int(transform.shape[0]), product.num_components
    log_det = float(np.linalg.slogdet(transform)[1])

    @functools.cache
    def build(size: int):
        inner = product.build(size)
        assert isinstance(inner, ProductMixture)  # `rotated` is given product fits only
        return RotatedProductMixture(inner, centre, transform)

    def log_prob(y):
        return product.log_prob((np.asarray(y, np.float64) - centre) @ transform.T) + log_det

    parameters = dict(product.parameters or {}, centre=centre, transform=transform)
    return Fit(build, log_prob, "rotated product", k, int(d * d + k * d), parameters)
