"""Same key, same numbers: across runs, chunkings, lane splits and (statistically) precisions."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import restore
from restore.local import RandomWalk
from restore.regeneration import Gaussian, UniformBox


def std_normal(x):
    return -0.5 * jnp.sum(x**2)


def sampler(dtype=jnp.float64, **kwargs):
    regeneration = Gaussian(jnp.zeros(2, dtype), jnp.asarray(2.0, dtype))
    return restore.JumpRestore(std_normal, RandomWalk(1.0), regeneration, **({"tour_length": 2.0} | kwargs))


def assert_same_run(a, b):
    for name in a.sums._fields:
        np.testing.assert_array_equal(getattr(a.sums, name), getattr(b.sums, name), err_msg=name)
    np.testing.assert_array_equal(a.draws, b.draws)
    np.testing.assert_array_equal(a.draw_weights, b.draw_weights)
    np.testing.assert_array_equal(a.histogram[0], b.histogram[0])


@pytest.mark.slow
def test_same_key_and_arguments_give_identical_results():
    kwargs = dict(num_lanes=8, num_steps=300, progress=False)
    a = restore.sample(sampler(), jax.random.key(3), **kwargs)
    b = restore.sample(sampler(), jax.random.key(3), **kwargs)
    assert_same_run(a, b)
    d = restore.sample(sampler(), jax.random.key(4), **kwargs)
    assert not np.array_equal(a.sums.sum_f, d.sums.sum_f)
    # Another chunking gives the same path (draws, final states) and the same sums up to the
    # order in which chunk totals are added on the host.
    c = restore.sample(sampler(), jax.random.key(3), num_chunks=7, **kwargs)
    np.testing.assert_array_equal(a.draws, c.draws)
    np.testing.assert_array_equal(a.final_state.position, c.final_state.position)
    for name in a.sums._fields:
        np.testing.assert_allclose(getattr(a.sums, name), getattr(c.sums, name), rtol=1e-13, err_msg=name)


@pytest.mark.slow
def test_a_run_split_over_lanes_and_merged_is_the_same_run():
    kwargs = dict(num_steps=300, progress=False, save=restore.SaveDraws(thin=3))
    whole = restore.sample(sampler(), jax.random.key(5), num_lanes=12, **kwargs)
    parts = [restore.sample(sampler(), jax.random.key(5), num_lanes=n, first_lane=f, **kwargs) for f, n in ((0, 4), (4, 8))]
    merged = restore.merge_results(parts)
    assert merged.num_lanes == 12
    assert_same_run(whole, merged)
    np.testing.assert_allclose(merged.histogram[1], whole.histogram[1], rtol=1e-12)
    for name in ("step", "lane_steps", "time", "accepted", "regenerations"):  # the per-chunk trace adds up too
        np.testing.assert_allclose(getattr(merged.trace, name), getattr(whole.trace, name), rtol=1e-12, err_msg=name)
    for name in ("x", "x**2"):
        np.testing.assert_allclose(merged.estimate(name).value, whole.estimate(name).value, rtol=1e-12)
    assert float(merged.normalising_constant().value) == pytest.approx(float(whole.normalising_constant().value), rel=1e-12)


def test_merge_refuses_parts_of_different_runs():
    kwargs = dict(num_lanes=4, num_steps=100, progress=False)
    a = restore.sample(sampler(), jax.random.key(0), **kwargs)
    with pytest.raises(ValueError, match="num_steps=50 but result 0 has 100"):
        restore.merge_results([a, restore.sample(sampler(), jax.random.key(0), **{**kwargs, "num_steps": 50})])
    with pytest.raises(ValueError, match="thin=10 but result 0 has 1"):
        restore.merge_results([a, restore.sample(sampler(), jax.random.key(0), **{**kwargs, "save": restore.SaveDraws(40)})])
    with pytest.raises(ValueError, match="non-empty sequence"):
        restore.merge_results([])
    with pytest.raises(ValueError, match="first_lane must be a non-negative integer"):
        restore.sample(sampler(), jax.random.key(0), first_lane=-1, **kwargs)


@pytest.mark.slow
def test_float32_and_float64_agree_within_their_errors():
    kwargs = dict(num_lanes=128, num_steps=600, progress=False)
    low = restore.sample(sampler(jnp.float32), jax.random.key(0), **kwargs)
    high = restore.sample(sampler(jnp.float64), jax.random.key(0), **kwargs)
    assert low.draws.dtype == np.float32 and high.draws.dtype == np.float64
    for name, truth in (("x", 0.0), ("x**2", 1.0)):
        a, b = low.estimate(name), high.estimate(name)
        z = (a.value - b.value) / np.hypot(a.standard_error, b.standard_error)
        assert np.all(np.abs(z) < 4.5), (name, a, b)
        assert np.all(np.abs(a.z_score(truth)) < 4.5)
    za, zb = low.normalising_constant(), high.normalising_constant()
    assert abs(float(za.value - zb.value)) < 4.5 * float(np.hypot(za.standard_error, zb.standard_error))


@pytest.mark.slow
def test_float32_sums_keep_their_precision_over_long_runs():
    """On the unit box the kill rate is the constant `c_tilde`, so the mean holding time is `1 / (1 + c_tilde)`.

    Each chunk's sums are added to the run's totals on the device with their rounding errors
    carried along (compensated summation), so a float32 run of 10^5 steps keeps a relative
    error near 3e-5. The negative control sums the same sampler's holding times in one
    float32 scan, as a run without chunk totals would: it drifts by 4e-4.
    """
    box = lambda x: jnp.where(jnp.all((x >= 0) & (x <= 1)), 0.0, -jnp.inf)  # noqa: E731
    f32 = lambda v: jnp.asarray(v, jnp.float32)  # noqa: E731
    regeneration = UniformBox(jnp.zeros(1, jnp.float32), jnp.ones(1, jnp.float32))
    box_sampler = restore.JumpRestore(box, RandomWalk(f32(0.3)), regeneration, log_rate=f32(np.log(0.3)))
    num_steps = 100_000

    result = restore.sample(
        box_sampler, jax.random.key(1), num_lanes=2, num_steps=num_steps, save=restore.SaveDraws(0), progress=False, num_chunks=50
    )
    assert result.sums.all_t.dtype == np.float64
    assert np.all(np.abs(result.sums.all_t / num_steps * 1.3 - 1.0) < 1e-4)

    def float32_running_sum(key):
        def step(carry, key):
            state, total = carry
            state, info = box_sampler.step(key, state)
            return (state, total + info.expected_holding_time), None

        start = box_sampler.init(jax.random.fold_in(key, 0))
        (_, total), _ = jax.lax.scan(step, (start, f32(0.0)), jax.random.split(key, num_steps))
        return total

    plain = jax.jit(float32_running_sum)(jax.random.key(1))
    assert plain.dtype == jnp.float32
    assert abs(float(plain) / num_steps * 1.3 - 1.0) > 2e-4  # the chunk totals are what keep the precision
