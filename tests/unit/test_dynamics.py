"""Continuous-time local dynamics: generator adjoints `L* p / p` and transitions.

Adjoints are checked against closed forms, against each other (the generic autodiff
`Diffusion` versus the special cases), against invariance (`∫ L* p = 0`, Langevin drift
gives zero), and against numerical quadrature; transitions by their moments over many
draws with fixed keys (float64, so deterministic).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.scipy.stats import multivariate_normal

from restore._point import evaluate
from restore.dynamics import (
    BrownianMotion,
    Diffusion,
    OrnsteinUhlenbeck,
    OverdampedLangevin,
    UnadjustedJump,
    diffusion_adjoint_ratio,
)
from restore.local import LocalInfo
from targets.analytic import Banana, GaussianMixture

NUM_DRAWS = 20_000


def _ratios(dynamics, logdensity_fn, xs):
    """`L* p / p` at every row of `xs`, for one dynamics or a list of them (one jit: compiles are slow)."""
    many = isinstance(dynamics, list)
    dynamics_list = dynamics if many else [dynamics]

    def one(x):
        point, _ = evaluate(logdensity_fn, x, False)
        return jnp.stack([d.adjoint_ratio(logdensity_fn, point) for d in dynamics_list])

    out = np.asarray(jax.jit(jax.vmap(one))(xs)).T
    return out if many else out[0]


def _advance_draws(dynamics, logdensity_fn, x0, duration, seed=0, n=NUM_DRAWS):
    """`n` independent draws of `Y_duration` given `Y_0 = x0` (one jit)."""

    @jax.jit
    def draws(key):
        keys = jax.random.split(key, n)
        return jax.vmap(lambda k: dynamics.advance(k, jnp.asarray(x0), jnp.asarray(duration), logdensity_fn))(keys)

    return np.asarray(draws(jax.random.key(seed)))


def _values(fn, xs):
    """`fn` at every row of `xs` (one jit)."""
    return np.asarray(jax.jit(jax.vmap(fn))(xs))


def _check_moments(draws, mean, var, num_se=4.5, extra=0.0):
    """Sample mean and variance per coordinate within `num_se` standard errors (+ `extra`)."""
    n = draws.shape[0]
    mean, var = np.broadcast_to(mean, draws.shape[1:]), np.broadcast_to(var, draws.shape[1:])
    mean_err = np.abs(draws.mean(0) - mean) / np.sqrt(var / n)
    var_err = np.abs(draws.var(0, ddof=1) - var) / (var * np.sqrt(2.0 / (n - 1)))
    assert np.all(mean_err < num_se + extra), (draws.mean(0), mean, mean_err)
    assert np.all(var_err < num_se + extra), (draws.var(0, ddof=1), var, var_err)


@pytest.fixture(scope="module")
def banana():
    return Banana(dim=2, curvature=0.4, scale=1.5)


@pytest.fixture(scope="module")
def mixture_1d():
    return GaussianMixture(np.array([[-2.0], [1.5]]), np.array([0.5, 1.2]), np.array([0.3, 0.7]))


@pytest.fixture(scope="module")
def mixture_2d():
    means, variances = np.array([[-1.0, 0.5], [1.5, -0.5]]), np.array([[0.6, 1.0], [1.3, 0.4]])
    return GaussianMixture(means, variances, np.array([0.4, 0.6]))


@pytest.fixture(scope="module")
def points_2d():
    return np.random.default_rng(3).normal(size=(6, 2)) * np.array([1.5, 1.0])


# ---------------------------------------------------------------- adjoints


@pytest.mark.parametrize("scale", [1.0, 0.7])
def test_brownian_adjoint_matches_gaussian_closed_form(scale):
    m = np.array([0.5, -1.0, 2.0])
    root = np.array([[1.0, 0.0, 0.0], [0.4, 0.8, 0.0], [-0.3, 0.2, 1.5]])
    cov = root @ root.T
    prec = np.linalg.inv(cov)
    xs = m + np.random.default_rng(1).normal(size=(5, 3)) * 2.0

    got = _ratios(BrownianMotion(scale), lambda x: multivariate_normal.logpdf(x, m, cov), xs)
    z = (xs - m) @ prec
    want = 0.5 * scale**2 * (np.sum(z * z, axis=1) - np.trace(prec))
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12)
    assert np.ptp(got) > 0.1  # the points probe both signs and several values


def test_generic_diffusion_without_drift_matches_brownian(banana, points_2d):
    scale = np.array([1.3, 0.6])
    dynamics = [
        BrownianMotion(scale),
        Diffusion(jnp.zeros_like, scale**2, 0.1),
        Diffusion(jnp.zeros_like, np.diag(scale**2), 0.1),
    ]
    bm, diagonal, matrix = _ratios(dynamics, banana.logdensity, points_2d)
    np.testing.assert_allclose(diagonal, bm, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(matrix, bm, rtol=1e-12, atol=1e-12)
    assert np.max(np.abs(bm)) > 0.1


@pytest.mark.parametrize("target_name", ["banana", "mixture"])
def test_langevin_drift_gives_zero_adjoint(banana, mixture_2d, points_2d, target_name):
    logdensity = banana.logdensity if target_name == "banana" else mixture_2d.logdensity
    a = np.array([[1.2, 0.4], [0.4, 0.7]])  # any constant a: b = a grad log p / 2 leaves p invariant
    langevin = Diffusion(lambda x: 0.5 * a @ jax.grad(logdensity)(x), a, 0.1)
    # Negative control: the same a with no drift is far from invariant at these points.
    no_drift = Diffusion(jnp.zeros_like, a, 0.1)
    got, control, overdamped = _ratios([langevin, no_drift, OverdampedLangevin(step_size=0.1)], logdensity, points_2d)
    np.testing.assert_allclose(got, 0.0, atol=1e-8)
    assert np.max(np.abs(control)) > 0.1
    assert np.all(overdamped == 0.0)


def test_ornstein_uhlenbeck_adjoint_matches_generic_diffusion(banana, points_2d):
    scale = np.array([1.1, 0.6])
    ou = OrnsteinUhlenbeck(mean=np.array([0.5, -0.3]), rate=np.array([0.8, 2.0]), scale=scale)
    generic = Diffusion(ou.drift, scale**2, 0.1)
    got, want = _ratios([ou, generic], banana.logdensity, points_2d)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    assert np.ptp(got) > 0.1
    # ... and so does the function form, with a full matrix.
    function_form = _values(
        lambda x: diffusion_adjoint_ratio(banana.logdensity, x, ou.drift, np.diag(scale**2)), points_2d
    )
    np.testing.assert_allclose(function_form, got, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize(
    "dynamics", [BrownianMotion(0.8), OrnsteinUhlenbeck(mean=0.5, rate=0.7, scale=1.3)], ids=["brownian", "ou"]
)
def test_adjoint_integrates_to_zero(mixture_1d, dynamics):
    """`∫ L* p dx = 0` (total mass is conserved), by the trapezoid rule on a 1-d grid."""
    grid = np.linspace(-16.0, 16.0, 4001)
    p = np.exp(_values(mixture_1d.logdensity, grid[:, None]))
    ratio = _ratios(dynamics, mixture_1d.logdensity, grid[:, None])
    assert abs(np.trapezoid(p * ratio, grid)) < 1e-8
    assert np.trapezoid(p * np.abs(ratio), grid) > 0.1  # a real cancellation, not a zero integrand


def test_unadjusted_jump_adjoint_matches_quadrature(mixture_1d):
    s, rate = 0.7, 2.0
    jump = UnadjustedJump(s, log_convolution=mixture_1d.smoothed(s**2).logdensity, rate=rate)
    ys = np.array([[-4.0], [-2.0], [0.0], [0.7], [3.0]])
    xs = np.linspace(-16.0, 16.0, 6001)
    log_p = _values(mixture_1d.logdensity, np.concatenate([xs[:, None], ys]))
    p, p_y = np.exp(log_p[: xs.size]), np.exp(log_p[xs.size :])
    kernel = np.exp(-0.5 * ((ys - xs[None, :]) / s) ** 2) / (s * np.sqrt(2 * np.pi))
    convolution = np.trapezoid(p[None, :] * kernel, xs, axis=1)

    np.testing.assert_allclose(np.exp(_values(jump.log_convolution, ys)), convolution, rtol=1e-9)
    np.testing.assert_allclose(_ratios(jump, mixture_1d.logdensity, ys), rate * (convolution / p_y - 1.0), rtol=1e-8)
    assert np.ptp(convolution / p_y) > 0.5


def test_unadjusted_jump_moves_are_always_accepted(mixture_1d):
    jump = UnadjustedJump(jnp.array([0.5]), log_convolution=mixture_1d.smoothed(0.25).logdensity)

    @jax.jit
    def move(key, x):
        point, _ = evaluate(mixture_1d.logdensity, x, False)
        key_propose, key_accept = jax.random.split(key)
        y, aux = jump.propose(key_propose, point, mixture_1d.logdensity)
        candidate, _ = evaluate(mixture_1d.logdensity, y, False)
        moved, info = jump.accept(key_accept, point, candidate, aux)
        return candidate, moved, info, x + 0.5 * jax.random.normal(key_propose, x.shape, x.dtype)

    candidate, moved, info, expected = move(jax.random.key(7), np.array([0.3], np.float32))
    assert moved.position.dtype == jnp.float32
    np.testing.assert_array_equal(moved.position, expected)
    np.testing.assert_array_equal(moved.logdensity, candidate.logdensity)
    assert isinstance(info, LocalInfo) and bool(info.accepted) and float(info.acceptance_probability) == 1.0
    assert not jump.is_invariant and jump.rate == 1.0


def test_adjoints_are_inf_not_nan_where_density_is_zero_or_invalid():
    def logdensity(x):  # zero density for x < 0, NaN at x = 5
        return jnp.where(x[0] > 0, -x[0] + jnp.where(x[0] == 5.0, jnp.nan, 0.0), -jnp.inf)

    xs = np.array([[-1.0], [5.0], [1.0]])
    dynamics = [
        BrownianMotion(),
        OrnsteinUhlenbeck(),
        Diffusion(lambda x: -x, 1.0, 0.1),
        # zero convolution where p is zero too: -inf - (-inf) must not give NaN
        UnadjustedJump(1.0, log_convolution=lambda y: jnp.where(y[0] > -0.5, -jnp.abs(y[0]), -jnp.inf)),
    ]
    for d, got in zip(dynamics, _ratios(dynamics, logdensity, xs)):
        assert got[0] == np.inf and got[1] == np.inf, (type(d).__name__, got)
        assert np.isfinite(got[2])


# ---------------------------------------------------------------- transitions


def test_brownian_advance_moments():
    x0, t, scale = np.array([0.5, -1.0]), 0.7, np.array([1.3, 0.6])
    draws = _advance_draws(BrownianMotion(scale), None, x0, t)
    _check_moments(draws, x0, scale**2 * t)
    assert BrownianMotion.is_exact


def test_ornstein_uhlenbeck_advance_moments():
    mean, rate, scale = np.array([1.0, -1.0]), np.array([0.8, 2.0]), 1.5
    x0, t = np.array([3.0, 0.5]), 0.6
    draws = _advance_draws(OrnsteinUhlenbeck(mean, rate, scale), None, x0, t, seed=1)
    want_mean = mean + np.exp(-rate * t) * (x0 - mean)
    want_var = scale**2 * (1 - np.exp(-2 * rate * t)) / (2 * rate)
    _check_moments(draws, want_mean, want_var)


def test_euler_diffusion_approaches_exact_ornstein_uhlenbeck():
    ou = OrnsteinUhlenbeck(mean=0.5, rate=2.0, scale=1.5)
    x0, t = np.array([2.0]), 0.6
    want_mean = 0.5 + np.exp(-2.0 * t) * 1.5
    want_var = 1.5**2 * (1 - np.exp(-4.0 * t)) / 4.0
    fine = _advance_draws(Diffusion(ou.drift, 1.5**2, 0.005), None, x0, t, seed=2)
    _check_moments(fine, want_mean, want_var)
    # Negative control: one Euler step over the whole duration is visibly wrong.
    coarse = _advance_draws(Diffusion(ou.drift, 1.5**2, t), None, x0, t, seed=2)
    with pytest.raises(AssertionError):
        _check_moments(coarse, want_mean, want_var)


def test_euler_substep_count_is_dynamic_under_jit_and_vmap():
    """`ceil(duration / step_size)` equal sub-steps: with negligible noise, `x (1 - theta h)^n`."""
    theta, step = 1.5, 0.1
    diffusion = Diffusion(lambda x: -theta * x, 1e-30, step)
    durations = np.array([0.0, 0.25, 1.0, -1.0, np.inf])
    x0 = np.array([1.0, -2.0])

    @jax.jit
    def advance(key, durations):
        keys = jax.random.split(key, durations.shape[0])
        return jax.vmap(lambda k, t: diffusion.advance(k, jnp.asarray(x0), t, None))(keys, durations)

    got = np.asarray(advance(jax.random.key(0), durations))
    n = np.array([0, 3, 10, 0])
    h = np.where(n > 0, durations[:4] / np.maximum(n, 1), 0.0)
    want = x0[None, :] * ((1 - theta * h) ** n)[:, None]
    np.testing.assert_allclose(got[:4], want, rtol=1e-12, atol=1e-12)
    assert np.all(np.isnan(got[4]))  # an infinite duration cannot be simulated: NaN, flagged downstream


def test_overdamped_langevin_keeps_gaussian_target_approximately():
    sigma = 1.7

    def logdensity(x):
        return -0.5 * jnp.sum(x**2) / sigma**2

    langevin = OverdampedLangevin(scale=1.2, step_size=0.01)
    x0s = sigma * np.random.default_rng(4).normal(size=(NUM_DRAWS, 1))

    @jax.jit
    def advance(key, x0s):
        keys = jax.random.split(key, x0s.shape[0])
        return jax.vmap(lambda k, x: langevin.advance(k, x, jnp.asarray(1.0), logdensity))(keys, x0s)

    draws = np.asarray(advance(jax.random.key(4), x0s))
    # Draws stay distributed as the target (ULA bias ~ step_size / 4 relative in the variance).
    _check_moments(draws, 0.0, sigma**2)
    # ... and they moved: correlation with the start is about exp(-t scale^2 / (2 sigma^2)).
    corr = np.corrcoef(x0s[:, 0], draws[:, 0])[0, 1]
    assert abs(corr - np.exp(-1.2**2 / (2 * sigma**2))) < 0.03
    assert not langevin.is_exact and langevin.is_invariant


def test_advance_keeps_float32_positions():
    dynamics = [
        BrownianMotion(0.5),
        OrnsteinUhlenbeck(0.0, 1.0, 0.5),
        Diffusion(lambda x: -x, 0.25, 0.1),
        OverdampedLangevin(step_size=0.1),
    ]

    def advance_all(key, x0, t):
        return [d.advance(key, x0, t, lambda x: -jnp.sum(x**2)) for d in dynamics]

    # A float64 duration (x64 is on): the position's dtype must win.
    out = jax.jit(advance_all)(jax.random.key(0), np.array([0.5, -0.5], np.float32), np.float64(0.3))
    assert [o.dtype for o in out] == [jnp.float32] * 4


# ---------------------------------------------------------------- GaussianMixture.smoothed


def test_smoothed_forms_agree_and_add_the_covariance(mixture_2d):
    mixture = mixture_2d
    scalar = mixture.smoothed(0.2)
    for other in [mixture.smoothed(np.array([0.2, 0.2])), mixture.smoothed(0.2 * np.eye(2))]:
        np.testing.assert_allclose(other.covariances, scalar.covariances, rtol=1e-15)
    matrix = np.array([[0.3, 0.1], [0.1, 0.2]])
    np.testing.assert_allclose(mixture.smoothed(matrix).covariances, mixture.covariances + matrix, rtol=1e-15)
    np.testing.assert_allclose(scalar.weights, mixture.weights)
    np.testing.assert_allclose(scalar.means, mixture.means)


@pytest.mark.parametrize(
    "covariance",
    [
        -0.1,
        np.array([0.1, -0.2]),
        np.ones(3),
        np.array([[1.0, 2.0], [2.0, 1.0]]),
        np.array([[1.0, 0.5], [0.0, 1.0]]),
        np.nan,
    ],
    ids=["negative", "negative-diagonal", "wrong-length", "not-psd", "asymmetric", "nan"],
)
def test_smoothed_rejects_bad_covariances(mixture_2d, covariance):
    with pytest.raises(ValueError, match="covariance"):
        mixture_2d.smoothed(covariance)


# ---------------------------------------------------------------- parameter checks


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: BrownianMotion(0.0), "scale"),
        (lambda: BrownianMotion(jnp.array([1.0, -1.0])), "scale"),
        (lambda: BrownianMotion(jnp.ones((2, 2))), "scale"),
        (lambda: OrnsteinUhlenbeck(rate=0.0), "rate"),
        (lambda: OrnsteinUhlenbeck(rate=-1.0), "rate"),
        (lambda: OrnsteinUhlenbeck(scale=-1.0), "scale"),
        (lambda: OrnsteinUhlenbeck(mean=jnp.inf), "mean"),
        (lambda: OrnsteinUhlenbeck(mean=jnp.zeros((2, 2))), "mean"),
        (lambda: OverdampedLangevin(0.0, step_size=0.1), "scale"),
        (lambda: OverdampedLangevin(step_size=0.0), "step_size"),
        (lambda: OverdampedLangevin(step_size=jnp.ones(2)), "step_size"),
        (lambda: Diffusion(jnp.zeros_like, 1.0, 0.0), "step_size"),
        (lambda: Diffusion(jnp.zeros_like, 1.0, -0.1), "step_size"),
        (lambda: Diffusion(jnp.zeros_like, 0.0, 0.1), "diffusion_matrix"),
        (lambda: Diffusion(jnp.zeros_like, jnp.ones((2, 3)), 0.1), "diffusion_matrix"),
        (lambda: Diffusion(jnp.zeros_like, jnp.ones((2, 2, 2)), 0.1), "diffusion_matrix"),
        (lambda: Diffusion(jnp.zeros_like, jnp.array([[1.0, 0.5], [0.0, 1.0]]), 0.1), "symmetric"),
        (lambda: Diffusion(jnp.zeros_like, jnp.array([[1.0, 2.0], [2.0, 1.0]]), 0.1), "positive definite"),
        (lambda: UnadjustedJump(0.0, lambda y: 0.0), "scale"),
        (lambda: UnadjustedJump(1.0, lambda y: 0.0, rate=0.0), "rate"),
        (lambda: UnadjustedJump(1.0, lambda y: 0.0, rate=float("nan")), "rate"),
    ],
)
def test_bad_parameters_raise_clear_errors(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_non_callables_and_dimension_mismatches_raise():
    with pytest.raises(TypeError, match="drift"):
        Diffusion(jnp.zeros(2), 1.0, 0.1)
    with pytest.raises(TypeError, match="log_convolution"):
        UnadjustedJump(1.0, 0.5)
    for dynamics in [
        BrownianMotion(np.ones(2)),
        OrnsteinUhlenbeck(mean=np.zeros(2)),
        OverdampedLangevin(np.ones(2), step_size=0.1),
        Diffusion(jnp.zeros_like, np.eye(2), 0.1),
        UnadjustedJump(np.ones(2), lambda y: 0.0),
    ]:
        dynamics.check_dim(2)
        with pytest.raises(ValueError, match="dimension 3"):
            dynamics.check_dim(3)
    with pytest.raises(ValueError, match="diffusion_matrix"):
        diffusion_adjoint_ratio(lambda x: -jnp.sum(x**2), np.zeros(2), None, np.eye(3))
    with pytest.raises(ValueError, match="drift_fn"):
        diffusion_adjoint_ratio(lambda x: -jnp.sum(x**2), np.zeros(2), lambda x: x[0], 1.0)
