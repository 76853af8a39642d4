"""`targets.analytic.Rotated`: the density, draws and moments of a target seen through a rotation."""

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np
import pytest
import scipy.stats

from targets.analytic import GaussianMixture, ManyWell, Rotated, random_rotation


def test_random_rotation_is_orthogonal_and_fixed_by_its_seed():
    q = random_rotation(7, 3)
    assert np.allclose(q @ q.T, np.eye(7), atol=1e-12)
    assert np.array_equal(q, random_rotation(7, 3))
    assert not np.allclose(q, random_rotation(7, 4))


def test_a_rotated_gaussian_is_the_gaussian_of_the_rotated_covariance():
    """Against SciPy's density of `N(Q m, Q C Q^T)`. Fails for `Q` in place of `Q^T` in the density
    (checked: the two differ by several nats at these points)."""
    d = 5
    q = random_rotation(d, 1)
    mean, cov = np.arange(d, dtype=float), np.diag(np.logspace(-1, 1, d))
    target = Rotated(GaussianMixture(mean[None], cov[None]), q)
    points = np.random.default_rng(0).normal(size=(20, d)) * 2 + q @ mean
    exact = scipy.stats.multivariate_normal(q @ mean, q @ cov @ q.T).logpdf(points)
    mine = np.asarray(jax.vmap(target.logdensity)(points))
    assert np.allclose(mine, exact, atol=1e-10)
    assert np.allclose(target.mean, q @ mean) and np.allclose(target.covariance, q @ cov @ q.T)
    wrong = np.asarray(jax.vmap(lambda y: target.target.logdensity(q @ y))(points))
    assert np.max(np.abs(wrong - exact)) > 1.0


def test_rotated_draws_have_the_exact_moments_and_log_z_is_kept():
    """Means and covariances of 200,000 draws of a rotated 6-d Many Well within 5 standard errors."""
    target = Rotated(ManyWell(6), random_rotation(6, 2))
    x = np.asarray(target.sample(jax.random.key(0), 200_000), np.float64)
    mean, cov = np.asarray(target.mean), np.asarray(target.covariance)
    sd = np.sqrt(np.diag(cov))
    assert np.all(np.abs(x.mean(axis=0) - mean) < 5 * sd / np.sqrt(len(x)))
    assert np.max(np.abs(np.cov(x.T) - cov)) < 0.05
    assert target.log_normalising_constant == ManyWell(6).log_normalising_constant
    assert float(target.logdensity(x[0])) == pytest.approx(float(ManyWell(6).logdensity(target.rotation.T @ x[0])))


def test_bad_rotations_are_refused():
    base = ManyWell(4)
    with pytest.raises(ValueError, match="shape"):
        Rotated(base, np.eye(3))
    with pytest.raises(ValueError, match="orthogonal"):
        Rotated(base, 2 * np.eye(4))
    with pytest.raises(NotImplementedError):
        Rotated(base, np.eye(4)).marginal_cdf(0, 0.0)
