"""Unit tests of the jump Restore kernel: numerics, input checks, evaluation count."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import restore
from restore._rate import kill_log_probability, log_kill_rate, log_total_rate
from restore.local import HMC, MALA, RandomWalk
from restore.regeneration import Gaussian, UniformBox


def std_normal(x):
    return -0.5 * jnp.sum(x**2)


def test_rate_arithmetic_is_exact_in_log_space_even_in_float32():
    big = jnp.asarray(1e4, jnp.float32)  # gamma = exp(1e4) overflows float32
    assert float(kill_log_probability(big, jnp.float32(0.0))) == 0.0
    assert float(jnp.exp(-log_total_rate(big, jnp.float32(0.0)))) == 0.0
    assert float(kill_log_probability(jnp.float32(-jnp.inf), jnp.float32(0.0))) == -np.inf
    # zero target density: killed at once whatever u is; zero u: never killed
    assert float(log_kill_rate(0.0, -jnp.inf, -jnp.inf)) == np.inf
    assert float(log_kill_rate(0.0, -jnp.inf, 0.0)) == -np.inf
    assert not np.isnan(float(log_kill_rate(0.0, jnp.inf, jnp.inf)))


@pytest.mark.slow
def test_no_zombie_tours_in_float32():
    """A float32 run where gamma = c u / p overflows must still kill, and give finite estimates."""
    with jax.enable_x64(False):
        logp = lambda x: -0.5 * jnp.sum(x**2) / 0.05**2  # noqa: E731
        nu = Gaussian(jnp.zeros(2, jnp.float32), jnp.float32(0.1**2))
        sampler = restore.JumpRestore(logp, RandomWalk(0.05), nu, log_rate=0.0)
        far = jnp.array([30.0, 0.0], jnp.float32)
        state = sampler.init(jax.random.key(0), far)
        assert state.log_kill_rate.dtype == jnp.float32 and state.log_kill_rate > 1e5
        _, info = sampler.step(jax.random.key(1), state)
        assert bool(info.regenerated) and float(info.expected_holding_time) == 0.0
        starts = jnp.tile(far, (64, 1))
        result = restore.sample(sampler, jax.random.key(2), num_lanes=64, num_steps=400, positions=starts, progress=False)
        est = result.estimate("x**2")
        assert np.all(np.isfinite(est.value)) and np.all(np.isfinite(est.standard_error))
        assert np.all(np.abs(est.z_score(0.05**2)) < 5)


@pytest.mark.parametrize("local", [RandomWalk(0.5), MALA(0.2), HMC(0.2, 4)])
def test_each_step_evaluates_the_density_once_outside_the_trajectory(local):
    calls = []

    def logp(x):
        calls.append(1)
        return std_normal(x)

    sampler = restore.JumpRestore(logp, local, Gaussian(jnp.zeros(3), 2.0), log_rate=0.0)
    state = sampler.init(jax.random.key(0))
    calls.clear()
    jax.make_jaxpr(sampler.step)(jax.random.key(1), state)
    inner = local.num_integration_steps - 1 if isinstance(local, HMC) else 0
    # one traced call for the shared evaluation, plus one traced body of HMC's inner scan
    assert len(calls) == 1 + (1 if inner else 0)


def test_init_and_step_shapes_and_jit_vmap():
    sampler = restore.JumpRestore(std_normal, RandomWalk(0.5), Gaussian(jnp.zeros(4), 2.0), log_rate=0.0)
    keys = jax.random.split(jax.random.key(0), 7)
    states = jax.jit(jax.vmap(sampler.init))(keys)
    assert states.position.shape == (7, 4)
    new, info = jax.jit(jax.vmap(sampler.step))(keys, states)
    assert new.position.shape == (7, 4) and info.holding_time.shape == (7,)
    assert np.all(np.asarray(info.expected_holding_time) > 0)


@pytest.mark.slow
def test_tour_length_needs_calibration_and_reports_the_pilot():
    sampler = restore.JumpRestore(std_normal, RandomWalk(0.5), Gaussian(jnp.zeros(2), 2.0), tour_length=4.0)
    with pytest.raises(ValueError, match="calibrate"):
        sampler.init(jax.random.key(0))
    calibrated, pilot = sampler.calibrate(jax.random.key(1))
    true_log_z = np.log(2 * np.pi)  # std_normal is unnormalised in 2-d
    assert abs(pilot.log_z - true_log_z) < 5 * pilot.relative_standard_error
    np.testing.assert_allclose(float(calibrated.log_rate), pilot.log_z - np.log(4.0))
    again, no_pilot = calibrated.calibrate(jax.random.key(2))
    assert again is calibrated and no_pilot is None  # a rate is kept, no second pilot
    result = restore.sample(sampler, jax.random.key(3), num_lanes=4, num_steps=20, progress=False)
    assert result.pilot is not None and result.tour_length == (4.0,)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({}, "exactly one"),
        ({"log_rate": 0.0, "tour_length": 1.0}, "exactly one"),
        ({"tour_length": 0.0}, "tour_length must be positive"),
        ({"tour_length": -1.0}, "tour_length must be positive"),
        ({"tour_length": float("inf")}, "tour_length must be positive"),
        ({"log_rate": float("nan")}, "log_rate must be finite"),
        ({"log_rate": 0.0, "local_rate": 0.0}, "local_rate must be positive"),
    ],
)
def test_bad_rates_are_rejected(kwargs, match):
    with pytest.raises(ValueError, match=match):
        restore.JumpRestore(std_normal, RandomWalk(0.5), Gaussian(jnp.zeros(2), 1.0), **kwargs)


def test_bad_shapes_are_rejected():
    nu = Gaussian(jnp.zeros(3), 1.0)
    with pytest.raises(ValueError, match="must return a scalar"):
        restore.JumpRestore(lambda x: -0.5 * x**2, RandomWalk(0.5), nu, log_rate=0.0)
    with pytest.raises(ValueError, match="has length 2 but the target has dimension 3"):
        restore.JumpRestore(std_normal, RandomWalk(jnp.ones(2)), nu, log_rate=0.0)
    with pytest.raises(ValueError, match="failed on a point of shape"):
        restore.JumpRestore(lambda x: jnp.sum(x.reshape(2, 2)), RandomWalk(0.5), nu, log_rate=0.0)
    with pytest.raises(ValueError, match="scale must be positive"):
        RandomWalk(-1.0)
    with pytest.raises(TypeError, match="restore.local kernel"):
        restore.JumpRestore(std_normal, "rw", nu, log_rate=0.0)
    sampler = restore.JumpRestore(std_normal, RandomWalk(0.5), nu, log_rate=0.0)
    with pytest.raises(ValueError, match=r"position must have shape \(3,\)"):
        sampler.init(jax.random.key(0), jnp.zeros(2))
    with pytest.raises(ValueError, match="positions must have shape"):
        restore.sample(sampler, jax.random.key(0), num_lanes=4, num_steps=10, positions=jnp.zeros((3, 3)), progress=False)
    with pytest.raises(ValueError, match="num_steps must be a positive integer"):
        restore.sample(sampler, jax.random.key(0), num_lanes=4, num_steps=0, progress=False)


@pytest.mark.slow
def test_nan_and_inf_log_densities_are_counted_not_propagated():
    def logp(x):  # NaN on a half-plane, +inf on a thin strip: both invalid
        value = std_normal(x)
        value = jnp.where(x[0] > 1.5, jnp.nan, value)
        return jnp.where(jnp.abs(x[1] - 2.0) < 0.05, jnp.inf, value)

    sampler = restore.JumpRestore(logp, RandomWalk(0.7), Gaussian(jnp.zeros(2), 1.5), log_rate=0.0)
    with pytest.warns(RuntimeWarning, match="NaN or \\+inf"):
        result = restore.sample(sampler, jax.random.key(0), num_lanes=64, num_steps=500, progress=False)
    assert result.num_invalid > 0
    est = result.estimate("x")
    assert np.all(np.isfinite(est.value)) and np.all(np.isfinite(est.standard_error))


@pytest.mark.slow
def test_zero_density_region_kills_at_once_with_zero_weight():
    logp = lambda x: jnp.where(jnp.all(jnp.abs(x) < 1.0), 0.0, -jnp.inf)  # noqa: E731 uniform on a square
    sampler = restore.JumpRestore(logp, RandomWalk(0.3), Gaussian(jnp.zeros(2), 1.0), log_rate=0.0)
    state = sampler.init(jax.random.key(0), jnp.array([3.0, 0.0]))
    assert float(state.log_kill_rate) == np.inf
    _, info = sampler.step(jax.random.key(1), state)
    assert bool(info.regenerated) and float(info.holding_time) == 0.0
    result = restore.sample(sampler, jax.random.key(2), num_lanes=128, num_steps=400, progress=False)
    np.testing.assert_allclose(result.estimate("x**2").value, 1.0 / 3.0, atol=5 * result.estimate("x**2").standard_error.max())
    assert result.num_invalid == 0


@pytest.mark.slow
def test_narrow_regeneration_is_detected():
    sampler = restore.JumpRestore(std_normal, RandomWalk(0.8), UniformBox(-jnp.ones(2), jnp.ones(2)), log_rate=0.0)
    with pytest.warns(RuntimeWarning, match="regeneration density is zero"):
        result = restore.sample(sampler, jax.random.key(0), num_lanes=32, num_steps=200, progress=False)
    assert result.num_uncovered > 0


def test_regeneration_that_misses_the_support_fails_the_pilot():
    logp = lambda x: jnp.where(x[0] > 50.0, std_normal(x - 60.0), -jnp.inf)  # noqa: E731
    sampler = restore.JumpRestore(logp, RandomWalk(0.5), Gaussian(jnp.zeros(2), 1.0), tour_length=1.0)
    with pytest.raises(ValueError, match="misses the target's support"):
        sampler.calibrate(jax.random.key(0))
