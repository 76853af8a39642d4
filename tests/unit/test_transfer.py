"""Transfer kernels: invariance of the reference, dependence on the exit point, transition densities, errors.

Invariance checks push `N` exact reference draws through `K` successive transfers (one
`sample` each, independent keys) and compare the result after the first and after the
last with fresh reference draws (two-sample KS on every coordinate and on a random
projection): repeating the transfer lets a small violation of invariance add up. Each has
a negative control that must fail. Keys are fixed, so every check
is deterministic. Exit points are pushed in float32 (the kernels' parameters are float64):
the same compiled function checks that `sample` keeps the dtype of `exit_position` under
`jit` and `vmap`. XLA compiles are the cost here, so few distinct functions are jitted.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.stats

from restore.regeneration import AbstractRegeneration, Gaussian, Mixture, UniformBox
from restore.transfer import (
    AbstractTransfer,
    AutoregressiveGaussian,
    Independent,
    MetropolisTransfer,
    TransferMixture,
    WrappedGaussianJump,
)

N = 20_000
K = 8  # successive transfers of every exit point
PASS = 1e-3  # every p-value of an exact kernel must exceed this
FAIL = 1e-6  # some p-value of a broken one must fall below this

MEAN = jnp.array([0.5, -1.0, 2.0])
BOX_LOW, BOX_HIGH = jnp.array([0.0, -1.0]), jnp.array([1.0, 3.0])
COV = jnp.array([[2.0, 0.6, -0.3], [0.6, 1.0, 0.2], [-0.3, 0.2, 0.5]])


@eqx.filter_jit
def _push(transfer: AbstractTransfer, key, exits):
    """`K` successive transfers of every exit point: the path, shape `(K, n, d)`."""

    def transfer_all(points, key):
        points = jax.vmap(transfer.sample)(jax.random.split(key, points.shape[0]), points)
        return points, points

    return jax.lax.scan(transfer_all, exits, jax.random.split(key, K))[1]


@eqx.filter_jit
def _log_densities(transfer: AbstractTransfer, exit_position, positions):
    """`log mu(exit_position, y)` for every row `y` of `positions`."""
    return jax.vmap(lambda y: transfer.log_transition_density(exit_position, y))(positions)


def _ks_pvalues(y, z, seed: int) -> list[float]:
    """Two-sample KS p-values of `y` against `z` on every coordinate and on one random direction."""
    y, z = np.asarray(y), np.asarray(z)
    v = np.random.default_rng(seed).normal(size=y.shape[1])
    pairs = [(y[:, i], z[:, i]) for i in range(y.shape[1])] + [(y @ v, z @ v)]
    return [scipy.stats.ks_2samp(a, b).pvalue for a, b in pairs]


def _pushed_and_fresh(transfer: AbstractTransfer, exits_from: AbstractRegeneration, seed: int):
    """`N` draws of `exits_from`, their path through `K` transfers, and `5 N` fresh draws of the reference."""
    k_exit, k_move, k_fresh = jax.random.split(jax.random.key(seed), 3)
    exits = exits_from.sample(k_exit, (N,)).astype(jnp.float32)
    path = _push(transfer, k_move, exits)
    assert path.dtype == jnp.float32 and path.shape == (K, *exits.shape)
    return exits, path, transfer.reference.sample(k_fresh, (5 * N,))


class _Tempered(AbstractRegeneration):
    """Exact draws of `base`, but `log_prob` of `base ** power`: a Metropolis transfer targeting it is broken."""

    base: Gaussian
    power: float = eqx.field(static=True)
    dim: int = eqx.field(static=True)

    def sample(self, key, shape=()):
        return self.base.sample(key, shape)

    def log_prob(self, x):
        return self.power * self.base.log_prob(x)


def _ar_plus_independent(weights=(0.7, 0.3)) -> TransferMixture:
    return TransferMixture([AutoregressiveGaussian(MEAN, COV, 0.9), Independent(Gaussian(MEAN, COV))], weights)


INVARIANT = {
    "autoregressive": lambda: AutoregressiveGaussian(MEAN, COV, 0.9),
    "autoregressive-rho0": lambda: AutoregressiveGaussian(MEAN, COV, 0.0),
    "metropolis-gaussian": lambda: MetropolisTransfer(Gaussian(MEAN, COV), 0.8),
    # a non-Gaussian reference with hard walls, per-coordinate scales, three steps (fori_loop)
    "metropolis-box-3-steps": lambda: MetropolisTransfer(
        UniformBox(BOX_LOW, BOX_HIGH), jnp.array([0.4, 1.5]), num_steps=3
    ),
    "wrapped": lambda: WrappedGaussianJump(jnp.array([0.1, 0.7]), dim=2),
    "mixture-ar-independent": _ar_plus_independent,
}


@pytest.mark.parametrize("name", list(INVARIANT))
def test_transfer_leaves_reference_invariant(name):
    transfer = INVARIANT[name]()
    exits, path, fresh = _pushed_and_fresh(transfer, transfer.reference, seed=1)
    assert np.all(np.isfinite(path))
    assert not np.allclose(path[0], exits)  # it moved
    pvalues = _ks_pvalues(path[0], fresh, seed=2) + _ks_pvalues(path[-1], fresh, seed=2)
    assert min(pvalues) > PASS, pvalues


SHIFTED = Gaussian(MEAN + 0.3, COV)
BROKEN = {
    # exit points not drawn from the reference: the kernel does not map them to it
    "autoregressive-wrong-exits": (lambda: AutoregressiveGaussian(MEAN, COV, 0.9), SHIFTED),
    "mixture-wrong-exits": (_ar_plus_independent, SHIFTED),
    "wrapped-wrong-exits": (
        lambda: WrappedGaussianJump(jnp.array([0.1, 0.7]), dim=2),
        UniformBox(jnp.zeros(2), jnp.array([0.5, 1.0])),
    ),
    # Metropolis steps whose acceptance ratio uses the wrong density (reference^0.25)
    "metropolis-broken-acceptance": (
        lambda: MetropolisTransfer(_Tempered(base=Gaussian(MEAN, COV), power=0.25, dim=3), 0.8),
        Gaussian(MEAN, COV),
    ),
}


@pytest.mark.parametrize("name", list(BROKEN))
def test_negative_control_is_detected(name):
    make, exits_from = BROKEN[name]
    transfer = make()
    _, path, fresh = _pushed_and_fresh(transfer, exits_from, seed=3)
    if isinstance(transfer.reference, _Tempered):  # compare with the distribution it should have kept
        fresh = transfer.reference.base.sample(jax.random.key(4), (5 * N,))
    pvalues = _ks_pvalues(path[0], fresh, seed=2)  # after one transfer
    assert min(pvalues) < FAIL, pvalues


def _cross_covariance(x, y):
    x, y = np.asarray(x), np.asarray(y)
    return (x - x.mean(0)).T @ (y - y.mean(0)) / (x.shape[0] - 1)


@pytest.mark.parametrize("rho", [0.0, 0.6])
def test_autoregressive_correlation_with_exit_is_rho(rho):
    transfer = AutoregressiveGaussian(MEAN, COV, rho)
    exits, path, _ = _pushed_and_fresh(transfer, transfer.reference, seed=5)
    pushed = path[0]
    np.testing.assert_allclose(_cross_covariance(exits, pushed), rho * np.asarray(COV), atol=0.05)
    corr = [np.corrcoef(exits[:, i], pushed[:, i])[0, 1] for i in range(3)]
    np.testing.assert_allclose(corr, rho, atol=0.03)


def test_mixture_correlation_follows_the_weights():
    # with probability 0.25 the AR(0.9) kernel, else an independent draw: Cov(x, y) = 0.225 S
    transfer = _ar_plus_independent(weights=(1.0, 3.0))
    exits, path, _ = _pushed_and_fresh(transfer, transfer.reference, seed=6)
    pushed = path[0]
    np.testing.assert_allclose(_cross_covariance(exits, pushed), 0.225 * np.asarray(COV), atol=0.05)
    np.testing.assert_allclose(transfer.weights, [0.25, 0.75])


def test_wrapped_jump_stays_near_the_exit():
    # E cos(2 pi (y - x)) = exp(-2 pi^2 scale^2) per coordinate, whatever the exit point
    transfer = WrappedGaussianJump(jnp.array([0.1, 0.7]), dim=2)
    exits, path, _ = _pushed_and_fresh(transfer, transfer.reference, seed=7)
    pushed = path[0]
    assert np.all((pushed >= 0) & (pushed < 1))
    mean_cos = np.mean(np.cos(2 * np.pi * (np.asarray(pushed) - np.asarray(exits))), axis=0)
    np.testing.assert_allclose(mean_cos, np.exp(-2 * np.pi**2 * np.array([0.1, 0.7]) ** 2), atol=0.02)


def test_metropolis_stays_near_the_exit_with_an_atom():
    transfer = MetropolisTransfer(Gaussian(MEAN, COV), 0.3)
    exits, path, _ = _pushed_and_fresh(transfer, transfer.reference, seed=8)
    pushed = path[0]
    stayed = np.all(np.asarray(pushed) == np.asarray(exits), axis=1)
    assert 0.05 < stayed.mean() < 0.6  # rejections leave it exactly at the exit point
    step = np.linalg.norm(np.asarray(pushed) - np.asarray(exits), axis=1)[~stayed]
    assert np.sqrt(np.mean(step**2)) < 0.3 * math.sqrt(3) * 1.2  # accepted moves are proposal-sized
    corr = [np.corrcoef(exits[:, i], pushed[:, i])[0, 1] for i in range(3)]
    assert min(corr) > 0.9


def test_metropolis_from_outside_the_support_moves_in():
    transfer = INVARIANT["metropolis-box-3-steps"]()
    exits = jnp.broadcast_to(jnp.array([1.05, 0.5], jnp.float32), (N, 2))  # just outside the box
    pushed = np.asarray(_push(transfer, jax.random.key(9), exits)[0])
    inside = np.all((pushed >= np.asarray(BOX_LOW)) & (pushed <= np.asarray(BOX_HIGH)), axis=1)
    # a step from the exit point enters with probability P(1.05 + 0.4 z_1 <= 1) P(-1 <= 0.5 + 1.5 z_2 <= 3)
    enter = scipy.stats.norm.cdf(-0.05 / 0.4) * (scipy.stats.norm.cdf(2.5 / 1.5) - scipy.stats.norm.cdf(-1.0))
    assert abs(inside.mean() - (1 - (1 - enter) ** 3)) < 0.02
    assert np.all(np.all(pushed == np.asarray(exits), axis=1) | inside)  # a move never leads outside again


def _check_density_1d(transfer, exit_position, low, high, seed, bins=40, sub=200):
    """The density integrates to one on [low, high] and fits a histogram of draws (chi-square)."""
    edges = np.linspace(low, high, bins + 1)
    width = (high - low) / (bins * sub)
    midpoints = low + width * (np.arange(bins * sub) + 0.5)
    dens = np.exp(np.asarray(_log_densities(transfer, exit_position, jnp.asarray(midpoints)[:, None])))
    assert abs(dens.sum() * width - 1) < 1e-6  # midpoint rule
    probs = dens.reshape(bins, sub).sum(axis=1) * width
    exits = jnp.broadcast_to(exit_position.astype(jnp.float32), (N, 1))
    y = np.asarray(_push(transfer, jax.random.key(seed), exits)[0, :, 0])
    assert np.all((y >= low) & (y < high))
    counts, _ = np.histogram(y, edges)
    expected = probs / probs.sum() * counts.sum()
    keep = expected >= 5
    assert keep.sum() >= 15
    p = scipy.stats.chisquare(counts[keep], expected[keep] / expected[keep].sum() * counts[keep].sum()).pvalue
    assert p > PASS, p


def test_autoregressive_density_1d_normalised_and_fits_draws():
    transfer = AutoregressiveGaussian(jnp.array([0.5]), 2.0, 0.7)
    x = jnp.array([1.3])
    sd = math.sqrt(2.0 * (1 - 0.7**2))
    centre = 0.5 + 0.7 * 0.8
    _check_density_1d(transfer, x, centre - 7 * sd, centre + 7 * sd, seed=10)


@pytest.mark.parametrize("scale", [0.1, 0.5])
def test_wrapped_density_1d_normalised_and_fits_draws(scale):
    _check_density_1d(WrappedGaussianJump(scale, dim=1), jnp.array([0.9]), 0.0, 1.0, seed=11)


def test_autoregressive_density_matches_scipy():
    rho = 0.8
    transfer = AutoregressiveGaussian(MEAN, COV, rho)
    rng = np.random.default_rng(13)
    x, ys = rng.normal(size=3), rng.normal(size=(5, 3))
    got = _log_densities(transfer, jnp.asarray(x), jnp.asarray(ys))
    mean = np.asarray(MEAN) + rho * (x - np.asarray(MEAN))
    want = scipy.stats.multivariate_normal(mean, (1 - rho**2) * np.asarray(COV)).logpdf(ys)
    np.testing.assert_allclose(got, want, rtol=1e-10)


def test_wrapped_density_matches_brute_force_sum():
    scale = np.array([0.05, 0.5])
    transfer = WrappedGaussianJump(jnp.asarray(scale), dim=2)
    rng = np.random.default_rng(14)
    x, ys = rng.uniform(size=2), rng.uniform(size=(6, 2))
    ys[0] = (x + np.array([0.5, -0.5])) % 1  # the far side of the torus
    ys = np.concatenate([ys, [[0.5, 1.0]]])  # outside [0, 1)^2
    got = np.asarray(_log_densities(transfer, jnp.asarray(x), jnp.asarray(ys)))
    assert got[-1] == -np.inf
    got, ys = got[:-1], ys[:-1]
    k = np.arange(-50, 51)
    diff = ys[:, :, None] - x[None, :, None] + k
    terms = scipy.stats.norm.pdf(diff, scale=scale[None, :, None]).sum(axis=2)
    np.testing.assert_allclose(got, np.log(terms).sum(axis=1), rtol=1e-12)


def test_mixture_density_is_weighted_sum_and_needs_component_densities():
    ar, ind = AutoregressiveGaussian(MEAN, COV, 0.9), Independent(Gaussian(MEAN, COV))
    transfer = TransferMixture([ar, ind], [0.2, 0.8])
    x, ys = jnp.array([1.0, 0.0, 1.5]), jnp.array([[0.0, -0.5, 2.5], [1.0, 0.1, 1.4]])
    want = np.logaddexp(
        np.log(0.2) + np.asarray(_log_densities(ar, x, ys)), np.log(0.8) + np.asarray(_log_densities(ind, x, ys))
    )
    np.testing.assert_allclose(_log_densities(transfer, x, ys), want, rtol=1e-12)
    assert abs(want[1] - want[0]) > 1  # the AR part matters at these points
    with_atom = TransferMixture([ar, MetropolisTransfer(Gaussian(MEAN, COV), 0.5)])
    with pytest.raises(NotImplementedError, match="MetropolisTransfer"):
        with_atom.log_transition_density(x, ys[0])


def test_is_independent():
    g = Gaussian(MEAN, COV)
    assert not AutoregressiveGaussian(MEAN, COV, 0.0).is_independent
    assert not MetropolisTransfer(g, 1.0).is_independent
    assert not WrappedGaussianJump(0.1, 2).is_independent
    assert TransferMixture([Independent(g), Independent(Gaussian(MEAN, COV))]).is_independent
    assert not _ar_plus_independent().is_independent
    assert AutoregressiveGaussian(MEAN, COV, 0.5).reference.dim == 3 and WrappedGaussianJump(0.1, 2).dim == 2


def test_mixture_rejects_components_with_different_references():
    ar = AutoregressiveGaussian(MEAN, COV, 0.9)
    for other in [
        Independent(Gaussian(MEAN + 1, COV)),  # other mean
        AutoregressiveGaussian(MEAN, 2 * COV, 0.5),  # other covariance
        MetropolisTransfer(Mixture([Gaussian(MEAN, COV)]), 1.0),  # same density, other class: not provably equal
        Independent(Gaussian(jnp.zeros(2))),  # other dimension
        WrappedGaussianJump(0.1, 3),  # other reference altogether
    ]:
        with pytest.raises(ValueError, match="dimension|reference"):
            TransferMixture([ar, other])
    with pytest.raises(ValueError, match="reference"):
        TransferMixture([WrappedGaussianJump(0.1, 2), MetropolisTransfer(UniformBox(jnp.zeros(2), jnp.ones(2)), 0.1)])


BAD = {
    "rho=1": (lambda: AutoregressiveGaussian(MEAN, COV, 1.0), ValueError, "correlation"),
    "rho<0": (lambda: AutoregressiveGaussian(MEAN, COV, -0.1), ValueError, "correlation"),
    "rho=nan": (lambda: AutoregressiveGaussian(MEAN, COV, jnp.nan), ValueError, "correlation"),
    "rho-vector": (lambda: AutoregressiveGaussian(MEAN, COV, jnp.array([0.1, 0.2, 0.3])), ValueError, "scalar"),
    "ar-cov-shape": (lambda: AutoregressiveGaussian(MEAN, jnp.eye(2), 0.5), ValueError, "cov"),
    "ar-cov-not-pd": (lambda: AutoregressiveGaussian(MEAN, -jnp.eye(3), 0.5), ValueError, "positive definite"),
    "mh-scale=0": (lambda: MetropolisTransfer(Gaussian(MEAN), 0.0), ValueError, "positive"),
    "mh-scale<0": (lambda: MetropolisTransfer(Gaussian(MEAN), -1.0), ValueError, "positive"),
    "mh-scale=inf": (lambda: MetropolisTransfer(Gaussian(MEAN), jnp.inf), ValueError, "positive"),
    "mh-scale-length": (lambda: MetropolisTransfer(Gaussian(MEAN), jnp.ones(2)), ValueError, "length 2"),
    "mh-scale-matrix": (lambda: MetropolisTransfer(Gaussian(MEAN), jnp.eye(3)), ValueError, "scalar or a vector"),
    "mh-steps=0": (lambda: MetropolisTransfer(Gaussian(MEAN), 1.0, 0), ValueError, "num_steps"),
    "mh-steps-float": (lambda: MetropolisTransfer(Gaussian(MEAN), 1.0, 2.5), ValueError, "num_steps"),
    "mh-steps-bool": (lambda: MetropolisTransfer(Gaussian(MEAN), 1.0, True), TypeError, "num_steps"),
    "mh-not-a-distribution": (lambda: MetropolisTransfer(lambda x: -x @ x, 1.0), TypeError, "regeneration"),
    "wrapped-scale=0": (lambda: WrappedGaussianJump(0.0, 2), ValueError, "positive"),
    "wrapped-scale<0": (lambda: WrappedGaussianJump(-0.1, 2), ValueError, "positive"),
    "wrapped-scale-length": (lambda: WrappedGaussianJump(jnp.array([0.1, 0.2, 0.3]), 2), ValueError, "length 3"),
    "wrapped-dim=0": (lambda: WrappedGaussianJump(0.1, 0), ValueError, "dim"),
    "mixture-empty": (lambda: TransferMixture([]), ValueError, "at least one"),
    "mixture-not-a-transfer": (
        lambda: TransferMixture([Independent(Gaussian(MEAN)), Gaussian(MEAN)]),
        TypeError,
        "component 1",
    ),
    "mixture-weights-length": (lambda: _ar_plus_independent(weights=(1.0, 1.0, 1.0)), ValueError, "shape"),
    "mixture-weight-zero": (lambda: _ar_plus_independent(weights=(1.0, 0.0)), ValueError, "positive"),
    "mixture-weight-negative": (lambda: _ar_plus_independent(weights=(1.0, -1.0)), ValueError, "positive"),
    "mixture-weight-nan": (lambda: _ar_plus_independent(weights=(1.0, np.nan)), ValueError, "positive"),
    "sample-exit-shape": (
        lambda: AutoregressiveGaussian(MEAN, COV, 0.5).sample(jax.random.key(0), jnp.zeros(2)),
        ValueError,
        "shape",
    ),
    "density-position-shape": (
        lambda: WrappedGaussianJump(0.1, 2).log_transition_density(jnp.zeros(2), jnp.zeros((2, 2))),
        ValueError,
        "shape",
    ),
}


@pytest.mark.parametrize("name", list(BAD))
def test_clear_errors(name):
    make, error, match = BAD[name]
    with pytest.raises(error, match=match):
        make()
