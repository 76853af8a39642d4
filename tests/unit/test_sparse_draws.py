"""Draws computed only for the lanes that use them give exactly what `vmap` gives."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import restore
import restore._restore as restore_module
from restore._sparse_draws import draw_slots, draw_where
from restore.dynamics import Jump
from restore.local import RandomWalk
from restore.regeneration import Gaussian, Mixture, StudentT
from restore.transfer import AutoregressiveGaussian, Independent
from tests._models import mixture_2d


def test_draw_slots_hold_the_expected_share_with_room_and_give_up_when_it_is_large():
    assert draw_slots(512, 1 / 11) == 72  # mean 46.5, two standard deviations 13, eight more
    assert draw_slots(512, None) == draw_slots(512, 0.25) == 160
    assert draw_slots(512, 0.5) is None and draw_slots(16, 0.1) is None
    assert draw_slots(4096, 0.0) == 8


@pytest.mark.parametrize("needed_share", [0.0, 0.05, 0.3, 1.0])
def test_draw_where_equals_the_masked_vmap_whatever_the_number_of_batches(needed_share):
    """Eight slots for up to 200 lanes that need a draw: one to 25 batches, the same values."""
    n = 200
    keys = jax.random.split(jax.random.key(0), n)
    shift = jnp.arange(n, dtype=jnp.float64)[:, None] * jnp.ones((1, 3))
    needed = jax.random.uniform(jax.random.key(1), (n,)) < needed_share

    def draw(key, x):
        return x + jax.random.t(key, 3.0, (3,), jnp.float64)  # a rejection loop inside

    got = jax.jit(lambda *a: draw_where(draw, needed, 8, *a))(keys, shift)
    want = jax.jit(lambda *a: jnp.where(needed[:, None], jax.vmap(draw)(*a), 0.0))(keys, shift)
    np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


def test_draw_where_puts_each_draw_back_at_its_own_lane():
    """A draw that depends on the lane's own argument: a permutation would show."""
    needed = jnp.array([False, True, True, False, True, True, True, False, True, True, True])
    values = draw_where(lambda x: 10.0 * x, needed, 8, jnp.arange(11.0))
    np.testing.assert_array_equal(np.asarray(values), np.where(np.asarray(needed), 10.0 * np.arange(11.0), 0.0))


def _steps(sampler, step_all, num_lanes=256, num_steps=12):
    states = jax.vmap(sampler.init)(jax.random.split(jax.random.key(2), num_lanes))

    def body(states, key):
        states, info = step_all(jax.random.split(key, num_lanes), states)
        return states, (info.position, info.regenerated, info.accepted, info.log_importance_weight)

    return jax.jit(lambda s: jax.lax.scan(body, s, jax.random.split(jax.random.key(3), num_steps)))(states)


def _samplers():
    target = mixture_2d()
    heavy = StudentT(target.mean, 3.0 * target.covariance, 4.0)
    modes = Mixture([Gaussian(m, c) for m, c in zip(target.means, target.covariances)])
    wide = Gaussian(target.mean, 3.0 * target.covariance)
    yield "jump, Student-t", restore.JumpRestore(target.logdensity, RandomWalk(0.8), heavy, tour_length=8.0).calibrate(jax.random.key(0))[0]
    yield "two phases", restore.Restore(
        target.logdensity, (Jump(RandomWalk(0.8)), Jump(RandomWalk(0.3))), (Independent(wide), Independent(modes)), log_rate=(0.0, -1.0)
    )
    yield "exit-dependent transfer", restore.Restore(
        target.logdensity, Jump(RandomWalk(0.8)), AutoregressiveGaussian(target.mean, target.covariance, 0.5), log_rate=0.5
    )
    yield "MH with large steps", restore.MixtureMH(target.logdensity, RandomWalk(0.8), heavy, large_step_probability=0.1)


@pytest.mark.parametrize("costly", [False, True], ids=["kill terms at every lane", "kill terms where lanes moved"])
@pytest.mark.parametrize("name, sampler", list(_samplers()), ids=[n for n, _ in _samplers()])
def test_step_lanes_is_vmap_of_step_lane_by_lane(name, sampler, costly, monkeypatch):
    """Costly kill terms (`COSTLY_TERMS`, lowered to 0 here) are computed only where lanes
    moved or started a tour, in batches: the same values as at every lane."""
    if costly:
        monkeypatch.setattr(restore_module, "COSTLY_TERMS", 0.0)
    _, fast = _steps(sampler, sampler.step_lanes)
    _, plain = _steps(sampler, jax.vmap(sampler.step))
    for a, b in zip(fast, plain, strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert np.asarray(fast[1]).any() or name.startswith("MH")  # some lanes did draw a start


def test_kill_terms_count_as_costly_for_a_mixture_and_not_for_one_small_gaussian():
    normal = lambda x: -0.5 * jnp.sum(x**2)  # noqa: E731
    gaussian = restore.JumpRestore(normal, RandomWalk(0.5), Gaussian(jnp.zeros(10), 2.0 * jnp.eye(10)), log_rate=0.0)
    modes = Mixture([StudentT(jnp.full(10, float(i)), jnp.eye(10), 5.0) for i in range(3)])
    mixture = restore.JumpRestore(normal, RandomWalk(0.5), modes, log_rate=0.0)
    assert not gaussian._costly_terms() and mixture._costly_terms()
