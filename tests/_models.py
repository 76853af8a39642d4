"""Targets, regenerations and deliberately wrong samplers shared by the statistical tests."""

import jax
import jax.numpy as jnp
import numpy as np

import restore
from restore.local import RandomWalk, metropolis_accept
from restore.regeneration import AbstractRegeneration, StudentT, laplace_mixture
from targets.analytic import Banana, GaussianMixture, well_separated_gaussian_mixture


def mixture_2d() -> GaussianMixture:
    """Two unequal, overlapping-enough modes with different shapes."""
    means = jnp.array([[-2.5, 0.0], [2.0, 1.0]])
    covs = jnp.array([[[1.0, 0.3], [0.3, 0.6]], [[0.5, 0.0], [0.0, 1.5]]])
    return GaussianMixture(means, covs, jnp.array([0.3, 0.7]))


def mixture_10d() -> GaussianMixture:
    """Three well-separated modes in 10-d, weights 1/6, 2/6, 3/6."""
    return well_separated_gaussian_mixture(10, 3, separation=8.0)


def banana() -> Banana:
    return Banana(dim=2, curvature=0.1, scale=3.0)


def laplace_regeneration(target, key=jax.random.key(0), spread=6.0):
    """Equal-weight Student-t Laplace mixture at the modes found from random starts."""
    starts = spread * jax.random.normal(key, (48, target.dim))
    return laplace_mixture(target.logdensity, starts, tails="student_t", df=5.0, weights="equal", scale=1.5)


def broad_regeneration(target):
    """A Student-t centred on the target's mean with twice its covariance."""
    return StudentT(target.mean, 2.0 * target.covariance, 5.0)


class UnadjustedRandomWalk(RandomWalk):
    """Negative control: a random walk that accepts every move (not pi-invariant)."""

    def accept(self, key, point, candidate, aux):
        return metropolis_accept(key, point, candidate, jnp.zeros((), point.logdensity.dtype))


class RateDistortion(AbstractRegeneration):
    """Negative control: samples like `base` but reports `(1 - power) log u + power log p`.

    In jump Restore this makes the kill rate `c (p / u)^power u / p`: `power = 1` gives a
    constant kill rate `c`; `power = 1/2` the rate `c sqrt(u / p)`, wrongly scaled by a
    state-dependent factor.
    """

    base: AbstractRegeneration
    logdensity: object
    power: float
    dim: int

    def __init__(self, base, logdensity, power):
        self.base, self.logdensity, self.power, self.dim = base, logdensity, power, base.dim

    def sample(self, key, shape=()):
        return self.base.sample(key, shape)

    def log_prob(self, x):
        return (1.0 - self.power) * self.base.log_prob(x) + self.power * self.logdensity(x)


def calibrated(sampler, seed=123):
    return sampler.calibrate(jax.random.key(seed))[0]


def mode_indicator(target):
    return lambda x: jax.nn.one_hot(target.assign_mode(x), target.num_modes, dtype=x.dtype)


def second_moments(target):
    return np.diag(np.asarray(target.covariance)) + np.asarray(target.mean) ** 2


def jump_restore(target, local, regeneration, tour_length=1.0):
    return calibrated(restore.JumpRestore(target.logdensity, local, regeneration, tour_length=tour_length))
