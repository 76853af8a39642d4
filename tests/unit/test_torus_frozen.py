"""`TorusMetropolis(frozen=n)`: the first `n` coordinates never move, and the kernel stays reversible."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from restore._point import evaluate
from restore.local import KelemenMutation, TorusMetropolis, WrappedGaussianMutation


def _logdensity(u):
    """A smooth, strongly non-uniform density on the 2-torus (coordinate 0 matters too)."""
    return 2.0 * jnp.cos(2 * jnp.pi * u[0]) + 3.0 * jnp.sin(2 * jnp.pi * (u[1] - u[0]))


def _chain_pairs(kernel, n_chains: int, steps: int, seed: int):
    """`(x_n, x_{n+1})` of chains started from exact draws of the density (rejection sampling)."""
    rng = np.random.default_rng(seed)
    grid = rng.random((40 * n_chains, 2)).astype(np.float32)
    logp = np.asarray(jax.vmap(_logdensity)(jnp.asarray(grid)))
    keep = rng.random(len(grid)) < np.exp(logp - 5.0)
    start = jnp.asarray(grid[keep][:n_chains])
    assert len(start) == n_chains

    def step(point, key):
        k1, k2 = jax.random.split(key)
        position, aux = kernel.propose(k1, point, _logdensity)
        candidate, _ = evaluate(_logdensity, position, False)
        new, _ = kernel.accept(k2, point, candidate, aux)
        return new, new.position

    def run(x0, key):
        point, _ = evaluate(_logdensity, x0, False)
        _, path = jax.lax.scan(step, point, jax.random.split(key, steps))
        return jnp.concatenate([x0[None], path])

    keys = jax.random.split(jax.random.PRNGKey(seed), n_chains)
    return np.asarray(jax.jit(jax.vmap(run))(start, keys))


@pytest.mark.parametrize("mutation", [KelemenMutation(1 / 64, 1 / 4), WrappedGaussianMutation(0.2)])
def test_frozen_coordinates_never_move(mutation):
    path = _chain_pairs(TorusMetropolis(mutation, frozen=1), n_chains=256, steps=20, seed=1)
    np.testing.assert_array_equal(path[:, :, 0], path[:, :1, 0].repeat(path.shape[1], 1))
    assert np.mean(path[:, 1:, 1] != path[:, :-1, 1]) > 0.2  # the free coordinate does move


def test_frozen_kernel_is_reversible():
    """Detailed balance, empirically: started at stationarity, the binned joint law of
    `(x_n, x_{n+1})` of the free coordinate is symmetric, and the marginal stays put."""
    path = _chain_pairs(TorusMetropolis(WrappedGaussianMutation(0.2), frozen=1), n_chains=4000, steps=4, seed=2)
    a, b = path[:, :-1, 1].ravel(), path[:, 1:, 1].ravel()
    moved = a != b
    bins = 4
    joint = np.histogram2d(a[moved], b[moved], bins=bins, range=[[0, 1], [0, 1]])[0]
    asym = joint - joint.T
    se = np.sqrt(joint + joint.T) + 1e-9
    off = ~np.eye(bins, dtype=bool)
    assert np.max(np.abs(asym[off] / se[off])) < 4.0
    first, last = np.histogram(path[:, 0, 1], bins=8, range=(0, 1))[0], np.histogram(path[:, -1, 1], bins=8, range=(0, 1))[0]
    assert np.max(np.abs(first - last) / np.sqrt(first + last)) < 4.0


def test_frozen_must_leave_a_coordinate():
    with pytest.raises(ValueError, match="non-negative"):
        TorusMetropolis(frozen=-1)
    with pytest.raises(ValueError, match="leaves no coordinate"):
        TorusMetropolis(frozen=2).check_dim(2)
