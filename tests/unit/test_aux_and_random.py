"""A log density's extra output (`has_aux`) travels with the state; `log_uniform` resolves small probabilities."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

import restore
from restore._random import log_uniform
from restore.local import RandomWalk, TorusMetropolis
from restore.regeneration import Gaussian, UniformTorus


def with_colour(x):
    """A Gaussian log density whose aux is a function of the point (as a renderer's colour is)."""
    return -0.5 * jnp.sum(x**2), {"colour": jnp.stack([x[0], 2 * x[0]]), "norm": jnp.sum(x**2)}


def test_step_info_carries_the_aux_of_the_state_it_weighs():
    sampler = restore.JumpRestore(with_colour, RandomWalk(0.8), Gaussian(jnp.zeros(2), 2.0 * jnp.eye(2)), log_rate=-1.0, has_aux=True)
    keys = jax.random.split(jax.random.key(0), 256)
    states = jax.vmap(sampler.init)(keys)

    @jax.jit
    def run(states, key):
        def body(states, k):
            new, info = jax.vmap(sampler.step)(jax.random.split(k, 256), states)
            return new, (info.position, info.aux, new.position, new.aux)

        return jax.lax.scan(body, states, jax.random.split(key, 20))[1]

    position, aux, new_position, new_aux = run(states, jax.random.key(1))
    for x, a in ((position, aux), (new_position, new_aux)):
        np.testing.assert_allclose(a["colour"][..., 0], x[..., 0], rtol=1e-6)
        np.testing.assert_allclose(a["colour"][..., 1], 2 * x[..., 0], rtol=1e-6)
        np.testing.assert_allclose(a["norm"], np.sum(np.asarray(x) ** 2, axis=-1), rtol=1e-6)


def test_aux_does_not_change_the_run():
    """The same key gives the same path with and without aux: it is carried, never drawn on."""
    value = lambda x: with_colour(x)[0]  # noqa: E731
    kw = dict(log_rate=-1.0)
    plain = restore.JumpRestore(value, RandomWalk(0.8), Gaussian(jnp.zeros(2), 2.0 * jnp.eye(2)), **kw)
    aux = restore.JumpRestore(with_colour, RandomWalk(0.8), Gaussian(jnp.zeros(2), 2.0 * jnp.eye(2)), has_aux=True, **kw)
    a, b = (restore.sample(s, jax.random.key(3), num_lanes=16, num_steps=100, progress=False) for s in (plain, aux))
    np.testing.assert_array_equal(a.estimate("x").value, b.estimate("x").value)


def test_has_aux_mismatches_are_refused_clearly():
    gaussian = Gaussian(jnp.zeros(2), jnp.eye(2))
    with pytest.raises(ValueError, match="has_aux=True"):
        restore.JumpRestore(with_colour, RandomWalk(0.5), gaussian, log_rate=0.0)
    with pytest.raises(ValueError, match="pair"):
        restore.JumpRestore(lambda x: -jnp.sum(x**2), RandomWalk(0.5), gaussian, log_rate=0.0, has_aux=True)


def test_torus_sampler_with_aux_runs_in_float32():
    sampler = restore.JumpRestore(
        lambda u: (-50.0 * jnp.sum((u - 0.5) ** 2), u[:1]), TorusMetropolis(), UniformTorus(2, jnp.float32), tour_length=2.0, has_aux=True
    )
    result = restore.sample(sampler, jax.random.key(0), num_lanes=64, num_steps=300, progress=False)
    assert sampler.dtype == jnp.float32 and result.final_state.aux.dtype == jnp.float32
    estimate = result.estimate("x")
    assert np.all(np.abs(estimate.value - 0.5) < 5 * estimate.standard_error + 1e-3)


def test_log_uniform_is_exponential_and_resolves_below_the_float32_grid():
    keys = jax.random.split(jax.random.key(0), 200_000)
    draws = np.asarray(jax.jit(jax.vmap(lambda k: log_uniform(k, jnp.float32)))(keys), np.float64)
    assert draws.dtype == np.float64 and np.all(draws <= 0)
    assert stats.kstest(-draws, "expon").pvalue > 1e-3
    # a plain float32 uniform is a multiple of 2^-23; these fill in the bits below that grid
    scaled = np.exp(draws[draws < np.log(1e-2)]) * 2.0**23
    assert np.mean(np.abs(scaled - np.round(scaled)) > 1e-3) > 0.5


def test_log_uniform_keeps_float64_streams():
    key = jax.random.key(7)
    assert float(log_uniform(key, jnp.float64)) == float(jnp.log(jax.random.uniform(key, dtype=jnp.float64)))
