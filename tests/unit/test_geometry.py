"""Correlated local moves and Laplace candidates: what `autosample` uses on correlated targets."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from restore._autosample import default_kernel
from restore._point import Point
from restore._preconditioning import guide_components
from restore.local import CorrelatedRandomWalk, GuidedRandomWalk, RandomWalk
from restore.regeneration import DiagonalMixture, Gaussian, Mixture, StudentT, choose_regeneration, find_modes
from restore.regeneration._laplace_fit import laplace_fit

rng = np.random.default_rng(5)
Q, _ = np.linalg.qr(rng.standard_normal((4, 4)))
COV = Q @ np.diag([0.01, 0.3, 3.0, 100.0]) @ Q.T
MEAN = np.array([1.0, -2.0, 0.5, 3.0])


def gaussian(x):
    r = x - jnp.asarray(MEAN)
    return -0.5 * r @ jnp.asarray(np.linalg.inv(COV)) @ r


def test_correlated_random_walk_proposes_with_its_covariance():
    tril = np.linalg.cholesky(COV)
    kernel = CorrelatedRandomWalk(jnp.asarray(tril))
    point = Point(jnp.zeros(4), jnp.zeros(()), jnp.zeros(4), None)
    keys = jax.random.split(jax.random.key(0), 20000)
    steps = np.asarray(jax.vmap(lambda k: kernel.propose(k, point, gaussian)[0])(keys))
    np.testing.assert_allclose(np.cov(steps.T), COV, rtol=0.05, atol=0.02 * np.sqrt(np.outer(np.diag(COV), np.diag(COV))).max())
    with pytest.raises(ValueError, match="lower triangular"):
        CorrelatedRandomWalk(jnp.asarray(tril.T))
    with pytest.raises(ValueError, match="dimension"):
        kernel.check_dim(3)


def test_default_kernel_follows_full_components_and_stays_diagonal_otherwise():
    full = Mixture([Gaussian(jnp.asarray(MEAN), jnp.asarray(COV))])
    kernel = default_kernel(full, 4, jnp.float32)
    assert isinstance(kernel, CorrelatedRandomWalk)
    tril = np.asarray(kernel.scale_tril, np.float64)
    np.testing.assert_allclose(tril @ tril.T, (2.38**2 / 4) * COV, rtol=1e-4, atol=1e-6)
    diagonal = DiagonalMixture(np.ones(1), np.zeros((1, 4)), np.ones((1, 4)))
    assert isinstance(default_kernel(diagonal, 4, jnp.float32), RandomWalk)


def test_default_kernel_of_several_components_is_guided_by_them():
    """Two components of one covariance: the guided walk proposes with `(2.38^2 / d)` times it
    anywhere; a padded component (weight zero) takes no part."""
    two = Mixture([Gaussian(jnp.asarray(MEAN), jnp.asarray(COV)), StudentT(jnp.asarray(MEAN) + 1.0, jnp.asarray(COV), 5.0)])
    kernel = default_kernel(two, 4, jnp.float64)
    assert isinstance(kernel, GuidedRandomWalk) and not kernel.diagonal
    point = Point(jnp.asarray(MEAN) + 3.0, jnp.zeros(()), jnp.zeros(4), None)
    keys = jax.random.split(jax.random.key(0), 20000)
    steps = np.asarray(jax.vmap(lambda k: kernel.propose(k, point, gaussian)[0])(keys)) - np.asarray(point.position)
    expected = (2.38**2 / 4) * COV
    np.testing.assert_allclose(np.cov(steps.T), expected, rtol=0.05, atol=0.02 * np.sqrt(np.outer(np.diag(expected), np.diag(expected))).max())
    padded = DiagonalMixture(np.ones(3), np.zeros((3, 4)), np.stack([np.ones(4), 4 * np.ones(4), 1e-3 * np.ones(4)]))
    padded = eqx.tree_at(lambda u: u.log_weights, padded, jnp.log(jnp.asarray([0.5, 0.5, 0.0])))  # as `Fit.padded` pads
    walk = default_kernel(padded, 4, jnp.float64)
    assert isinstance(walk, GuidedRandomWalk) and walk.diagonal
    log_w, means, trils = guide_components(padded)
    assert np.isneginf(log_w[2]) and trils.shape == (3, 4, 4)
    p = np.asarray(walk.precision(jnp.zeros(4)))  # between the unit and the wide component, never the padded one
    assert np.all((p > 1 / 4) & (p < 1.0))


def test_guide_components_flatten_nested_mixtures():
    inner = DiagonalMixture(np.array([0.25, 0.75]), np.zeros((2, 3)), np.ones((2, 3)))
    outer = Mixture([inner, StudentT(jnp.zeros(3), 9.0 * jnp.eye(3), 3.0)], jnp.asarray([0.9, 0.1]))
    log_w, means, trils = guide_components(outer)
    np.testing.assert_allclose(np.exp(log_w), [0.9 * 0.25, 0.9 * 0.75, 0.1], rtol=1e-6)
    np.testing.assert_allclose(trils[2], 3.0 * np.eye(3), rtol=1e-6)
    assert means.shape == (3, 3)


def test_guided_random_walk_refuses_bad_guides():
    eye = np.eye(2)[None]
    with pytest.raises(ValueError, match="needs log_weights"):
        GuidedRandomWalk(np.zeros(2), np.zeros((1, 2)), eye)
    with pytest.raises(ValueError, match="lower triangular"):
        GuidedRandomWalk(np.zeros(1), np.zeros((1, 2)), np.array([[[1.0, 1.0], [0.0, 1.0]]]))
    with pytest.raises(ValueError, match="at least one finite"):
        GuidedRandomWalk(np.array([-np.inf]), np.zeros((1, 2)), eye)
    with pytest.raises(ValueError, match="step must be positive"):
        GuidedRandomWalk(np.zeros(1), np.zeros((1, 2)), eye, step=0.0)
    with pytest.raises(ValueError, match="dimension 2"):
        GuidedRandomWalk(np.zeros(1), np.zeros((1, 2)), eye).check_dim(3)


def test_laplace_fit_of_a_gaussian_is_the_gaussian():
    modes = find_modes(gaussian, jnp.asarray(rng.uniform(-5, 5, (8, 4))))
    fit = laplace_fit(modes, df=None)
    assert fit.family == "laplace" and fit.num_components == 1
    x = rng.standard_normal((50, 4)) @ np.linalg.cholesky(COV).T + MEAN
    exact = -0.5 * np.einsum("ni,ij,nj->n", x - MEAN, np.linalg.inv(COV), x - MEAN) - 0.5 * np.linalg.slogdet(2 * math.pi * COV)[1]
    np.testing.assert_allclose(fit.log_prob(x), exact, rtol=1e-6)
    u = fit.distribution
    np.testing.assert_allclose(np.asarray(jax.vmap(u.log_prob)(jnp.asarray(x))), exact, rtol=1e-4)
    assert laplace_fit(modes).family.startswith("laplace student-t")


def test_a_laplace_candidate_wins_where_it_is_closer_and_is_returned_as_given():
    modes = find_modes(gaussian, jnp.asarray(rng.uniform(-5, 5, (8, 4))))
    exact = laplace_fit(modes, df=None)
    draws = rng.standard_normal((4000, 4)) @ np.linalg.cholesky(COV).T + MEAN
    groups = np.repeat(np.arange(40), 100)
    chosen = choose_regeneration(draws, np.ones(4000), groups, families=("diagonal",), extra=(exact,))
    assert chosen.fit is exact
    assert any(c.family == "laplace" for c in chosen.candidates)
    # A Laplace candidate far from the draws is scored and left out.
    shifted = laplace_fit(find_modes(lambda x: gaussian(x - 20.0), jnp.asarray(rng.uniform(15, 25, (8, 4)))), df=None)
    assert choose_regeneration(draws, np.ones(4000), groups, families=("full",), extra=(shifted,)).fit.family == "full"
