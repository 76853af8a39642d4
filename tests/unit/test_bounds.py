"""Searches for the constants of a Restore process: `restore._bounds`.

Few distinct functions are searched, so that few XLA compilations are needed.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from restore._bounds import MinimalRate, RateBound, minimal_log_rate, rate_bound
from restore._multistart import SearchResult, maximise

# --------------------------------------------------------------------------- #
# Brownian-motion Restore: a = 1/2 (|grad log p|^2 + Laplacian log p)
# --------------------------------------------------------------------------- #

S = np.array([[1.2, 0.4], [0.4, 0.8]])
S_INV = np.linalg.inv(S)


def bm_logdensity(x):
    return -0.5 * x @ jnp.asarray(S_INV) @ x


def bm_adjoint_ratio(x):
    # Written from log p with JAX, as a user would.
    grad = jax.grad(bm_logdensity)(x)
    return 0.5 * (grad @ grad + jnp.trace(jax.hessian(bm_logdensity)(x)))


def std_normal_logpdf(x):
    return -0.5 * x @ x - 0.5 * x.shape[0] * math.log(2 * math.pi)


def test_brownian_motion_minimal_rate():
    # Closed form of a for this target, checked at a few points.
    xs = np.array([[0.0, 0.0], [1.0, -0.5], [2.0, 3.0]])
    expected_a = 0.5 * (np.sum((xs @ S_INV) ** 2, axis=1) - np.trace(S_INV))
    got_a = jax.jit(jax.vmap(bm_adjoint_ratio))(jnp.asarray(xs))
    np.testing.assert_allclose(got_a, expected_a, rtol=1e-12, atol=1e-12)

    # Starts on both sides of the ellipse {a < 0}; none at the optimum x = 0.
    starts = np.random.default_rng(0).normal(scale=1.5, size=(12, 2))
    a_starts = 0.5 * (np.sum((starts @ S_INV) ** 2, axis=1) - np.trace(S_INV))
    assert 0 < np.sum(a_starts < 0) < len(starts)

    out = minimal_log_rate(bm_logdensity, bm_adjoint_ratio, std_normal_logpdf, starts)
    assert isinstance(out, MinimalRate)
    # At x = 0: -a p / q = (tr S^-1 / 2) * 1 / (2 pi)^-1 = pi tr S^-1 = 2.5 pi.
    assert np.trace(S_INV) == pytest.approx(2.5)
    assert out.log_rate == pytest.approx(math.log(2.5 * math.pi), abs=1e-6)
    assert out.log_sup == out.log_rate
    np.testing.assert_allclose(out.argmax, [0.0, 0.0], atol=1e-4)
    assert out.num_negative_starts == int(np.sum(a_starts < 0))
    assert out.num_failed == 0

    # Same functions: no new compilation; the margin is added in log space.
    out2 = minimal_log_rate(bm_logdensity, bm_adjoint_ratio, std_normal_logpdf, starts, margin=0.25)
    assert out2.log_rate == pytest.approx(out.log_sup + 0.25, abs=1e-12)
    assert out2.log_sup == pytest.approx(out.log_sup, abs=1e-12)


def test_minimal_rate_from_starts_outside_negative_region():
    # Only starts with a > 0: the first phase must carry them into {a < 0}.
    # Twelve starts, as above, so that the compilation is reused.
    angles = np.linspace(0.0, 2 * np.pi, 12, endpoint=False)
    starts = 2.5 * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    a_starts = 0.5 * (np.sum((starts @ S_INV) ** 2, axis=1) - np.trace(S_INV))
    assert np.all(a_starts > 0)
    out = minimal_log_rate(bm_logdensity, bm_adjoint_ratio, std_normal_logpdf, starts)
    assert out.num_negative_starts == 0
    assert out.log_rate == pytest.approx(math.log(2.5 * math.pi), abs=1e-6)


def test_minimal_rate_is_minus_inf_when_a_is_non_negative():
    def a_positive(x):
        return 0.5 + 0.1 * x @ x

    starts = np.random.default_rng(1).normal(size=(5, 2))
    out = minimal_log_rate(bm_logdensity, a_positive, std_normal_logpdf, starts, margin=1.0)
    assert out.log_rate == -math.inf
    assert out.log_sup == -math.inf
    assert out.num_negative_starts == 0
    assert np.all(np.isnan(out.argmax))


# --------------------------------------------------------------------------- #
# 1-d: a bimodal deficit; the sup is found by the optimiser, not at a start.
# --------------------------------------------------------------------------- #


def one_d_logdensity(x):
    return -0.5 * x[0] ** 2


def one_d_adjoint_ratio(x):
    y = x[0]
    return 1.0 - 2.0 * jnp.exp(-((y - 1.0) ** 2)) - 6.0 * jnp.exp(-2.0 * (y + 2.0) ** 2)


def one_d_log_reference(x):
    return -0.5 * (x[0] / 1.5) ** 2 - math.log(1.5 * math.sqrt(2 * math.pi))


def _one_d_objective_np(y):
    a = 1.0 - 2.0 * np.exp(-((y - 1.0) ** 2)) - 6.0 * np.exp(-2.0 * (y + 2.0) ** 2)
    logq = -0.5 * (y / 1.5) ** 2 - math.log(1.5 * math.sqrt(2 * math.pi))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(a < 0, np.log(np.where(a < 0, -a, 1.0)) - 0.5 * y**2 - logq, -np.inf)


def test_one_d_bimodal_sup_needs_the_optimiser():
    grid = np.linspace(-6.0, 6.0, 240_001)
    values = _one_d_objective_np(grid)
    i = int(np.argmax(values))
    grid_max, grid_argmax = values[i], grid[i]
    assert -2.5 < grid_argmax < -1.5  # the deeper bump, not the one near 1

    # First start in {a > 0}; the others in the shallower bump or off the peak.
    starts = np.array([[3.5], [1.2], [-1.4], [0.8]])
    start_values = _one_d_objective_np(starts[:, 0])
    assert start_values[0] == -np.inf
    assert np.max(start_values) < grid_max - 0.05  # no start is near the sup

    out = minimal_log_rate(one_d_logdensity, one_d_adjoint_ratio, one_d_log_reference, starts)
    assert out.log_sup == pytest.approx(grid_max, abs=1e-7)
    assert out.argmax[0] == pytest.approx(grid_argmax, abs=1e-4)
    assert out.num_negative_starts == 3


# --------------------------------------------------------------------------- #
# rate_bound
# --------------------------------------------------------------------------- #


def quadratic_rate(y):
    return 10.0 - (y[0] - 3.0) ** 2 - (y[1] - 0.5) ** 2


def test_rate_bound_interior_and_face():
    key = jax.random.key(3)
    # Interior maximum at (3, 0.5), value 10.
    out = rate_bound(quadratic_rate, [2.0, -1.0], [4.0, 2.0], key=key, num_starts=16)
    assert isinstance(out, RateBound)
    assert out.sup_found == pytest.approx(10.0, abs=1e-9)
    assert out.bound == pytest.approx(20.0, abs=1e-8)
    np.testing.assert_allclose(out.argmax, [3.0, 0.5], atol=1e-4)

    # Same function and shapes (one compilation): the maximum is on the face y0 = 1.
    out = rate_bound(quadratic_rate, [-1.0, -1.0], [1.0, 2.0], key=key, num_starts=16, safety=1.5)
    assert out.sup_found == pytest.approx(6.0, abs=1e-9)
    assert out.bound == pytest.approx(9.0, abs=1e-8)
    np.testing.assert_allclose(out.argmax, [1.0, 0.5], atol=1e-4)
    assert np.all(np.asarray(out.argmax) <= np.array([1.0, 2.0]))


def compact_support_rate(y):
    # gamma = q / p with p = max(1 - |y|^2, 0): infinite outside the unit disc.
    r2 = y @ y
    inside = r2 < 1.0
    p = jnp.where(inside, 1.0 - r2, 1.0)
    return jnp.where(inside, jnp.exp(-0.5 * r2) / p, jnp.inf)


def test_rate_bound_infinite_rate_and_corner():
    key = jax.random.key(4)
    with pytest.raises(ValueError, match="smaller region"):
        rate_bound(compact_support_rate, [-2.0, -2.0], [2.0, 2.0], key=key, num_starts=16)
    # Inside the disc the rate increases with |y|: the sup is at the corners.
    out = rate_bound(compact_support_rate, [-0.5, -0.5], [0.5, 0.5], key=key, num_starts=16)
    assert out.sup_found == pytest.approx(2.0 * math.exp(-0.25), rel=1e-9)
    np.testing.assert_allclose(np.abs(np.asarray(out.argmax)), [0.5, 0.5], atol=1e-6)


def test_rate_bound_validation():
    key = jax.random.key(0)
    with pytest.raises(ValueError, match="lower < upper"):
        rate_bound(quadratic_rate, [0.0, 1.0], [1.0, 1.0], key=key)
    with pytest.raises(ValueError, match="same shape"):
        rate_bound(quadratic_rate, [0.0, 0.0], [1.0, 1.0, 1.0], key=key)
    with pytest.raises(ValueError, match="finite"):
        rate_bound(quadratic_rate, [0.0, -np.inf], [1.0, 1.0], key=key)
    with pytest.raises(ValueError, match="safety"):
        rate_bound(quadratic_rate, [0.0, 0.0], [1.0, 1.0], key=key, safety=0.5)


# --------------------------------------------------------------------------- #
# maximise
# --------------------------------------------------------------------------- #


def nan_on_right(y):
    value = 1.0 - (y[0] - 1.0) ** 2 - 2.0 * (y[1] + 0.5) ** 2
    return jnp.where(y[0] > 2.0, jnp.nan, value)


def test_maximise_beats_best_start_and_counts_failures():
    starts = np.array([[3.0, 0.0], [-1.0, 2.0], [2.5, 1.0], [0.0, 0.0]])
    out = maximise(nan_on_right, starts)
    assert isinstance(out, SearchResult)
    start_values = np.asarray(out.start_values)
    assert np.isnan(start_values[[0, 2]]).all() and np.isfinite(start_values[[1, 3]]).all()
    assert out.num_failed == 2
    assert np.isnan(np.asarray(out.values)[[0, 2]]).all()
    assert out.value >= np.nanmax(start_values)
    assert out.value == pytest.approx(1.0, abs=1e-10)
    np.testing.assert_allclose(out.argmax, [1.0, -0.5], atol=1e-5)
    np.testing.assert_allclose(np.asarray(out.values)[[1, 3]], 1.0, atol=1e-10)
    assert out.argmaxes.shape == (4, 2)


def test_maximise_all_failed_gives_nan():
    # Same function and shape as above: no new compilation.
    starts = np.array([[3.0, 0.0], [2.5, 1.0], [2.1, -3.0], [4.0, 4.0]])
    out = maximise(nan_on_right, starts)
    assert out.num_failed == 4
    assert math.isnan(out.value)
    assert np.all(np.isnan(np.asarray(out.argmax)))


def test_maximise_validation():
    with pytest.raises(ValueError, match=r"shape \(n, d\)"):
        maximise(nan_on_right, np.zeros(2))
    with pytest.raises(ValueError, match="finite"):
        maximise(nan_on_right, np.array([[0.0, np.nan]]))
    with pytest.raises(ValueError, match="both"):
        maximise(nan_on_right, np.zeros((1, 2)), lower=[-1.0, -1.0])
    with pytest.raises(ValueError, match="outside the box"):
        maximise(nan_on_right, np.array([[0.0, 3.0]]), lower=[-1.0, -1.0], upper=[1.0, 1.0])
    with pytest.raises(ValueError, match="dimension"):
        maximise(nan_on_right, np.zeros((1, 2)), lower=[-1.0], upper=[1.0])
    with pytest.raises(ValueError, match="real floating scalar"):
        maximise(lambda y: y, np.zeros((1, 2)))
    with pytest.raises(ValueError, match="max_steps"):
        maximise(nan_on_right, np.zeros((1, 2)), max_steps=0)
    with pytest.raises(ValueError, match="margin"):
        minimal_log_rate(bm_logdensity, bm_adjoint_ratio, std_normal_logpdf, np.zeros((1, 2)), margin=-1.0)
