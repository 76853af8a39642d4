"""ArviZ export: lanes grouped into chains, weighted draws are labelled, R-hat and ESS come from ArviZ.

Runs with ArviZ 0.x (`InferenceData`) and 1.x (`xarray.DataTree`): both give
`data.posterior`, `data.sample_stats`, and accept `az.rhat` / `az.ess`.
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import restore
from restore._arviz import chain_count, resample_lanes
from restore.local import RandomWalk
from restore.regeneration import Gaussian

az = pytest.importorskip("arviz")
ARVIZ_1 = int(az.__version__.split(".")[0]) >= 1


@pytest.fixture(scope="module")
def run():
    sampler = restore.JumpRestore(
        lambda x: -0.5 * jnp.sum(x**2), RandomWalk(1.0), Gaussian(jnp.zeros(2), 2.0), log_rate=0.0
    )
    return restore.sample(sampler, jax.random.key(3), num_lanes=32, num_steps=600, progress=False, save=restore.SaveDraws(32 * 200))


def _max(stat, name="x"):
    return float(np.max(np.asarray(stat[name])))


def test_lanes_grouped_into_chains_and_the_draws_say_what_they_are(run):
    data = run.to_arviz()
    assert type(data).__name__ == ("DataTree" if ARVIZ_1 else "InferenceData")
    n = run.draws.shape[0]
    assert data.posterior["x"].shape == (4, 8 * n, 2)  # 32 lanes, 8 per chain, one after another
    assert data.posterior.attrs["restore_draws"] == "resampled"
    assert data.posterior.attrs["restore_chains"].startswith("4 chains of 8 lanes")
    stats = data.sample_stats
    np.testing.assert_array_equal(np.asarray(stats["weight"]), 1.0)
    lane, chain, place = 13, 1, slice(5 * n, 6 * n)  # lane 13 is the sixth of chain 1
    np.testing.assert_array_equal(np.asarray(stats["lane"])[chain, place], lane)
    source = np.asarray(stats["source_draw"])[chain, place]
    np.testing.assert_array_equal(np.asarray(data.posterior["x"])[chain, place], run.draws[source, lane])
    np.testing.assert_array_equal(np.asarray(stats["source_weight"])[chain, place], run.draw_weights[source, lane])

    weighted = run.to_arviz(resample=False, chains=32)  # one chain per lane
    assert weighted.posterior.attrs["restore_draws"] == "weighted"
    np.testing.assert_array_equal(np.asarray(weighted.posterior["x"]), np.swapaxes(run.draws, 0, 1))
    np.testing.assert_array_equal(np.asarray(weighted.sample_stats["weight"]), run.draw_weights.T)


def test_chains_divide_the_lanes():
    assert chain_count(512, 4) == 4 and chain_count(10, 4) == 2 and chain_count(7, 4) == 1 and chain_count(3, 8) == 3
    with pytest.raises(ValueError, match="chains"):
        chain_count(8, 0)


def test_mh_lanes_stay_one_chain_each():
    # MH lanes start away from the target: R-hat must see each lane's start, so no grouping.
    mh = restore.MixtureMH(lambda x: -0.5 * jnp.sum(x**2), RandomWalk(1.0), Gaussian(jnp.zeros(2), 2.0), 0.1)
    result = restore.sample(mh, jax.random.key(2), num_lanes=8, num_steps=100, progress=False)
    assert result.to_arviz().posterior["x"].shape == (8, 100, 2)
    assert result.to_arviz(chains=4).posterior["x"].shape == (4, 200, 2)


def test_short_lanes_of_a_healthy_run_give_rhat_near_one():
    # 256 lanes of 200 draws each, whose draws are correlated within tours: one chain per
    # lane puts R-hat near sqrt(1 + 2 (tau - 1) / 200), above 1.01 on an exact run; lanes
    # grouped into 4 chains give R-hat near 1 and ArviZ's ESS matches the tour-based one.
    sampler = restore.JumpRestore(
        lambda x: -0.5 * jnp.sum(x**2), RandomWalk(1.0), Gaussian(jnp.zeros(2), 2.0), log_rate=0.0
    )
    short = restore.sample(
        sampler, jax.random.key(3), num_lanes=256, num_steps=200, progress=False, save=restore.SaveDraws(256 * 200)
    )
    assert np.all(short.estimate("x").reliable)
    assert _max(az.rhat(short.to_arviz(chains=256))) > 1.01
    data = short.to_arviz()
    assert _max(az.rhat(data)) < 1.005
    np.testing.assert_allclose(np.asarray(az.ess(data)["x"]), short.ess("x"), rtol=0.2)


def test_rhat_and_ess_from_arviz(run):
    data = run.to_arviz()
    assert _max(az.rhat(data)) < 1.02
    ess = np.asarray(az.ess(data)["x"])
    assert np.all(ess > 500) and np.all(ess < 32 * run.draws.shape[0])
    # Consecutive lanes make a chain: stuck lanes (half of them moved away) are seen by R-hat
    stuck = dataclasses.replace(run, draws=run.draws + 3.0 * (np.arange(32) < 16)[None, :, None], sampler_name="stuck")
    assert _max(az.rhat(stuck.to_arviz())) > 1.5


def test_named_variables_from_a_transform(run):
    data = run.to_arviz(transform=lambda x: {"first": x[..., 0], "radius": np.linalg.norm(x, axis=-1)})
    assert set(data.posterior.data_vars) == {"first", "radius"}
    assert data.posterior["radius"].shape == (4, 8 * run.draws.shape[0])
    with pytest.raises(ValueError, match="leading"):
        run.to_arviz(transform=lambda x: {"flat": x.reshape(-1)})


def test_resampling_follows_the_weights():
    weights = np.array([[0.0, 1.0, 0.0, 3.0], [1.0, 1.0, 1.0, 1.0], [0.0, 0.0, 0.0, 0.0]])
    index = resample_lanes(weights, seed=0)
    assert set(index[0]) <= {1, 3} and np.sum(index[0] == 3) == 3
    np.testing.assert_array_equal(index[1], [0, 1, 2, 3])
    np.testing.assert_array_equal(index[2], [0, 1, 2, 3])  # no weight at all: kept as stored


def test_no_draws_no_export(run):
    empty = dataclasses.replace(run, draws=np.zeros((0, 4, 2)), draw_weights=np.zeros((0, 4)), sampler_name="empty")
    with pytest.raises(ValueError, match="max_draws"):
        empty.to_arviz()
