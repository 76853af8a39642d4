"""Tests of `targets.analytic`: normalisation, exact sampling, exact moments, errors.

Every random quantity uses a fixed key or seed, so the outcome is deterministic.
Targets and their samples are module-scoped fixtures: on CPU most of the run time
is XLA compilation, so each target is sampled once and reused by several tests.
"""

import jax

jax.config.update("jax_enable_x64", True)

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.integrate
import scipy.special
import scipy.stats

from targets import analytic
from targets.analytic import (
    AbstractMixture,
    AbstractTarget,
    Banana,
    Funnel,
    GaussianMixture,
    Ring,
    StudentTMixture,
    well_separated_gaussian_mixture,
    well_separated_student_t_mixture,
)
from targets.analytic._builders import separated_points
from targets.analytic._special import log_gamma_variates, student_t_cdf

N_KS = 20_000  # draws for Kolmogorov-Smirnov tests
N_MOMENTS = 200_000  # draws for mean / covariance checks
KS_P_MIN = 1e-3
Z_MAX = 5.0  # tolerance in Monte Carlo standard errors


# ----------------------------------------------------------------------------- helpers


@eqx.filter_jit
def _batched_logdensity(target: AbstractTarget, x: jax.Array) -> jax.Array:
    return jax.vmap(target.logdensity)(x)


def _logdensity(target: AbstractTarget, x) -> np.ndarray:
    return np.asarray(_batched_logdensity(target, jnp.asarray(x)))


@eqx.filter_jit
def _single_logdensity(target: AbstractTarget, x: jax.Array) -> jax.Array:
    return target.logdensity(x)


def _grid_integral_2d(target: AbstractTarget, xs: np.ndarray, ys: np.ndarray) -> float:
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    pts = np.stack([gx.ravel(), gy.ravel()], axis=1)
    dens = np.exp(_logdensity(target, pts)).reshape(gx.shape)
    return float(np.trapezoid(np.trapezoid(dens, ys, axis=1), xs))


def _assert_moments(samples, mean, cov, z_max: float = Z_MAX) -> None:
    """Sample mean and covariance within `z_max` Monte Carlo standard errors of the exact ones."""
    x = np.asarray(samples)
    mean = np.asarray(mean)
    cov = np.asarray(cov)
    n = x.shape[0]
    z_mean = (x.mean(0) - mean) / (x.std(0) / math.sqrt(n))
    assert np.all(np.abs(z_mean) < z_max), f"mean z-scores {z_mean}"
    c = x - mean  # centred with the exact mean, E[c c^T] is exactly the covariance
    prods = c[:, :, None] * c[:, None, :]
    z_cov = (prods.mean(0) - cov) / (prods.std(0) / math.sqrt(n))
    assert np.all(np.abs(z_cov) < z_max), f"covariance z-scores {z_cov}"


def _ks_pvalue(samples, cdf) -> float:
    return scipy.stats.kstest(np.asarray(samples), lambda t: np.asarray(cdf(t))).pvalue


def _points(seed: int, n: int, d: int, scale: float = 3.0) -> np.ndarray:
    return scale * np.random.default_rng(seed).standard_normal((n, d))


# ---------------------------------------------------------------------------- fixtures


class _Drawn:
    """A target with exact draws (and, for mixtures, their components)."""

    def __init__(self, target: AbstractTarget, n: int, seed: int):
        self.target = target
        if isinstance(target, AbstractMixture):
            x, modes = target.sample_with_modes(jax.random.key(seed), n)
            self.modes = np.asarray(modes)
        else:
            x = target.sample(jax.random.key(seed), n)
        self.x = np.asarray(x)


@pytest.fixture(scope="module")
def gmm2() -> _Drawn:
    # Rotated, mildly anisotropic, unequal weights 1/6, 2/6, 3/6.
    return _Drawn(well_separated_gaussian_mixture(2, 3, key=jax.random.key(11)), N_MOMENTS, 1)


@pytest.fixture(scope="module")
def tmix2() -> _Drawn:
    # Correlated scales, separated locations (for `assign_mode`); df > 4 so the sample
    # covariance has a finite variance (needed by the moment check).
    means = jnp.array([[-12.0, 0.0], [10.0, 6.0]])
    scales = jnp.array([[[1.0, 0.4], [0.4, 0.8]], [[2.0, -0.5], [-0.5, 1.0]]])
    target = StudentTMixture(means, scales, jnp.array([6.0, 9.0]), jnp.array([1.0, 3.0]))
    return _Drawn(target, N_MOMENTS, 2)


@pytest.fixture(scope="module")
def banana3() -> _Drawn:
    return _Drawn(Banana(dim=3, curvature=0.1, scale=4.0), N_MOMENTS, 3)


@pytest.fixture(scope="module")
def ring2() -> _Drawn:
    return _Drawn(Ring(), N_MOMENTS, 4)


@pytest.fixture(scope="module")
def ring3() -> _Drawn:
    return _Drawn(Ring(3, radius=2.0, width=0.7), N_MOMENTS, 5)


@pytest.fixture(scope="module")
def funnel3() -> _Drawn:
    # scale 1: with Neal's scale 3 the Monte Carlo variance of the covariance is huge.
    return _Drawn(Funnel(dim=3, scale=1.0), N_MOMENTS, 6)


# ------------------------------------------------------------------ structure / interface


def test_public_names_and_abstract_classes():
    assert analytic.GaussianMixture is GaussianMixture
    for cls in (GaussianMixture, StudentTMixture):
        assert issubclass(cls, AbstractMixture)
    for cls in (Banana, Ring, Funnel):
        assert issubclass(cls, AbstractTarget) and not issubclass(cls, AbstractMixture)
    with pytest.raises(TypeError):
        AbstractTarget()  # abstract
    with pytest.raises(TypeError):
        AbstractMixture()


# ------------------------------------------------------------------------ normalisation


def test_gaussian_mixture_normalised_on_grid(gmm2):
    xs = np.linspace(-14.0, 14.0, 561)
    assert abs(_grid_integral_2d(gmm2.target, xs, xs) - 1.0) < 1e-3


def test_gaussian_mixture_matches_scipy_in_4d():
    rng = np.random.default_rng(0)
    means = 3 * rng.standard_normal((3, 4))
    a = rng.standard_normal((3, 4, 4))
    covs = a @ np.swapaxes(a, 1, 2) + 0.5 * np.eye(4)
    weights = np.array([2.0, 1.0, 5.0])
    target = GaussianMixture(means, covs, weights)
    x = _points(1, 50, 4)
    ref = scipy.special.logsumexp(
        np.stack(
            [scipy.stats.multivariate_normal(m, c).logpdf(x) for m, c in zip(means, covs)], axis=1
        )
        + np.log(weights / weights.sum()),
        axis=1,
    )
    np.testing.assert_allclose(_logdensity(target, x), ref, rtol=1e-10, atol=1e-10)
    # Moments by the law of total variance, written out independently.
    w = weights / weights.sum()
    mean = w @ means
    cov = sum(wk * (c + np.outer(m - mean, m - mean)) for wk, m, c in zip(w, means, covs))
    np.testing.assert_allclose(target.mean, mean, rtol=1e-12)
    np.testing.assert_allclose(target.covariance, cov, rtol=1e-12)


def test_gaussian_mixture_covariance_forms_agree():
    means = jnp.array([[0.0, 1.0], [2.0, -1.0]])
    full = GaussianMixture(means, jnp.array([2.0 * np.eye(2), 3.0 * np.eye(2)]))
    per_component = GaussianMixture(means, jnp.array([2.0, 3.0]))
    diagonal = GaussianMixture(means, jnp.array([[2.0, 2.0], [3.0, 3.0]]))
    for other in (per_component, diagonal):
        np.testing.assert_allclose(other.covariances, full.covariances, rtol=1e-15)
        np.testing.assert_allclose(other.covariance, full.covariance, rtol=1e-12)
    np.testing.assert_allclose(full.weights, [0.5, 0.5])
    assert full.num_modes == 2 and full.dim == 2


def test_student_t_mixture_normalised_on_grid(tmix2):
    # Heavy tails: integrate on x = 3 sinh(u), u uniform, to reach |x| ~ 1e3.
    u = np.linspace(-6.5, 6.5, 1301)
    x = 3.0 * np.sinh(u)
    jac = 3.0 * np.cosh(u)
    gx, gy = np.meshgrid(x, x, indexing="ij")
    pts = np.stack([gx.ravel(), gy.ravel()], axis=1)
    dens = np.exp(_logdensity(tmix2.target, pts)).reshape(gx.shape) * jac[:, None] * jac[None, :]
    total = np.trapezoid(np.trapezoid(dens, u, axis=1), u)
    assert abs(total - 1.0) < 1e-3


def test_student_t_mixture_matches_scipy_in_3d():
    means = np.array([[0.0, 1.0, 2.0], [-3.0, 0.0, 1.0]])
    scales = np.array(
        [np.diag([1.0, 2.0, 0.5]), [[2.0, 0.3, 0.1], [0.3, 1.0, 0.2], [0.1, 0.2, 1.5]]]
    )
    dfs = np.array([3.0, 1.5])
    weights = np.array([0.3, 0.7])
    target = StudentTMixture(means, scales, dfs, weights)
    x = _points(2, 40, 3, scale=5.0)
    ref = scipy.special.logsumexp(
        np.stack(
            [
                scipy.stats.multivariate_t(m, s, df=nu).logpdf(x)
                for m, s, nu in zip(means, scales, dfs)
            ],
            axis=1,
        )
        + np.log(weights),
        axis=1,
    )
    np.testing.assert_allclose(_logdensity(target, x), ref, rtol=1e-10, atol=1e-10)


def test_banana_normalised_on_grid():
    target = Banana()  # curvature 0.1, scale 10: the banana reaches y_1 ~ 250
    y0 = np.linspace(-65.0, 65.0, 1301)
    y1 = np.linspace(-25.0, 425.0, 4501)
    assert abs(_grid_integral_2d(target, y0, y1) - 1.0) < 1e-3


def test_banana_matches_untwisted_gaussian(banana3):
    y = _points(3, 30, 3)
    x1 = y[:, 1] - 0.1 * (y[:, 0] ** 2 - 16.0)
    ref = (
        scipy.stats.norm(0, 4.0).logpdf(y[:, 0])
        + scipy.stats.norm.logpdf(x1)
        + scipy.stats.norm.logpdf(y[:, 2])
    )
    np.testing.assert_allclose(_logdensity(banana3.target, y), ref, rtol=1e-12)


def test_ring_normalised_on_grid_2d_and_1d(ring2):
    xs = np.linspace(-6.0, 6.0, 601)
    assert abs(_grid_integral_2d(ring2.target, xs, xs) - 1.0) < 1e-3
    ring1 = Ring(dim=1, radius=1.0, width=0.8)  # the two bumps overlap at 0
    t = np.linspace(-8.0, 8.0, 4001)
    dens = np.exp(_logdensity(ring1, t[:, None]))
    assert abs(np.trapezoid(dens, t) - 1.0) < 1e-6


@pytest.mark.parametrize("dim, radius, width", [(3, 3.0, 0.5), (5, 1.0, 2.0), (10, 0.0, 1.0)])
def test_ring_normalised_radially(dim, radius, width):
    # p depends on |x| only: integral = |S^(d-1)| int rho^(d-1) p(rho e) d rho for any unit e.
    ring = Ring(dim, radius, width)
    direction = np.random.default_rng(dim).standard_normal(dim)
    direction /= np.linalg.norm(direction)
    rho = np.linspace(0.0, radius + 40 * width, 20001)
    dens = np.exp(_logdensity(ring, rho[:, None] * direction))
    sphere = 2 * math.pi ** (dim / 2) / math.gamma(dim / 2)
    assert abs(sphere * np.trapezoid(rho ** (dim - 1) * dens, rho) - 1.0) < 1e-6


@pytest.mark.parametrize(
    "dim, radius, width", [(1, 0.0, 1.0), (2, 3.0, 0.5), (7, 1.0, 2.0), (40, 30.0, 0.2)]
)
def test_ring_constants_match_quadrature(dim, radius, width):
    ring = Ring(dim, radius, width)
    m = dim - 1
    mode = 0.5 * (radius + math.sqrt(radius**2 + 4 * m * width**2)) or 1.0

    def f(rho, power):  # rho^power exp(-(rho - r)^2 / (2 w^2)), divided by its value at the mode
        return np.exp(
            power * np.log(rho / mode)
            - ((rho - radius) ** 2 - (mode - radius) ** 2) / (2 * width**2)
        )

    hi = mode + 60 * width
    k0 = scipy.integrate.quad(f, 0, hi, args=(m,), points=[mode], limit=400)[0]
    k2 = scipy.integrate.quad(f, 0, hi, args=(m + 2,), points=[mode], limit=400)[0]
    log_z = (
        math.log(2.0)
        + 0.5 * dim * math.log(math.pi)
        - math.lgamma(0.5 * dim)
        + math.log(k0)
        + m * math.log(mode)
        - (mode - radius) ** 2 / (2 * width**2)
    )
    assert abs(ring.log_normaliser - log_z) < 1e-9
    assert abs(ring.second_moment / (mode**2 * k2 / k0) - 1.0) < 1e-9
    q = np.array([0.5 * mode, mode, mode + width, mode + 5 * width])
    parts = [scipy.integrate.quad(f, 0, qi, args=(m,), limit=400)[0] / k0 for qi in q]
    np.testing.assert_allclose(np.asarray(ring.radial_cdf(q)), parts, atol=1e-8)


def test_funnel_normalised_on_grid_2d():
    target = Funnel(dim=2, scale=1.5)
    # v on a uniform grid; for each v the x-grid is scaled to the conditional width.
    v = np.linspace(-12.0, 12.0, 961)
    u = np.linspace(-12.0, 12.0, 481)
    width = np.exp(0.5 * v)
    x = u[None, :] * width[:, None]
    pts = np.stack([np.broadcast_to(v[:, None], x.shape).ravel(), x.ravel()], axis=1)
    dens = np.exp(_logdensity(target, pts)).reshape(x.shape)
    inner = np.trapezoid(dens, u, axis=1) * width  # dx = width du
    assert abs(np.trapezoid(inner, v) - 1.0) < 1e-3


def test_funnel_matches_scipy_in_10d():
    target = Funnel()  # Neal's: dim 10, scale 3
    x = _points(4, 30, 10, scale=1.0)
    x[:, 0] *= 3.0
    ref = scipy.stats.norm(0, 3.0).logpdf(x[:, 0]) + scipy.stats.norm(
        0, np.exp(0.5 * x[:, :1])
    ).logpdf(x[:, 1:]).sum(1)
    np.testing.assert_allclose(_logdensity(target, x), ref, rtol=1e-11)
    np.testing.assert_allclose(
        np.diag(target.covariance), [9.0] + [math.exp(4.5)] * 9, rtol=1e-12
    )


# ------------------------------------------------- sampling consistent with the density


def test_gaussian_mixture_samples_match_marginal_cdfs(gmm2):
    x = gmm2.x[:N_KS]
    for i in range(2):
        assert _ks_pvalue(x[:, i], lambda t: gmm2.target.marginal_cdf(i, t)) > KS_P_MIN  # noqa: B023
    # Control: the same check rejects a mixture shifted by a tenth of a standard deviation.
    t = gmm2.target
    shifted = GaussianMixture(t.means + 0.1, t.covariances, t.weights)
    assert _ks_pvalue(x[:, 0], lambda s: shifted.marginal_cdf(0, s)) < KS_P_MIN


def test_student_t_mixture_samples_match_marginal_cdfs(tmix2):
    # Coordinate 1: its scales differ between components and correlate with coordinate 0.
    x = tmix2.x[:N_KS]
    assert _ks_pvalue(x[:, 1], lambda t: tmix2.target.marginal_cdf(1, t)) > KS_P_MIN


def test_student_t_cdf_matches_scipy():
    t = np.linspace(-60.0, 60.0, 1201)
    df = np.array([0.5, 1.0, 2.5, 5.0, 40.0])[:, None]
    cdf = jax.jit(student_t_cdf)(t, df)
    np.testing.assert_allclose(cdf, scipy.stats.t.cdf(t, df), atol=1e-12)


def test_log_gamma_variates_are_gamma_distributed():
    alphas = np.array([0.05, 0.7, 1.0, 3.5, 200.0])
    log_g = np.asarray(log_gamma_variates(jax.random.key(7), jnp.repeat(alphas, N_KS)))
    for a, lg in zip(alphas, log_g.reshape(len(alphas), N_KS)):
        assert np.all(np.isfinite(lg))
        assert _ks_pvalue(np.exp(lg), scipy.stats.gamma(a).cdf) > KS_P_MIN, a


def test_banana_samples_match_marginals(banana3):
    y = banana3.x[:N_KS]
    target = banana3.target
    assert _ks_pvalue(y[:, 0], lambda t: target.marginal_cdf(0, t)) > KS_P_MIN
    assert _ks_pvalue(y[:, 2], lambda t: target.marginal_cdf(2, t)) > KS_P_MIN
    # The bent coordinate, untwisted with the density's map, is standard normal.
    x1 = y[:, 1] - 0.1 * (y[:, 0] ** 2 - 16.0)
    assert _ks_pvalue(x1, scipy.stats.norm.cdf) > KS_P_MIN


def test_ring_radii_match_radial_cdf(ring2):
    ring = ring2.target
    radii = np.linalg.norm(ring2.x[:N_KS], axis=1)
    assert _ks_pvalue(radii, ring.radial_cdf) > KS_P_MIN
    # Control: a ring 5% wider is rejected.
    wider = Ring(2, 3.0, 0.525)
    assert _ks_pvalue(radii, wider.radial_cdf) < KS_P_MIN


def test_ring_radii_match_radial_cdf_5d():
    ring = Ring(5, radius=1.0, width=1.0)
    x = np.asarray(ring.sample(jax.random.key(5), N_KS))
    assert _ks_pvalue(np.linalg.norm(x, axis=1), ring.radial_cdf) > KS_P_MIN


def test_ring_coordinates_match_marginal_cdf_3d(ring3):
    ring = ring3.target
    x = ring3.x[:N_KS]
    # Every coordinate has the same marginal; coordinate i of the i-th third of the
    # draws gives independent draws from it.
    parts = np.array_split(np.arange(N_KS), 3)
    pooled = np.concatenate([x[idx, i] for i, idx in enumerate(parts)])
    assert _ks_pvalue(pooled, lambda t: ring.marginal_cdf(0, t)) > KS_P_MIN
    # Directions are uniform: the first coordinate of x / |x| is uniform on [-1, 1].
    u = x[:, 0] / np.linalg.norm(x, axis=1)
    assert _ks_pvalue(u, scipy.stats.uniform(-1, 2).cdf) > KS_P_MIN


def test_ring_1d_samples_match_marginal_and_radial_cdfs():
    ring = Ring(1, radius=1.0, width=0.8)  # the two bumps overlap at 0
    x = np.asarray(ring.sample(jax.random.key(8), N_KS))
    assert _ks_pvalue(x[:, 0], lambda t: ring.marginal_cdf(0, t)) > KS_P_MIN
    assert _ks_pvalue(np.abs(x[:, 0]), ring.radial_cdf) > KS_P_MIN


def test_ring_marginal_cdf_3d_against_quadrature(ring3):
    ring = ring3.target
    # p(x_0 = s) = int p(s, y, z) dy dz = 2 pi int_0^inf r p(sqrt(s^2 + r^2)) dr.
    t = np.linspace(-5.0, 5.0, 1001)
    r = np.linspace(0.0, 8.0, 1601)
    rad = np.sqrt(t[:, None] ** 2 + r[None, :] ** 2)
    logp = -0.5 * ((rad - 2.0) / 0.7) ** 2 - ring.log_normaliser
    pdf = 2 * math.pi * np.trapezoid(r * np.exp(logp), r, axis=1)
    cdf = scipy.integrate.cumulative_trapezoid(pdf, t, initial=0.0)
    np.testing.assert_allclose(np.asarray(ring.marginal_cdf(0, t)), cdf, atol=1e-5)


def test_funnel_samples_match_marginals(funnel3):
    x = funnel3.x[:N_KS]
    assert _ks_pvalue(x[:, 0], lambda t: funnel3.target.marginal_cdf(0, t)) > KS_P_MIN
    # Conditionally on v the other coordinates are N(0, exp(v)).
    z = x[:, 1:] * np.exp(-0.5 * x[:, :1])
    assert _ks_pvalue(z.ravel(), scipy.stats.norm.cdf) > KS_P_MIN


# -------------------------------------------------------------------------- moments


@pytest.mark.parametrize("name", ["gmm2", "tmix2", "banana3", "ring2", "ring3", "funnel3"])
def test_sample_moments_match_exact_moments(name, request):
    drawn = request.getfixturevalue(name)
    _assert_moments(drawn.x, drawn.target.mean, drawn.target.covariance)


def test_exact_moment_formulas():
    banana = Banana(dim=3, curvature=0.1, scale=4.0)
    np.testing.assert_allclose(banana.covariance, np.diag([16.0, 1.0 + 2 * 0.01 * 256, 1.0]))
    np.testing.assert_allclose(banana.mean, 0.0)
    funnel = Funnel(dim=3, scale=1.0)
    np.testing.assert_allclose(funnel.covariance, np.diag([1.0, math.exp(0.5), math.exp(0.5)]))
    ring = Ring(2, 3.0, 0.5)
    # E[rho^2] = int rho^3 e / int rho e; for a Gaussian profile r^2 + 3 w^2 up to tiny terms.
    np.testing.assert_allclose(ring.covariance, (9.0 + 3 * 0.25) / 2 * np.eye(2), rtol=1e-8)
    t = StudentTMixture(jnp.array([[1.0, 0.0], [-1.0, 0.0]]), jnp.array([1.0, 2.0]), 4.0)
    expected = np.diag([2.0 * 1.5, 2.0 * 1.5]) + np.diag([1.0, 0.0])
    np.testing.assert_allclose(t.covariance, expected, rtol=1e-12)


def test_score_has_mean_zero_under_samples(gmm2, banana3):
    # E_p[grad log p] = 0 and E_p[grad log p x^T] = -I (Stein): ties grad logdensity to sample.
    for drawn in (gmm2, banana3):
        x = drawn.x[:50_000]
        scores = np.asarray(jax.jit(jax.vmap(jax.grad(drawn.target.logdensity)))(x))
        z = scores.mean(0) / (scores.std(0) / math.sqrt(scores.shape[0]))
        assert np.all(np.abs(z) < Z_MAX), z
        d = x.shape[1]
        prods = scores[:, :, None] * x[:, None, :]
        z_stein = (prods.mean(0) + np.eye(d)) / (prods.std(0) / math.sqrt(x.shape[0]))
        assert np.all(np.abs(z_stein) < Z_MAX), z_stein


# ------------------------------------------------------------------------ mixtures


def test_assign_mode_recovers_generating_component(gmm2):
    target = gmm2.target
    assigned = np.asarray(jax.jit(jax.vmap(target.assign_mode))(gmm2.x))
    assert np.mean(assigned == gmm2.modes) > 0.999
    # Components are drawn in proportion to their (unequal) weights.
    freq = np.bincount(gmm2.modes, minlength=3) / gmm2.modes.shape[0]
    np.testing.assert_allclose(freq, target.weights, atol=0.005)
    resp = np.asarray(jax.vmap(target.responsibilities)(gmm2.x[:10]))
    np.testing.assert_allclose(resp.sum(1), 1.0, rtol=1e-12)
    np.testing.assert_array_equal(resp.argmax(1), assigned[:10])


def test_assign_mode_modes_on_a_line():
    # 1-D: three modes on a line (the grid layout of `separated_points`).
    target = well_separated_gaussian_mixture(1, 3)
    x, modes = target.sample_with_modes(jax.random.key(50), N_KS)
    assigned = jax.jit(jax.vmap(target.assign_mode))(x)
    assert np.mean(np.asarray(assigned) == np.asarray(modes)) > 0.999


def test_assign_mode_recovers_student_t_component(tmix2):
    assigned = jax.jit(jax.vmap(tmix2.target.assign_mode))(tmix2.x)
    assert np.mean(np.asarray(assigned) == tmix2.modes) > 0.999


def test_builders_geometry_and_defaults():
    for dim in (1, 2, 3, 6):
        for k in (1, 2, 3, 5, 9):
            pts = separated_points(dim, k, 8.0)
            assert pts.shape == (k, dim)
            np.testing.assert_allclose(pts.mean(0), 0.0, atol=1e-12)
            if k > 1:
                dists = np.linalg.norm(pts[:, None] - pts[None], axis=-1)[np.triu_indices(k, 1)]
                assert dists.min() >= 8.0 - 1e-9
    target = well_separated_gaussian_mixture(2)
    np.testing.assert_allclose(target.weights, [1 / 6, 2 / 6, 3 / 6])
    np.testing.assert_allclose(target.covariances, np.broadcast_to(np.eye(2), (3, 2, 2)))
    again = well_separated_gaussian_mixture(2)
    np.testing.assert_array_equal(target.means, again.means)  # deterministic without a key
    scaled = well_separated_gaussian_mixture(
        4, 3, scale=0.5, key=jax.random.key(8), weights=[1.0, 1.0, 2.0]
    )
    eig = np.linalg.eigvalsh(np.asarray(scaled.covariances))
    assert eig.min() >= 0.75 * 0.25 - 1e-12 and eig.max() <= 1.25 * 0.25 + 1e-12
    assert not np.allclose(eig, 0.25)  # anisotropic
    np.testing.assert_allclose(scaled.weights, [0.25, 0.25, 0.5])
    dists = np.linalg.norm(scaled.means[:, None] - scaled.means[None], axis=-1)
    assert dists[np.triu_indices(3, 1)].min() >= 8.0 * 0.5 - 1e-9
    same = well_separated_gaussian_mixture(4, 3, scale=0.5, key=jax.random.key(8))
    np.testing.assert_array_equal(same.covariances, scaled.covariances)  # deterministic per key
    t = well_separated_student_t_mixture(2, 2, df=3.0)
    np.testing.assert_allclose(t.dfs, [3.0, 3.0])
    np.testing.assert_allclose(t.weights, [1 / 3, 2 / 3])
    assert t.num_modes == 2


# ------------------------------------------------------ autodiff, jit, vmap, dtypes


def test_gradients_finite_and_jit_vmap_consistent(gmm2, tmix2, banana3, ring2, funnel3):
    for target in (gmm2.target, tmix2.target, banana3.target, ring2.target, funnel3.target):
        d = target.dim
        pts = np.concatenate(
            [
                _points(60, 5, d),
                np.zeros((1, d)),  # the Ring's centre, where |x| is not differentiable
                np.full((1, d), 40.0),
            ]
        )
        grads = np.asarray(jax.jit(jax.vmap(jax.grad(target.logdensity)))(pts))
        assert np.all(np.isfinite(grads)), type(target).__name__
        assert np.all(np.isfinite(_logdensity(target, pts)))
        # Gradient at pts[0] against central finite differences, evaluated in one batch
        # of the same shape (2 d <= 7 points), so the compiled batch is reused.
        h = 1e-6
        shifts = np.concatenate([h * np.eye(d), -h * np.eye(d)])
        batch = np.concatenate([pts[0] + shifts, np.zeros((len(pts) - 2 * d, d))])
        vals = _logdensity(target, batch)
        fd = (vals[:d] - vals[d : 2 * d]) / (2 * h)
        np.testing.assert_allclose(grads[0], fd, rtol=1e-5, atol=1e-6)
        assert target.mean.shape == (d,) and target.covariance.shape == (d, d)
    # Single-point jit and vmap agree.
    target = gmm2.target
    pts = _points(61, 3, 2)
    single = np.array([float(_single_logdensity(target, p)) for p in pts])
    np.testing.assert_allclose(_logdensity(target, pts), single, rtol=1e-12)


def test_sample_under_outer_jit_and_shapes():
    funnel = Funnel(dim=2)
    draws = eqx.filter_jit(lambda t, k: t.sample(k, 7))(funnel, jax.random.key(0))
    assert draws.shape == (7, 2)
    np.testing.assert_array_equal(funnel.sample(jax.random.key(0), 7), draws)  # same key
    assert funnel.sample(jax.random.key(0), 0).shape == (0, 2)


def test_logdensity_not_nan_at_extreme_points():
    funnel = Funnel(dim=4)
    pts = np.array([[-60.0, 0.0, 0.0, 0.0], [-60.0, 1e-3, 0.0, 0.0], [60.0, 1e5, -1e5, 3.0]])
    assert not np.any(np.isnan(_logdensity(funnel, pts)))
    grads = jax.jit(jax.vmap(jax.grad(funnel.logdensity)))(pts[:1])
    assert np.all(np.isfinite(np.asarray(grads)))
    for target in (Ring(2), Banana(), well_separated_student_t_mixture(2)):
        far, near = _logdensity(target, np.array([[1e6, 1e6], [0.5, 0.5]]))
        assert not np.isnan(far) and far < near - 10, type(target).__name__


def test_float32_inputs_stay_float32():
    means = np.array([[0.0, 0.0], [3.0, 3.0]], dtype=np.float32)
    mix = GaussianMixture(means, np.float32(1.0), np.array([1, 2], dtype=np.float32))
    assert mix.means.dtype == jnp.float32 and mix.covariances.dtype == jnp.float32
    x32 = jnp.ones((1, 2), jnp.float32)
    assert mix.sample(jax.random.key(70), 3).dtype == jnp.float32
    assert mix.marginal_cdf(0, x32[0]).dtype == jnp.float32
    tmix = StudentTMixture(np.zeros((1, 2), np.float32), np.float32(1.0), np.float32(4.0))
    for target in (mix, tmix, Ring()):
        out = _batched_logdensity(target, x32)
        assert out.dtype == jnp.float32 and np.all(np.isfinite(np.asarray(out)))


def test_construction_under_jit_with_traced_means():
    @jax.jit
    def logp(means, x):
        return GaussianMixture(means, 1.0).logdensity(x)

    means = jnp.array([[0.0, 0.0], [4.0, 0.0]])
    np.testing.assert_allclose(
        logp(means, jnp.zeros(2)), GaussianMixture(means, 1.0).logdensity(jnp.zeros(2))
    )


# --------------------------------------------------------------------------- errors


def test_gaussian_mixture_input_errors():
    with pytest.raises(ValueError, match="means must have shape"):
        GaussianMixture(jnp.zeros(3), 1.0)
    with pytest.raises(ValueError, match="means must be finite"):
        GaussianMixture(jnp.array([[0.0, jnp.nan]]), 1.0)
    with pytest.raises(ValueError, match="covariances must be a scalar, or have shape"):
        GaussianMixture(jnp.zeros((2, 3)), jnp.ones((2, 2, 2)))
    with pytest.raises(ValueError, match=r"covariances\[1\] is not positive definite"):
        GaussianMixture(jnp.zeros((2, 2)), jnp.array([np.eye(2), [[1.0, 2.0], [2.0, 1.0]]]))
    with pytest.raises(ValueError, match="covariances must be symmetric"):
        GaussianMixture(jnp.zeros((1, 2)), jnp.array([[[1.0, 0.5], [0.0, 1.0]]]))
    with pytest.raises(ValueError, match="covariances must be finite and strictly positive"):
        GaussianMixture(jnp.zeros((2, 2)), jnp.array([1.0, -1.0]))
    with pytest.raises(ValueError, match=r"weights must have shape \(2,\)"):
        GaussianMixture(jnp.zeros((2, 2)), 1.0, jnp.ones(3))
    with pytest.raises(ValueError, match="weights must be finite and strictly positive"):
        GaussianMixture(jnp.zeros((2, 2)), 1.0, jnp.array([1.0, 0.0]))
    mix = GaussianMixture(jnp.zeros((2, 2)), 1.0)
    with pytest.raises(ValueError, match=r"x must be a single point of shape \(2,\)"):
        mix.logdensity(jnp.zeros(3))
    with pytest.raises(ValueError, match=r"coordinate index i must lie in \[0, 2\)"):
        mix.marginal_cdf(2, 0.0)
    with pytest.raises(ValueError, match="number of samples"):
        mix.sample(jax.random.key(0), -1)


def test_student_t_mixture_input_errors():
    with pytest.raises(ValueError, match="dfs .* must be finite and > 0"):
        StudentTMixture(jnp.zeros((2, 2)), 1.0, jnp.array([3.0, 0.0]))
    with pytest.raises(ValueError, match=r"dfs must be a scalar or have shape \(2,\)"):
        StudentTMixture(jnp.zeros((2, 2)), 1.0, jnp.ones(3))
    with pytest.raises(ValueError, match=r"scales\[0\] is not positive definite"):
        StudentTMixture(jnp.zeros((1, 2)), jnp.array([[[1.0, 0.0], [0.0, -1.0]]]), 3.0)
    heavy = StudentTMixture(jnp.zeros((2, 2)), 1.0, jnp.array([1.5, 5.0]))
    np.testing.assert_allclose(heavy.mean, 0.0)  # df > 1: the mean exists
    with pytest.raises(ValueError, match="covariance of a Student-t mixture exists only if"):
        heavy.covariance
    cauchy = StudentTMixture(jnp.zeros((1, 2)), 1.0, 1.0)
    with pytest.raises(ValueError, match="mean of a Student-t mixture exists only if every df > 1"):
        cauchy.mean
    assert np.all(np.isfinite(_logdensity(cauchy, np.ones((1, 2)))))


def test_other_target_errors():
    with pytest.raises(ValueError, match="dim must be >= 2"):
        Banana(dim=1)
    with pytest.raises(ValueError, match="scale must be positive"):
        Banana(scale=0.0)
    with pytest.raises(ValueError, match="curvature must be finite"):
        Banana(curvature=float("inf"))
    with pytest.raises(NotImplementedError, match="coordinate 1"):
        Banana().marginal_cdf(1, 0.0)
    with pytest.raises(ValueError, match="radius must be >= 0"):
        Ring(radius=-1.0)
    with pytest.raises(ValueError, match="width must be positive"):
        Ring(width=0.0)
    with pytest.raises(ValueError, match="dim must be an integer"):
        Ring(dim=2.5)
    with pytest.raises(NotImplementedError, match="no closed form in dimension 2"):
        Ring(dim=2).marginal_cdf(0, 0.0)
    with pytest.raises(ValueError, match="dim must be >= 2"):
        Funnel(dim=1)
    with pytest.raises(NotImplementedError, match="only coordinate 0"):
        Funnel().marginal_cdf(3, 0.0)
    with pytest.raises(ValueError, match="num_modes must be >= 1"):
        well_separated_gaussian_mixture(2, 0)
    with pytest.raises(ValueError, match="separation must be positive"):
        well_separated_gaussian_mixture(2, separation=-1.0)
    with pytest.raises(ValueError, match=r"weights must have shape \(3,\)"):
        well_separated_gaussian_mixture(2, 3, weights=[1.0, 2.0])
    with pytest.raises(ValueError, match="df must be positive"):
        well_separated_student_t_mixture(2, df=0.0)
