"""ArviZ export: lanes are chains, weighted draws are labelled, R-hat and ESS come from ArviZ.

Runs with ArviZ 0.x (`InferenceData`) and 1.x (`xarray.DataTree`): both give
`data.posterior`, `data.sample_stats`, and accept `az.rhat` / `az.ess`.
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import restore
from restore._arviz import resample_lanes
from restore.local import RandomWalk
from restore.regeneration import Gaussian

az = pytest.importorskip("arviz")
ARVIZ_1 = int(az.__version__.split(".")[0]) >= 1


@pytest.fixture(scope="module")
def run():
    sampler = restore.JumpRestore(lambda x: -0.5 * jnp.sum(x**2), RandomWalk(1.0), Gaussian(jnp.zeros(2), 2.0), log_rate=0.0)
    return restore.sample(sampler, jax.random.key(3), num_lanes=32, num_steps=600, progress=False, max_draws=32 * 200)


def _max(stat, name="x"):
    return float(np.max(np.asarray(stat[name])))


def test_lanes_are_chains_and_the_draws_say_what_they_are(run):
    data = run.to_arviz()
    assert type(data).__name__ == ("DataTree" if ARVIZ_1 else "InferenceData")
    n = run.draws.shape[0]
    assert data.posterior["x"].shape == (32, n, 2)
    assert data.posterior.attrs["restore_draws"] == "resampled"
    stats = data.sample_stats
    np.testing.assert_array_equal(np.asarray(stats["weight"]), 1.0)
    source = np.asarray(stats["source_draw"])
    lane = 5
    np.testing.assert_array_equal(np.asarray(data.posterior["x"])[lane], run.draws[source[lane], lane])
    np.testing.assert_array_equal(np.asarray(stats["source_weight"])[lane], run.draw_weights[source[lane], lane])

    weighted = run.to_arviz(resample=False)
    assert weighted.posterior.attrs["restore_draws"] == "weighted"
    np.testing.assert_array_equal(np.asarray(weighted.posterior["x"]), np.swapaxes(run.draws, 0, 1))
    np.testing.assert_array_equal(np.asarray(weighted.sample_stats["weight"]), run.draw_weights.T)


def test_rhat_and_ess_from_arviz(run):
    data = run.to_arviz()
    assert _max(az.rhat(data)) < 1.02
    ess = np.asarray(az.ess(data)["x"])
    assert np.all(ess > 500) and np.all(ess < 32 * run.draws.shape[0])
    # Lanes stay chains: stuck lanes (half of them moved away) are seen by R-hat
    stuck = dataclasses.replace(run, draws=run.draws + 3.0 * (np.arange(32) < 16)[None, :, None], sampler_name="stuck")
    assert _max(az.rhat(stuck.to_arviz())) > 1.5


def test_named_variables_from_a_transform(run):
    data = run.to_arviz(transform=lambda x: {"first": x[..., 0], "radius": np.linalg.norm(x, axis=-1)})
    assert set(data.posterior.data_vars) == {"first", "radius"}
    assert data.posterior["radius"].shape == (32, run.draws.shape[0])
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
