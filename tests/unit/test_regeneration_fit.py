"""Fitted regeneration families: exact densities and draws, weighted fits, and the held-out choice."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from restore.regeneration import (
    Candidate,
    DiagonalMixture,
    Gaussian,
    Mixture,
    ProductMixture,
    RotatedProductMixture,
    StudentT,
    choose_regeneration,
    fit_mixture,
    fit_product,
    fit_rotated_product,
    independent_axes,
)
from restore.regeneration._choose import AXES_GAIN, FAMILIES, FAMILY_GAIN, close_families

KEY = jax.random.key(3)


@pytest.mark.parametrize("df", [None, 4.0, 7.5])
def test_diagonal_mixture_matches_the_general_mixture(df):
    means = jnp.asarray([[0.0, 1.0, -2.0], [3.0, -1.0, 0.5]])
    scales = jnp.asarray([[1.0, 0.5, 2.0], [0.3, 1.5, 1.0]])
    weights = jnp.asarray([0.3, 0.7])
    fast = DiagonalMixture(weights, means, scales, df)
    make = (lambda m, s: Gaussian(m, s**2)) if df is None else (lambda m, s: StudentT(m, s**2, df))
    slow = Mixture([make(m, s) for m, s in zip(means, scales)], weights)
    points = jax.random.normal(KEY, (20, 3)) * 3
    np.testing.assert_allclose(jax.vmap(fast.log_prob)(points), jax.vmap(slow.log_prob)(points), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("df", [None, 5.0])
def test_diagonal_mixture_draws_follow_its_density(df):
    dist = DiagonalMixture(jnp.asarray([0.25, 0.75]), jnp.asarray([[-3.0, 0.0], [2.0, 1.0]]), jnp.asarray([[0.5, 1.0], [1.0, 2.0]]), df)
    draws = np.asarray(dist.sample(KEY, (20_000,)))
    assert draws.shape == (20_000, 2)

    def cdf(t):  # coordinate 0: a two-component mixture of (scaled) normals or t's
        base = stats.norm if df is None else stats.t(df)
        return 0.25 * base.cdf((t + 3.0) / 0.5) + 0.75 * base.cdf((t - 2.0) / 1.0)

    assert stats.kstest(draws[:, 0], cdf).pvalue > 1e-3


@pytest.mark.slow
def test_product_mixture_density_and_draws():
    weights = jnp.asarray([[0.85, 0.15], [0.5, 0.5], [1.0, 1e-3]])
    means = jnp.asarray([[1.7, -1.7], [0.0, 4.0], [2.0, -2.0]])
    scales = jnp.asarray([[0.4, 0.4], [1.0, 0.5], [1.0, 1.0]])
    dist = ProductMixture(weights, means, scales)
    w = np.asarray(weights) / np.asarray(weights).sum(axis=1, keepdims=True)

    def marginal_logpdf(j, t):
        return np.log(sum(w[j, k] * stats.norm.pdf(t, means[j, k], scales[j, k]) for k in range(2)))

    x = np.asarray(jax.random.normal(KEY, (10, 3)) * 2)
    expected = sum(marginal_logpdf(j, x[:, j]) for j in range(3))
    np.testing.assert_allclose(jax.vmap(dist.log_prob)(jnp.asarray(x)), expected, rtol=1e-10)
    draws = np.asarray(dist.sample(KEY, (20_000,)))
    for j in range(3):
        cdf = lambda t, j=j: sum(w[j, k] * stats.norm.cdf(t, means[j, k], scales[j, k]) for k in range(2))  # noqa: E731
        assert stats.kstest(draws[:, j], cdf).pvalue > 1e-3
    assert abs(np.mean(draws[:, 0] > 0) - 0.85) < 0.02


def test_bad_parameters_are_refused():
    with pytest.raises(ValueError, match="scales"):
        DiagonalMixture([1.0], [[0.0, 0.0]], [[1.0, -1.0]])
    with pytest.raises(ValueError, match="weights"):
        ProductMixture([[1.0, 0.0]], [[0.0, 1.0]], [[1.0, 1.0]])
    with pytest.raises(ValueError, match="df"):
        DiagonalMixture([1.0], [[0.0]], [[1.0]], df=0.5)
    with pytest.raises(ValueError, match="num_components"):
        fit_mixture(np.zeros((10, 2)), np.ones(10), 0)
    with pytest.raises(ValueError, match="shape"):
        fit_product(np.zeros((10, 2)), np.ones(9), 2)


def _weighted_bimodal(n=8000, seed=0):
    """Importance-weighted draws of 0.3 N((-3, 0), I) + 0.7 N((3, 1), diag(0.25, 4)) from a broad proposal."""
    rng = np.random.default_rng(seed)
    x = rng.normal(0.0, 4.0, (n, 2))
    p = 0.3 * stats.multivariate_normal([-3, 0], np.eye(2)).pdf(x) + 0.7 * stats.multivariate_normal([3, 1], np.diag([0.25, 4])).pdf(x)
    q = stats.multivariate_normal([0, 0], 16 * np.eye(2)).pdf(x)
    return x, p / q


@pytest.mark.parametrize("covariance", ["full", "diagonal"])
def test_weighted_em_recovers_a_mixture(covariance):
    x, w = _weighted_bimodal()
    fit = fit_mixture(x, w, 2, covariance=covariance, seed=1)
    dist = fit.distribution
    if covariance == "diagonal":
        means, weights = np.asarray(dist.means), np.exp(np.asarray(dist.log_weights))
    else:
        means, weights = np.array([np.asarray(c.mean) for c in dist.components]), np.asarray(dist.weights)
    order = np.argsort(means[:, 0])
    np.testing.assert_allclose(means[order], [[-3, 0], [3, 1]], atol=0.25)
    np.testing.assert_allclose(weights[order], [0.3, 0.7], atol=0.05)
    y = x[:50]
    np.testing.assert_allclose(fit.log_prob(y), jax.vmap(dist.log_prob)(jnp.asarray(y)), rtol=1e-10)


def test_weighted_product_fit_recovers_unequal_wells():
    rng = np.random.default_rng(2)
    n, d = 6000, 4
    signs = rng.uniform(size=(n, d)) < 0.5  # draws with equal wells...
    x = np.where(signs, 1.7, -1.7) + 0.3 * rng.standard_normal((n, d))
    w = np.prod(np.where(signs, 0.85, 0.15) / 0.5, axis=1)  # ...weighted to wells of 0.85 / 0.15
    fit = fit_product(x, w, 2)
    draws = np.asarray(fit.distribution.sample(KEY, (20_000,)))
    np.testing.assert_allclose(np.mean(draws > 0, axis=0), 0.85, atol=0.03)
    np.testing.assert_allclose(fit.log_prob(x[:20]), jax.vmap(fit.distribution.log_prob)(jnp.asarray(x[:20])), rtol=1e-10)


@pytest.mark.slow
def test_choice_follows_the_structure_of_the_draws():
    rng = np.random.default_rng(4)
    n = 4000
    groups = np.repeat(np.arange(40), n // 40)
    # 8 independent bimodal coordinates: 256 modes in product form
    product = np.where(rng.uniform(size=(n, 8)) < 0.7, 2.0, -2.0) + 0.4 * rng.standard_normal((n, 8))
    chosen = choose_regeneration(product, np.ones(n), groups)
    assert chosen.fit.family == "product", chosen.candidates
    # one strongly correlated Gaussian: a full covariance is worth its cost
    cov = np.array([[1.0, 0.95, 0.0], [0.95, 1.0, 0.0], [0.0, 0.0, 1.0]])
    correlated = rng.multivariate_normal(np.zeros(3), cov, n)
    chosen = choose_regeneration(correlated, np.ones(n), groups)
    assert chosen.fit.family.startswith("full"), chosen.candidates
    # 40 separated modes in 2-d: many components
    centres = rng.uniform(-40, 40, (40, 2))
    spread = centres[rng.integers(0, 40, n)] + rng.standard_normal((n, 2))
    chosen = choose_regeneration(spread, np.ones(n), groups)
    assert chosen.fit.num_components >= 32, chosen.candidates
    best = max(c.score for c in chosen.candidates)
    assert all(c.score <= best for c in chosen.candidates)


def test_choice_needs_several_groups():
    with pytest.raises(ValueError, match="groups"):
        choose_regeneration(np.zeros((100, 2)), np.ones(100), np.zeros(100))
    with pytest.raises(ValueError, match="families"):
        choose_regeneration(np.zeros((100, 2)), np.ones(100), np.arange(100), families=("flows",))


def test_fit_densities_are_normalised():
    x, w = _weighted_bimodal(3000)
    for fit in (fit_mixture(x, w, 3, df=5.0), fit_mixture(x, w, 2, covariance="diagonal", df=5.0), fit_product(x, w, 3)):
        grid = np.linspace(-30, 30, 601)
        gx, gy = np.meshgrid(grid, grid)
        points = np.stack([gx.ravel(), gy.ravel()], axis=1)
        mass = np.exp(fit.log_prob(points)).sum() * (grid[1] - grid[0]) ** 2
        assert mass == pytest.approx(1.0, abs=0.01), fit.family
        assert math.isfinite(fit.cost) and fit.cost > 0


def test_component_indices_follow_the_weights_and_never_draw_a_zero_weight():
    """Mixtures draw their components by inverting the cumulative weights: per row of
    weights, the counts pass a chi-square test against the weights (Bonferroni over rows),
    and padded components of weight zero, between and after the others, never come up."""
    from restore.regeneration._utils import component_indices

    weights = np.array([[0.5, 0.0, 0.3, 0.2, 0.0], [1e-3, 0.999, 0.0, 0.0, 0.0], [0.2, 0.2, 0.2, 0.2, 0.2]])
    with np.errstate(divide="ignore"):
        log_weights = jnp.asarray(np.log(weights) - 40.0)  # unnormalised, and small: normalised inside
    idx = np.asarray(component_indices(KEY, log_weights, (50_000,), jnp.float64))
    assert idx.shape == (50_000, 3)
    for row in range(3):
        counts = np.bincount(idx[:, row], minlength=5)
        assert np.all(counts[weights[row] == 0] == 0)
        used = weights[row] > 0
        assert stats.chisquare(counts[used], 50_000 * weights[row, used]).pvalue > 1e-3 / 3
    flat = np.asarray(component_indices(KEY, jnp.log(jnp.asarray([0.25, 0.75])), (40_000,), jnp.float64))
    assert flat.shape == (40_000,) and abs(np.mean(flat) - 0.75) < 0.01


def test_padded_fits_have_the_same_density_and_draws():
    """`Fit.padded` (autosample runs every fit of a family on one compiled program): the
    padded distribution has arrays of the larger size and the same log density; products and
    diagonal mixtures draw the same points from the same key (their component choice is the
    same cumulative-weight inversion); padding to fewer components is refused."""
    from restore.regeneration._choose import padded_size

    x, w = _weighted_bimodal(3000)
    y = jnp.asarray(x[:40])
    fits = (fit_product(x, w, 2), fit_mixture(x, w, 2, covariance="diagonal", df=5.0), fit_mixture(x, w, 2))
    for fit in fits:
        plain, padded = fit.distribution, fit.padded(8)
        assert padded.log_weights.shape[-1] == 8 and plain.log_weights.shape[-1] == 2, fit.family
        np.testing.assert_allclose(jax.vmap(padded.log_prob)(y), jax.vmap(plain.log_prob)(y), rtol=1e-12, err_msg=fit.family)
        with pytest.raises(ValueError, match="cannot pad"):
            fit.padded(1)
    for fit in fits[:2]:
        np.testing.assert_array_equal(fit.padded(8).sample(KEY, (500,)), fit.distribution.sample(KEY, (500,)), err_msg=fit.family)
    # a fit runs on a program compiled for `size` when that is enough and not over PAD_LIMIT times its own
    assert padded_size(3, None) == 3 and padded_size(3, 8) == 8 and padded_size(3, 2) == 3 and padded_size(2, 16) == 2


def _rotation(d: int, seed: int) -> np.ndarray:
    q, r = np.linalg.qr(np.random.default_rng(seed).standard_normal((d, d)))
    return q * np.sign(np.diag(r))


def _rotated_wells(n: int, seed: int, d: int = 8, wells: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Draws with `wells` independent double wells (0.7 / 0.3) and standard normal other coordinates
    (`y`), seen through a random rotation and shift (`x = centre + Q y`): `(x, y, Q)`."""
    rng = np.random.default_rng(seed)
    y = rng.standard_normal((n, d))
    y[:, :wells] = np.where(rng.uniform(size=(n, wells)) < 0.7, 2.0, -2.0) + 0.4 * y[:, :wells]
    q = _rotation(d, seed + 1)
    return 1.5 + y @ q.T, y, q


def test_rotated_product_density_and_draws():
    """`u(x) = |det A| v(A (x - c))`: normalised on a grid, equal to the product's density of the
    new coordinates plus `log |det A|`, and its draws, mapped back, follow the product's marginals."""
    product = ProductMixture(jnp.asarray([[0.7, 0.3], [0.5, 0.5]]), jnp.asarray([[2.0, -2.0], [0.0, 3.0]]), jnp.asarray([[0.4, 0.4], [1.0, 0.5]]))
    transform = np.array([[2.0, 0.5], [-0.3, 0.8]])
    centre = np.array([1.0, -1.0])
    dist = RotatedProductMixture(product, centre, transform)
    x = np.asarray(jax.random.normal(KEY, (50, 2)) * 3)
    expected = np.asarray(jax.vmap(product.log_prob)(jnp.asarray((x - centre) @ transform.T))) + np.log(abs(np.linalg.det(transform)))
    np.testing.assert_allclose(jax.vmap(dist.log_prob)(jnp.asarray(x)), expected, rtol=1e-12)
    grid = np.linspace(-12, 14, 521)
    gx, gy = np.meshgrid(grid, grid)
    mass = np.exp(np.asarray(jax.vmap(dist.log_prob)(jnp.asarray(np.stack([gx.ravel(), gy.ravel()], axis=1))))).sum() * (grid[1] - grid[0]) ** 2
    assert mass == pytest.approx(1.0, abs=0.01)
    y = (np.asarray(dist.sample(KEY, (20_000,))) - centre) @ transform.T
    w, m, sd = np.asarray([[0.7, 0.3], [0.5, 0.5]]), np.asarray(product.means), np.asarray(product.scales)
    for j in range(2):
        cdf = lambda t, j=j: sum(w[j, k] * stats.norm.cdf(t, m[j, k], sd[j, k]) for k in range(2))  # noqa: E731
        assert stats.kstest(y[:, j], cdf).pvalue > 1e-3


def test_rotated_product_refuses_bad_transforms():
    product = ProductMixture(jnp.ones((2, 1)), jnp.zeros((2, 1)), jnp.ones((2, 1)))
    with pytest.raises(ValueError, match="invertible"):
        RotatedProductMixture(product, np.zeros(2), [[1.0, 2.0], [2.0, 4.0]])
    with pytest.raises(ValueError, match="shape"):
        RotatedProductMixture(product, np.zeros(2), np.eye(3))
    with pytest.raises(ValueError, match="finite"):
        RotatedProductMixture(product, np.zeros(2), [[1.0, np.nan], [0.0, 1.0]])
    with pytest.raises(TypeError, match="ProductMixture"):
        RotatedProductMixture(Gaussian(jnp.zeros(2), 1.0), np.zeros(2), np.eye(2))
    with pytest.raises(ValueError, match="span"):
        independent_axes(np.c_[np.arange(10.0), np.arange(10.0)], np.ones(10))


def test_independent_axes_turn_a_rotated_product_back_into_a_product():
    """Four double wells and four normal coordinates under a random rotation: the product along the
    independent axes scores within 0.1 nats of one along the true axes on held-out draws, while the
    product along the coordinate axes (the control: no directions found) is more than 1 nat worse."""
    x, y, _ = _rotated_wells(24_000, seed=5)
    train, test = slice(0, 16_000), slice(16_000, None)
    w = np.ones(16_000)
    along_found = np.mean(fit_rotated_product(x[train], w, 2).log_prob(x[test]))
    along_truth = np.mean(fit_product(y[train], w, 2).log_prob(y[test]))  # the rotation keeps densities
    along_coordinates = np.mean(fit_product(x[train], w, 2).log_prob(x[test]))
    assert along_found > along_truth - 0.1, (along_found, along_truth)
    assert along_coordinates < along_truth - 1.0, (along_coordinates, along_truth)
    turned, straight = independent_axes(x, np.ones(len(x))), independent_axes(y, np.ones(len(y)))
    assert turned.non_gaussian.sum() == straight.non_gaussian.sum() == 4  # the wells, not the normal coordinates
    assert straight.along_coordinates() and not turned.along_coordinates()  # no rotation of draws independent along the axes
    # the expected gain over the coordinate axes: a low estimate of the held-out gain, near zero where there is none
    assert 1.0 < turned.gain < along_found - along_coordinates, (turned.gain, along_found - along_coordinates)
    assert abs(straight.gain) < AXES_GAIN, straight.gain


@pytest.mark.slow
def test_choice_takes_the_rotated_product_only_where_the_axes_are_turned():
    x, y, _ = _rotated_wells(8000, seed=6)
    groups = np.repeat(np.arange(40), 200)
    turned = choose_regeneration(x, np.ones(8000), groups)
    assert turned.fit.family == "rotated product", turned.candidates
    straight = choose_regeneration(y, np.ones(8000), groups)  # as good, and cheaper: the plain product
    assert straight.fit.family == "product", straight.candidates
    draws = jnp.asarray(x[:40])
    plain, padded = turned.fit.distribution, turned.fit.padded(2 * turned.fit.num_components)
    np.testing.assert_allclose(jax.vmap(padded.log_prob)(draws), jax.vmap(plain.log_prob)(draws), rtol=1e-12)
    np.testing.assert_allclose(turned.fit.log_prob(x[:40]), jax.vmap(plain.log_prob)(draws), rtol=1e-10)


@pytest.mark.parametrize("family", ["product", "diagonal", "full-t", "conditional"])
def test_a_fit_to_draws_that_are_not_the_targets_is_refitted_to_the_targets(family):
    """Chosen from over-dispersed draws (a stand-in for seeding chains that have not equilibrated),
    a fit of each family is fitted again, with as many components, to draws of the target, and the
    new fit wins on held-out groups; fitted again to the draws it came from it may lose, and is
    then returned as it was. A fit of no family (a Laplace mixture) is returned as it is."""
    from restore.regeneration._choose import refit_regeneration
    rng = np.random.default_rng(5)
    n = 4000
    groups = np.repeat(np.arange(40), n // 40)
    modes = np.where(rng.uniform(size=(n, 3)) < 0.3, 2.0, -2.0)
    target = modes + 0.5 * rng.standard_normal((n, 3))
    wide = modes + 1.5 * rng.standard_normal((n, 3))
    first = choose_regeneration(wide, np.ones(n), groups, families=(family,)).fit
    choice = refit_regeneration(first, target, np.ones(n), groups)
    old, new = choice.candidates
    assert choice.fit is not first and choice.fit.num_components == first.num_components, choice.candidates
    assert new.score > old.score + 0.1, choice.candidates
    again = refit_regeneration(choice.fit, target, np.ones(n), groups, seed=1)
    assert again.fit is choice.fit or again.candidates[1].score > again.candidates[0].score
    made_elsewhere = first._replace(family="laplace")
    assert refit_regeneration(made_elsewhere, target, np.ones(n), groups).fit is made_elsewhere


def test_a_later_choice_fits_again_only_the_families_that_came_close():
    """`close_families` drops a family that trailed by more than `FAMILY_GAIN` nats per coordinate, with the
    Student-t family searched from it, and keeps the rest (the scores are Many-Well-32's first choice)."""
    d = 32
    scored = [("product", -34.16), ("diagonal", -55.95), ("diagonal student-t(df=5)", -54.43), ("full", -56.26),
              ("conditional", -55.96), ("rotated product", -34.20)]  # fmt: skip
    candidates = [Candidate(family, 1, 1, score) for family, score in scored]
    kept = close_families(FAMILIES, candidates, d)
    assert kept == ("product", "rotated-product"), kept  # conditional-t and full-t had no candidate: they follow their base
    close = [c._replace(score=-34.16 - 0.9 * FAMILY_GAIN * d) if c.family == "full" else c for c in candidates]
    assert close_families(FAMILIES, close, d) == ("product", "rotated-product", "full", "full-t")
    assert close_families(FAMILIES, [], d) == FAMILIES
