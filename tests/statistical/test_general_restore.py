"""The general Restore layer: diffusions, non-invariant jumps, exit-dependent transfers, schedules.

Every variant passes fixed-time stationarity; the negative controls (a dropped `L* p`
term, the rate `(L* p + c mu* p) / p` with an exit-dependent transfer, a schedule whose
rates use the wrong reference) must fail it.
"""

import warnings
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import restore
from restore._bounds import minimal_log_rate
from restore._point import evaluate
from restore.dynamics import BrownianMotion, Diffusion, Jump, OrnsteinUhlenbeck, OverdampedLangevin, UnadjustedJump
from restore.local import MALA, RandomWalk
from restore.regeneration import AbstractRegeneration, Gaussian, Mixture
from restore.testing import stationarity_test
from restore.transfer import AbstractTransfer, AutoregressiveGaussian, Independent, MetropolisTransfer
from tests._models import mixture_2d

S = jnp.array([[1.2, 0.4], [0.4, 0.8]])
PRECISION = jnp.linalg.inv(S)


def gaussian_logdensity(x):
    """`N(0, S)`, unnormalised: `Z = 2 pi sqrt(det S)`."""
    return -0.5 * x @ PRECISION @ x


def gaussian_sample(key, n):
    return jax.random.multivariate_normal(key, jnp.zeros(2), S, (n,))


def safe_log_rate(target, dynamics, reference, margin=0.3):
    """`log c_tilde` a margin above the searched minimal safe value (and at least log 1/2)."""
    adjoint = lambda x: dynamics.adjoint_ratio(target.logdensity, evaluate(target.logdensity, x, False)[0])
    starts = target.mean + 4.0 * jax.random.normal(jax.random.key(1), (64, target.dim))
    found = minimal_log_rate(target.logdensity, adjoint, reference.log_prob, starts)
    return max(found.log_rate, np.log(0.5)) + margin


def check(sampler, target, passes, key=3, time=2.0, lanes=4000):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # bound violations are checked below
        report = stationarity_test(
            sampler, jax.random.key(key), target.sample, num_lanes=lanes, time=time, assign_mode=target.assign_mode, mode_weights=target.weights
        )
    assert report.passed == passes, str(report)
    if passes:  # the process simulated is the exact one but for a vanishing share of thinning candidates
        assert report.details["num_bound_exceeded"] <= 1e-4 * report.details["num_steps"], report.details
        assert report.details["num_negative_rate"] == 0, report.details
    else:
        assert report.min_p_value < 1e-6, str(report)


def diffusion_reference(target):
    """The target's components, 1.5 times wider: the diffusions' kill rates stay below affordable
    thinning bounds on all but about 1e-4 of the target's mass. (A single Gaussian twice as wide
    as the target puts `c_tilde q / p` over any such bound between the modes, on 0.7-3% of it.)"""
    return Mixture([Gaussian(m, 1.5 * c) for m, c in zip(target.means, target.covariances)], target.weights)


# --------------------------------------------------------------------------- the published Brownian example


def test_brownian_restore_reproduces_the_published_example():
    """`pi = N(0, S)` unnormalised, `nu = N(0, I)`, `log c_tilde = 2.07`: moments, tour length and `Z`."""
    process = restore.Restore(gaussian_logdensity, BrownianMotion(), Gaussian(jnp.zeros(2), jnp.eye(2)), log_rate=2.07, bound=100.0)
    with pytest.warns(RuntimeWarning, match="exceeded the thinning bound"):
        result = restore.sample(process, jax.random.key(0), num_lanes=1000, num_steps=2000, progress=False, save=restore.SaveDraws(0))
    z = result.estimate("x**2").z_score(np.array([1.2, 0.8]))
    assert np.all(np.abs(z) < 4), z
    z_log = 2 * np.pi * np.sqrt(0.8)
    stats = result.tour_statistics()
    assert abs(stats.mean_duration - z_log / np.exp(2.07)) < 4 * stats.mean_duration_se
    log_z = result.normalising_constant("tours")
    assert abs(float(log_z.value) - np.log(z_log)) < 4 * float(log_z.standard_error)
    # the reported 1/c = Z_hat / c_tilde: its relative error is that of the run's Z_hat
    assert abs(np.log(stats.expected_duration * np.exp(2.07) / z_log)) < 4 * float(log_z.standard_error), stats
    # The bound is violated only at a vanishing share of candidate events (tour starts far out).
    assert result.num_bound_exceeded < 1e-4 * result.num_steps * result.num_lanes


def test_brownian_restore_in_one_dimension_has_unit_mean_tour():
    """`pi = N(0, 1)`, `mu = N(0, 2^2)`, `c = 1` (`c_tilde = Z = sqrt(2 pi)`): mean tour duration 1."""
    process = restore.Restore(
        lambda x: -0.5 * jnp.sum(x**2), BrownianMotion(), Gaussian(jnp.zeros(1), 4.0), log_rate=0.5 * np.log(2 * np.pi), bound=40.0
    )
    result = restore.sample(process, jax.random.key(1), num_lanes=1000, num_steps=1000, progress=False, save=restore.SaveDraws(0))
    stats = result.tour_statistics()
    assert abs(stats.mean_duration - 1.0) < 4 * stats.mean_duration_se
    assert result.num_negative_rate == 0


# --------------------------------------------------------------------------- fixed-time stationarity


def test_brownian_restore_is_stationary_and_without_the_adjoint_is_not():
    target = mixture_2d()
    reference = diffusion_reference(target)
    log_rate = safe_log_rate(target, BrownianMotion(), reference)
    check(restore.Restore(target.logdensity, BrownianMotion(), reference, log_rate=log_rate, bound=100.0), target, True)

    class BrownianWithoutAdjoint(BrownianMotion):
        is_invariant = True  # pretends L* p = 0

    # Without the adjoint any c_tilde > 0 keeps the rate positive; a small one gives long tours.
    wrong = restore.Restore(target.logdensity, BrownianWithoutAdjoint(), reference, log_rate=-1.0, bound=100.0)
    check(wrong, target, False)


def test_ornstein_uhlenbeck_restore_is_stationary():
    target = mixture_2d()
    dynamics = OrnsteinUhlenbeck(target.mean, 1.0, 1.0)
    reference = diffusion_reference(target)
    log_rate = safe_log_rate(target, dynamics, reference)
    check(restore.Restore(target.logdensity, dynamics, reference, log_rate=log_rate, bound=200.0), target, True)


def test_langevin_restore_is_stationary():
    """Overdamped Langevin is pi-invariant (its Euler simulation is approximate: small steps)."""
    target = mixture_2d()
    reference = diffusion_reference(target)
    process = restore.Restore(target.logdensity, OverdampedLangevin(1.0, step_size=0.01), reference, tour_length=1.0, bound=60.0)
    check(process.calibrate(jax.random.key(0))[0], target, True)


def test_generic_diffusion_restore_is_stationary():
    """A drift towards the mean with an anisotropic diffusion matrix; `L* p / p` by autodiff."""
    target = mixture_2d()
    dynamics = Diffusion(lambda x: -0.5 * (x - target.mean), jnp.array([[1.0, 0.3], [0.3, 0.6]]), step_size=0.01)
    reference = diffusion_reference(target)
    log_rate = safe_log_rate(target, dynamics, reference)
    check(restore.Restore(target.logdensity, dynamics, reference, log_rate=log_rate, bound=100.0), target, True)


def test_unadjusted_jump_restore_with_its_adjoint_is_stationary():
    """An always-accepted random walk (not pi-invariant) corrected by its closed-form adjoint."""
    target = mixture_2d()
    dynamics = UnadjustedJump(0.7, target.smoothed(0.49).logdensity)
    reference = Gaussian(target.mean, 2.0 * target.covariance)
    log_rate = safe_log_rate(target, dynamics, reference)
    check(restore.Restore(target.logdensity, dynamics, reference, log_rate=log_rate), target, True)


# --------------------------------------------------------------------------- exit-dependent transfers


class PaperRateTransfer(AbstractTransfer):
    """Negative control: the autoregressive kernel, killed at `c mu* p / p` (the rate that holds for
    independent transfers) instead of `c q / p`. `mu* p` is the closed-form Gaussian mixture."""

    kernel: AutoregressiveGaussian
    reference: AbstractRegeneration

    def __init__(self, kernel, target):
        rho, m = kernel.correlation, kernel.mean
        cov = kernel.reference.cov if hasattr(kernel.reference, "cov") else kernel.scale_tril @ kernel.scale_tril.T
        parts = [
            Gaussian(m + rho * (mu - m), rho**2 * c + (1 - rho**2) * cov) for mu, c in zip(target.means, target.covariances)
        ]
        self.kernel, self.reference = kernel, Mixture(parts, target.weights)

    def sample(self, key, exit_position):
        return self.kernel.sample(key, exit_position)


def exit_dependent_setup():
    target = mixture_2d()
    kernel = AutoregressiveGaussian(target.mean, 3.0 * target.covariance, 0.9)
    return target, kernel


def test_exit_dependent_transfer_is_stationary_and_the_mu_star_rate_is_not():
    target, kernel = exit_dependent_setup()
    # Short tours (large c_tilde) and a strongly exit-dependent kernel: many transfers by time 4.
    process = restore.Restore(target.logdensity, Jump(RandomWalk(0.8)), kernel, log_rate=2.0)
    assert not process.is_regenerative
    check(process, target, True, time=4.0)
    wrong = restore.Restore(target.logdensity, Jump(RandomWalk(0.8)), PaperRateTransfer(kernel, target), log_rate=2.0)
    check(wrong, target, False, time=4.0)


def test_metropolis_transfer_is_stationary():
    target = mixture_2d()
    transfer = MetropolisTransfer(Gaussian(target.mean, 2.0 * target.covariance), 1.0, num_steps=3)
    process = restore.Restore(target.logdensity, Jump(RandomWalk(0.8)), transfer, tour_length=1.0).calibrate(jax.random.key(0))[0]
    check(process, target, True, time=4.0)


REPLICATIONS, LANES_PER_REPLICATION = 80, 25


def calibrated(z):
    """z-scores of independent replications whose spread is that of a unit normal: the
    standard deviation within 0.75-1.4 (each z is about Student-t with 24 degrees of freedom,
    standard deviation 1.04; over 80 replications the sample one varies by about 0.08)
    and none beyond 4.5."""
    return bool(0.75 < np.std(z) < 1.4 and np.all(np.abs(z) < 4.5))


def test_dependent_tours_give_lane_based_errors_that_are_calibrated():
    """Tours are dependent: estimates default to lanes (independent replicates), whose
    z-scores over replications are standard normal."""
    target, kernel = exit_dependent_setup()
    process = restore.Restore(target.logdensity, Jump(RandomWalk(0.8)), kernel, tour_length=2.0)
    result = restore.sample(
        process, jax.random.key(5), num_lanes=REPLICATIONS * LANES_PER_REPLICATION, num_steps=1500, progress=False, save=restore.SaveDraws(0),
        observables={"x": lambda x: x, "mode": lambda x: (target.assign_mode(x) == 1).astype(x.dtype)},
    )
    with pytest.raises(ValueError, match="use method='lanes'"):
        result.estimate("x", method="tours")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", restore.UnreliableEstimateWarning)  # k_hat from 25 lanes is rough
        z = np.array([
            float(result.estimate("mode", lanes=slice(LANES_PER_REPLICATION * r, LANES_PER_REPLICATION * (r + 1))).z_score(float(target.weights[1])))
            for r in range(REPLICATIONS)
        ])  # fmt: skip
    assert calibrated(z), (np.std(z), np.abs(z).max())
    assert not calibrated(1.7 * z), np.std(1.7 * z)  # standard errors 1.7 times too small fail
    pooled = result.estimate("x").z_score(np.asarray(target.mean))
    assert np.all(np.abs(pooled) < 4), pooled
    log_z = result.normalising_constant("tours")
    assert abs(float(log_z.value)) < 4 * float(log_z.standard_error)  # the mixture is normalised


# --------------------------------------------------------------------------- schedules


class StationaryPhase(restore.AbstractSampler):
    """Starts each lane in a random phase with probabilities proportional to `1 / c_k`: with
    `X_0 ~ pi` independent of it, that is the stationary law of (state, phase)."""

    process: restore.Restore
    has_tours: ClassVar[bool] = True

    @property
    def dim(self):
        return self.process.dim

    @property
    def dtype(self):
        return self.process.dtype

    def init(self, key, position=None):
        k_phase, k_init = jax.random.split(key)
        weights = -jnp.asarray(self.process.log_rate)
        phase = jax.random.categorical(k_phase, weights)
        return self.process.init(k_init, position, phase)

    def step(self, key, state):
        return self.process.step(key, state)

    def advance_position(self, key, state, duration):
        return self.process.advance_position(key, state, duration)


class SwappedReference(AbstractTransfer):
    """Negative control: samples from one regeneration, reports another as its reference."""

    source: AbstractRegeneration
    reference: AbstractRegeneration

    def sample(self, key, exit_position):
        return self.source.sample(key).astype(exit_position.dtype)


def test_cycled_schedule_is_stationary_and_the_wrong_reference_is_not():
    """Two phases with their own kernels, regenerations and tour lengths; each tour's rate uses
    the regeneration that started it. Using the one that will start the next tour fails."""
    target = mixture_2d()
    wide = Gaussian(target.mean, 3.0 * target.covariance)
    narrow = Mixture([Gaussian(m, c) for m, c in zip(target.means, target.covariances)])
    dynamics = (Jump(RandomWalk(0.8)), Jump(MALA(0.6)))
    process = restore.Restore(target.logdensity, dynamics, (Independent(wide), Independent(narrow)), log_rate=(0.0, -1.0))
    assert process.num_phases == 2 and process.is_regenerative
    check(StationaryPhase(process), target, True, time=4.0)
    swapped = (SwappedReference(wide, narrow), SwappedReference(narrow, wide))
    wrong = restore.Restore(target.logdensity, dynamics, swapped, log_rate=(0.0, -1.0))
    check(StationaryPhase(wrong), target, False, time=4.0)


# --------------------------------------------------------------------------- the layer itself


def test_jump_restore_is_the_general_process_with_one_phase():
    target = mixture_2d()
    nu = Gaussian(target.mean, 2.0 * target.covariance)
    jump = restore.JumpRestore(target.logdensity, RandomWalk(0.8), nu, log_rate=0.3)
    general = restore.Restore(target.logdensity, Jump(RandomWalk(0.8)), Independent(nu), log_rate=0.3)
    assert isinstance(jump, restore.AbstractRestore)
    keys = jax.random.split(jax.random.key(0), 50)

    def run(sampler):
        state = sampler.init(jax.random.key(1))
        out = []
        for k in keys:
            state, _ = sampler.step(k, state)
            out.append(np.asarray(state.position))
        return np.array(out)

    np.testing.assert_array_equal(run(jump), run(general))


def test_bad_general_processes_are_rejected():
    target = mixture_2d()
    nu = Gaussian(target.mean, 2.0 * target.covariance)
    with pytest.raises(ValueError, match="bound"):
        restore.Restore(target.logdensity, BrownianMotion(), nu, log_rate=0.0)
    with pytest.raises(ValueError, match="exit point"):
        restore.Restore(target.logdensity, BrownianMotion(), AutoregressiveGaussian(target.mean, jnp.eye(2), 0.5), log_rate=0.0, bound=10.0)
    with pytest.raises(ValueError, match="same kind"):
        restore.Restore(target.logdensity, (BrownianMotion(), Jump(RandomWalk(0.5))), nu, log_rate=0.0, bound=10.0)
    with pytest.raises(ValueError, match="phases"):
        restore.Restore(target.logdensity, (Jump(RandomWalk(0.5)),) * 2, (Independent(nu),) * 3, log_rate=0.0)
    with pytest.raises(ValueError, match="one value per phase"):
        restore.Restore(target.logdensity, (Jump(RandomWalk(0.5)),) * 2, nu, log_rate=(0.0, 1.0, 2.0))
    with pytest.raises(TypeError, match="restore.dynamics"):
        restore.Restore(target.logdensity, RandomWalk(0.5), nu, log_rate=0.0)
    process = restore.Restore(target.logdensity, BrownianMotion(), nu, log_rate=0.0, bound=10.0)
    with pytest.raises(ValueError, match="rao_blackwell"):
        restore.sample(process, jax.random.key(0), num_lanes=2, num_steps=2, weights="time", progress=False)


def test_kill_rate_and_a_searched_bound():
    """`kill_rate` is the Brownian closed form; `rate_bound` over a box finds its maximum there."""
    process = restore.Restore(gaussian_logdensity, BrownianMotion(), Gaussian(jnp.zeros(2), jnp.eye(2)), log_rate=2.07, bound=1.0)
    x = jnp.array([0.7, -0.4])
    grad = -PRECISION @ x
    expected = 0.5 * (grad @ grad - jnp.trace(PRECISION)) + np.exp(2.07) * np.exp(-0.5 * x @ x) / (2 * np.pi) / np.exp(gaussian_logdensity(x))
    np.testing.assert_allclose(float(process.kill_rate(x)), float(expected), rtol=1e-10)
    found = restore.rate_bound(process.kill_rate, -jnp.ones(2), jnp.ones(2), key=jax.random.key(0), safety=1.0)
    grid = jnp.stack(jnp.meshgrid(jnp.linspace(-1, 1, 81), jnp.linspace(-1, 1, 81)), -1).reshape(-1, 2)
    assert float(found.bound) >= float(jnp.max(jax.vmap(process.kill_rate)(grid))) * (1 - 1e-6)


def test_too_small_a_constant_is_reported():
    """Brownian Restore with `c_tilde` far below the safe value: negative rates are counted and warned about."""
    process = restore.Restore(gaussian_logdensity, BrownianMotion(), Gaussian(jnp.zeros(2), jnp.eye(2)), log_rate=0.0, bound=100.0)
    with pytest.warns(RuntimeWarning, match="negative"):
        result = restore.sample(process, jax.random.key(0), num_lanes=16, num_steps=200, progress=False, save=restore.SaveDraws(0))
    assert result.num_negative_rate > 0


def test_z_from_tours_with_a_phase_rule_that_does_not_cycle():
    """One tour in four uses phase 1: the tours' own constants give `Z`, not the cycle's mean."""
    logdensity = lambda x: -0.5 * jnp.sum(x**2)  # Z = 2 pi
    process = restore.Restore(
        logdensity, Jump(RandomWalk(1.0)), (Gaussian(jnp.zeros(2), 2.0), Gaussian(jnp.zeros(2), 1.5)),
        log_rate=(0.0, 2.0), phase_rule=lambda i: (i % 4 == 0).astype(jnp.int32),
    )  # fmt: skip
    assert process.phase_of_tour(jnp.arange(6)).tolist() == [0, 0, 0, 0, 1, 0]
    result = restore.sample(process, jax.random.key(0), num_lanes=64, num_steps=1000, progress=False, save=restore.SaveDraws(0))
    log_z = result.normalising_constant("tours")
    assert abs(float(log_z.z_score(np.log(2 * np.pi)))) < 4, log_z
    stats = result.tour_statistics()
    assert abs(stats.mean_duration - stats.expected_duration) < 4 * stats.mean_duration_se, stats
    # About 3/4 of the tours have c_tilde = 1 and 1/4 have c_tilde = e^2, harmonically averaged.
    assert abs(result.tour_log_rate - np.log(1 / (0.75 + 0.25 * np.exp(-2.0)))) < 0.02
