"""Tests of the targets with exact normalising constants: `ManyWell` and `spread_gaussian_mixture`.

Exact `log Z` against independent numerical integration, exact samplers against the
density (Kolmogorov-Smirnov tests with fixed keys), the rejection envelope's bound on a
fine grid, moments, mode assignment and input errors.
"""

import jax

jax.config.update("jax_enable_x64", True)

import math

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.integrate
import scipy.special
import scipy.stats
from jax.scipy.special import ndtr

from targets.analytic import (
    AbstractTarget,
    Funnel,
    GaussianMixture,
    ManyWell,
    _double_well,
    spread_gaussian_mixture,
    well_separated_gaussian_mixture,
)

N_DRAWS = 100_000
KS_P_MIN = 1e-3
Z_MAX = 5.0


def _pair_integrand(x: float) -> float:
    return math.exp(-(x**4) + 6.0 * x**2 + 0.5 * x)


def _quad(fn, lower: float, upper: float) -> float:
    return scipy.integrate.quad(fn, lower, upper, epsabs=0.0, epsrel=1e-12, limit=400)[0]


@pytest.fixture(scope="module")
def many_well_draws() -> np.ndarray:
    return np.asarray(ManyWell(6).sample(jax.random.key(3), N_DRAWS))


def test_many_well_log_z_matches_independent_quadrature():
    """`log Z_pair` recomputed by plain adaptive quadrature over the real line, and the published 164.70."""
    z, err = scipy.integrate.quad(_pair_integrand, -np.inf, np.inf, epsabs=0.0, epsrel=1e-13, limit=400)
    assert err < 1e-12 * z
    log_pair = math.log(z) + 0.5 * math.log(2.0 * math.pi)
    assert ManyWell(2).log_normalising_constant == pytest.approx(log_pair, rel=1e-12)
    assert ManyWell(32).log_normalising_constant == pytest.approx(16.0 * log_pair, rel=1e-12)
    assert abs(ManyWell(32).log_normalising_constant - 164.6957) < 1e-3


def test_many_well_pair_integrates_to_its_normalising_constant_in_2d():
    """Trapezoid rule on a fine 2-d grid of the jitted `logdensity` (spectrally accurate for this integrand)."""
    target = ManyWell(2)
    a = np.linspace(-4.0, 4.0, 4001)
    b = np.linspace(-9.0, 9.0, 1201)
    ga, gb = np.meshgrid(a, b, indexing="ij")
    points = jnp.asarray(np.stack([ga.ravel(), gb.ravel()], axis=1))
    log_p = np.asarray(jax.jit(jax.vmap(target.logdensity))(points)).reshape(ga.shape)
    shift = log_p.max()
    integral = np.trapezoid(np.trapezoid(np.exp(log_p - shift), b, axis=1), a)
    assert math.log(integral) + shift == pytest.approx(target.log_normalising_constant, abs=1e-9)


def test_many_well_constants_match_quadrature():
    c = _double_well.constants()
    z = math.exp(c.log_normaliser)
    moment = lambda f: _quad(lambda x: f(x) * _pair_integrand(x), -np.inf, np.inf) / z  # noqa: E731
    assert c.mean == pytest.approx(moment(lambda x: x), rel=1e-10)
    assert c.second_moment == pytest.approx(moment(lambda x: x * x), rel=1e-10)
    assert c.positive_probability == pytest.approx(moment(lambda x: float(x > 0)), rel=1e-9)
    assert c.positive_probability == pytest.approx(0.8443, abs=1e-4)
    target = ManyWell(4)
    np.testing.assert_allclose(target.mean, [c.mean, 0.0, c.mean, 0.0])
    np.testing.assert_allclose(np.diag(target.covariance), [c.second_moment - c.mean**2, 1.0] * 2)


def test_double_well_cdf_matches_quadrature():
    c = _double_well.constants()
    ts = np.array([-3.0, -1.9, -1.71, -1.0, 0.0, 0.7, 1.75, 2.2, 3.0])
    ref = [_quad(_pair_integrand, -np.inf, t) / math.exp(c.log_normaliser) for t in ts]
    np.testing.assert_allclose(np.asarray(ManyWell(2).marginal_cdf(0, jnp.asarray(ts))), ref, rtol=0, atol=1e-12)
    assert float(ManyWell(2).marginal_cdf(0, -10.0)) == 0.0
    assert float(ManyWell(2).marginal_cdf(0, 10.0)) == pytest.approx(1.0, abs=1e-13)


def test_rejection_envelope_bounds_the_density_on_a_fine_grid():
    """`h - log g <= log_bound` everywhere (checked on 4M points), and the bound is not loose."""
    c = _double_well.constants()
    x = np.linspace(-12.0, 12.0, 4_000_001)
    gap = _double_well.log_unnormalised(x) - np.asarray(_double_well.log_envelope(jnp.asarray(x), c))
    assert gap.max() <= c.log_bound
    assert gap.max() > c.log_bound - 0.05
    assert 0.7 < c.acceptance < 0.8


def test_many_well_samples_match_marginal_cdfs(many_well_draws):
    target = ManyWell(6)
    for i in (0, 1, 4):
        cdf = lambda t, i=i: np.asarray(target.marginal_cdf(i, jnp.asarray(t)))  # noqa: E731
        assert scipy.stats.kstest(many_well_draws[:20_000, i], cdf).pvalue > KS_P_MIN, i


@pytest.mark.slow
def test_many_well_samples_match_density_on_a_projection(many_well_draws):
    """KS on `a + b` of one pair: its CDF is `∫ f(a) Phi(t - a) da`, by quadrature on a fine grid."""
    s = many_well_draws[:10_000, 0] + many_well_draws[:10_000, 1]
    grid = np.linspace(-_double_well.SUPPORT, _double_well.SUPPORT, 4001)
    density = np.exp(_double_well.log_unnormalised(grid) - _double_well.constants().log_normaliser)

    def cdf(t):
        return np.trapezoid(density * scipy.special.ndtr(np.atleast_1d(t)[:, None] - grid), grid, axis=1)

    assert scipy.stats.kstest(s, cdf).pvalue > KS_P_MIN


def test_many_well_sample_moments_and_mode_probability(many_well_draws):
    target = ManyWell(6)
    x = many_well_draws
    n = len(x)
    z_mean = (x.mean(0) - np.asarray(target.mean)) / (x.std(0) / math.sqrt(n))
    assert np.all(np.abs(z_mean) < Z_MAX), z_mean
    var = np.diag(np.asarray(target.covariance))
    centred = (x - np.asarray(target.mean)) ** 2
    z_var = (centred.mean(0) - var) / (centred.std(0) / math.sqrt(n))
    assert np.all(np.abs(z_var) < Z_MAX), z_var
    positive = (x[:, 0::2] > 0).mean(0)
    p = target.positive_probability
    assert np.all(np.abs(positive - p) < Z_MAX * math.sqrt(p * (1 - p) / n)), positive


def test_many_well_mode_assignment_and_shapes():
    target = ManyWell(6)
    assert target.num_pairs == 3 and target.num_modes == 8
    x = jnp.array([1.0, 0.0, -1.0, 5.0, 2.0, -5.0])
    assert int(target.assign_mode(x)) == 0b101
    assert int(target.assign_mode(-x)) == 0b010
    assert isinstance(target, AbstractTarget)
    g = jax.grad(target.logdensity)(x)
    np.testing.assert_allclose(g[1::2], -x[1::2])
    with pytest.raises(ValueError, match="at most 31 pairs"):
        ManyWell(64).assign_mode(jnp.zeros(64))


def test_many_well_input_errors():
    with pytest.raises(ValueError, match="even"):
        ManyWell(5)
    with pytest.raises(ValueError, match="dim"):
        ManyWell(0)
    with pytest.raises(ValueError, match="shape"):
        ManyWell(4).logdensity(jnp.zeros(3))


def test_normalised_targets_report_zero_log_z():
    assert Funnel().log_normalising_constant == 0.0
    assert well_separated_gaussian_mixture(2).log_normalising_constant == 0.0
    assert spread_gaussian_mixture().log_normalising_constant == 0.0


def test_spread_mixture_geometry_and_seed():
    m = spread_gaussian_mixture()
    assert isinstance(m, GaussianMixture)
    assert m.means.shape == (40, 2) and np.all(np.abs(np.asarray(m.means)) <= 40.0)
    np.testing.assert_allclose(m.weights, 1.0 / 40)
    np.testing.assert_allclose(m.covariances, np.broadcast_to(np.eye(2), (40, 2, 2)))
    np.testing.assert_array_equal(m.means, spread_gaussian_mixture().means)
    other = spread_gaussian_mixture(key=jax.random.key(1))
    assert not np.allclose(other.means, m.means)
    small = spread_gaussian_mixture(3, 5, half_width=2.0, scale=0.5)
    assert small.means.shape == (5, 3) and np.all(np.abs(np.asarray(small.means)) <= 2.0)
    np.testing.assert_allclose(small.covariances[0], 0.25 * np.eye(3))


def test_spread_mixture_integrates_to_one_in_2d():
    m = spread_gaussian_mixture()
    a = np.linspace(-50.0, 50.0, 401)  # step 0.25: the trapezoid error on unit Gaussians is ~exp(-2 pi^2 / 0.25^2)
    ga, gb = np.meshgrid(a, a, indexing="ij")
    points = jnp.asarray(np.stack([ga.ravel(), gb.ravel()], axis=1))
    p = np.exp(np.asarray(jax.jit(jax.vmap(m.logdensity))(points))).reshape(ga.shape)
    integral = np.trapezoid(np.trapezoid(p, a, axis=1), a)
    assert math.log(integral) == pytest.approx(m.log_normalising_constant, abs=1e-9)


def test_spread_mixture_samples_match_density_on_a_projection():
    m = spread_gaussian_mixture()
    u = np.array([0.6, 0.8])
    x = np.asarray(m.sample(jax.random.key(5), 20_000))
    centres = np.asarray(m.means) @ u

    def cdf(t):
        return np.asarray(ndtr(jnp.asarray(np.atleast_1d(t))[:, None] - centres)).mean(axis=1)

    assert scipy.stats.kstest(x @ u, cdf).pvalue > KS_P_MIN


def test_spread_mixture_input_errors():
    with pytest.raises(ValueError, match="half_width"):
        spread_gaussian_mixture(half_width=0.0)
    with pytest.raises(ValueError, match="num_modes"):
        spread_gaussian_mixture(num_modes=0)
    with pytest.raises(ValueError, match="scale"):
        spread_gaussian_mixture(scale=-1.0)
