"""`unrolled_keys` draws JAX's own bits: every key operation and distribution equals the default keys'."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import restore
import restore._run as run_module
from restore._threefry import UNROLLED_THREEFRY, loggamma, threefry2x32, unrolled_keys
from restore.local import RandomWalk
from restore.regeneration import Gaussian, StudentT

DRAWS = {
    "split": lambda k: jax.random.key_data(jax.random.split(k, 3)),
    "split 2-d": lambda k: jax.random.key_data(jax.random.split(k, (2, 3))),
    "fold_in": lambda k: jax.random.key_data(jax.random.fold_in(k, 77)),
    "bits 8": lambda k: jax.random.bits(k, (5,), jnp.uint8),
    "bits 16": lambda k: jax.random.bits(k, (3, 5), jnp.uint16),
    "bits 32": lambda k: jax.random.bits(k, (7,), jnp.uint32),
    "bits 64": lambda k: jax.random.bits(k, (2, 3), jnp.uint64),
    "scalar uniform": lambda k: jax.random.uniform(k),
    "float32 uniform": lambda k: jax.random.uniform(k, (7,), jnp.float32),
    "normal": lambda k: jax.random.normal(k, (4, 3)),
    "randint": lambda k: jax.random.randint(k, (4,), 0, 1000),
    "student t": lambda k: jax.random.t(k, 5.0, (3,)),
    "loggamma": lambda k: loggamma(k, 2.5, (3,), jnp.float64),
}


@pytest.mark.parametrize("name", sorted(DRAWS))
def test_unrolled_keys_draw_the_same_bits(name):
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(42), i))(jnp.arange(6))
    assert jax.random.key_impl(unrolled_keys(keys)) == UNROLLED_THREEFRY  # converted, so the comparison means something
    draw = jax.jit(jax.vmap(DRAWS[name]))
    np.testing.assert_array_equal(draw(unrolled_keys(keys)), draw(keys))
    np.testing.assert_array_equal(DRAWS[name](unrolled_keys(keys[0])), DRAWS[name](keys[0]))  # unbatched, eager


def test_the_hash_is_threefry_and_a_wrong_round_is_caught():
    """Against JAX's own hash (and its published test vector); one rotation changed fails."""
    k1, k2 = np.uint32([0x13198A2E, 0x03707344])
    x1, x2 = np.uint32([0x243F6A88, 0x85A308D3])
    expected = jax.extend.random.threefry_2x32((k1, k2), jnp.asarray([x1, x2]))
    np.testing.assert_array_equal(jnp.stack(threefry2x32(k1, k2, x1, x2)), expected)
    np.testing.assert_array_equal(expected, np.uint32([0xC4923A9C, 0x483DF7A0]))  # Salmon et al. (2011)
    import restore._threefry as module

    rotations = module._ROTATIONS
    try:
        module._ROTATIONS = ((13, 15, 26, 6), (17, 29, 16, 25))
        assert not np.array_equal(jnp.stack(threefry2x32(k1, k2, x1, x2)), expected)
    finally:
        module._ROTATIONS = rotations


@pytest.mark.parametrize("seed", [0, 7, 2**31 + 5, -3])
def test_seeds_match_jax(seed):
    made = jax.random.key(seed, impl=UNROLLED_THREEFRY)
    np.testing.assert_array_equal(jax.random.key_data(made), jax.random.key_data(jax.random.key(seed)))


def test_other_keys_are_left_alone():
    rbg = jax.random.key(0, impl="rbg")
    assert unrolled_keys(rbg) is rbg
    raw = jax.random.PRNGKey(0)
    assert unrolled_keys(raw) is raw
    converted = unrolled_keys(jax.random.key(0))
    assert unrolled_keys(converted) is converted
    previous = jax.config.jax_threefry_partitionable
    try:
        jax.config.update("jax_threefry_partitionable", False)  # another layout of the bits: not ours
        key = jax.random.key(0)
        assert unrolled_keys(key) is key
    finally:
        jax.config.update("jax_threefry_partitionable", previous)


@pytest.mark.parametrize("regeneration", [Gaussian(jnp.zeros(2), 2.0), StudentT(jnp.zeros(2), 2.0, 4.5)])
def test_a_run_is_the_same_with_jax_keys(monkeypatch, regeneration):
    """`restore.sample` on unrolled keys against the same run on JAX's keys: the same sums and draws."""
    def sampler():  # a new log density function each time: the run loop is traced again
        return restore.JumpRestore(lambda x: -0.5 * jnp.sum(x**2), RandomWalk(0.8), regeneration, tour_length=4.0)

    kwargs = dict(num_lanes=16, num_steps=120, progress=False, num_chunks=3)
    fast = restore.sample(sampler(), jax.random.key(3), **kwargs)
    monkeypatch.setattr(run_module, "unrolled_keys", lambda keys: keys)
    plain = restore.sample(sampler(), jax.random.key(3), **kwargs)
    np.testing.assert_array_equal(fast.draws, plain.draws)
    for name in ("sum_t", "num_tours", "num_accepted"):
        np.testing.assert_array_equal(getattr(fast.sums, name), getattr(plain.sums, name))
    np.testing.assert_array_equal(fast.sums.sum_f, plain.sums.sum_f)
