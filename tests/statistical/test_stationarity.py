"""Check 1 of the validation protocol: fixed-time stationarity, with negative controls that fail it."""

import blackjax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import restore
from restore.dynamics import BrownianMotion
from restore.local import (
    HMC,
    MALA,
    BlackJAXKernel,
    CorrelatedRandomWalk,
    GuidedRandomWalk,
    RandomWalk,
    metropolis_accept,
)
from restore.regeneration import Gaussian
from restore.testing import stationarity_test
from tests._models import (
    RateDistortion,
    UnadjustedRandomWalk,
    banana,
    broad_regeneration,
    jump_restore,
    laplace_regeneration,
    mixture_2d,
    mixture_10d,
)

ALPHA = 1e-3  # family-wise level of each check; negative controls fail far beyond it


def _check(sampler, target, key, time=4.0, num_lanes=20_000):
    mixture = hasattr(target, "assign_mode")
    return stationarity_test(
        sampler,
        key,
        target.sample,
        num_lanes=num_lanes,
        time=time,
        assign_mode=target.assign_mode if mixture else None,
        mode_weights=target.weights if mixture else None,
        alpha=ALPHA,
    )


LOCALS = {
    "rw": lambda d: RandomWalk(2.0 / np.sqrt(d)),
    "mala": lambda d: MALA(0.6 / d**0.33),
    "hmc": lambda d: HMC(0.4, 4),
    "correlated_rw": lambda d: CorrelatedRandomWalk(_correlated_factor(d)),
    "guided_rw": lambda d: _guided_walk(d),
}


def _guided_walk(d: int, scales=(0.3, 1.0, 3.0), kind: type[GuidedRandomWalk] = GuidedRandomWalk) -> GuidedRandomWalk:
    """A guide of three components whose scales differ tenfold (one correlated), centred at -2, 0
    and 2 on the diagonal: steps that change with the position, so the reverse density matters."""
    trils = np.stack([scales[0] * np.eye(d), scales[1] * _correlated_factor(d) * np.sqrt(d) / 2.0, scales[2] * np.eye(d)])
    means = np.stack([-2.0 * np.ones(d), np.zeros(d), 2.0 * np.ones(d)])
    return kind(np.log(np.ones(3) / 3), means, trils, 2.0 / np.sqrt(d))


def _correlated_factor(d: int) -> np.ndarray:
    """`2 / sqrt(d)` times the Cholesky factor of a correlation matrix with 0.6 off the diagonal."""
    return 2.0 / np.sqrt(d) * np.linalg.cholesky(0.4 * np.eye(d) + 0.6 * np.ones((d, d)))


@pytest.mark.parametrize("kernel", LOCALS)
@pytest.mark.parametrize("case", ["mixture_2d", "banana", "mixture_10d"])
def test_jump_restore_keeps_the_target_at_a_fixed_time(kernel, case):
    target = {"mixture_2d": mixture_2d, "banana": banana, "mixture_10d": mixture_10d}[case]()
    nu = broad_regeneration(target) if case == "banana" else laplace_regeneration(target)
    sampler = jump_restore(target, LOCALS[kernel](target.dim), nu, tour_length=1.0)
    report = _check(sampler, target, jax.random.key(11))
    assert report.passed, str(report)


def test_blackjax_kernel_as_local_dynamics_keeps_the_target():
    target = mixture_2d()
    local = BlackJAXKernel(lambda logp: blackjax.mala(logp, step_size=0.3), uses_gradient=True)
    sampler = jump_restore(target, local, laplace_regeneration(target))
    report = _check(sampler, target, jax.random.key(12))
    assert report.passed, str(report)


def test_mixture_mh_baseline_keeps_the_target():
    target = mixture_10d()
    sampler = restore.MixtureMH(target.logdensity, RandomWalk(0.6), laplace_regeneration(target), 0.2)
    report = _check(sampler, target, jax.random.key(13), time=10.0)  # holding times are 1: 10 steps
    assert report.passed, str(report)


# ---------------------------------------------------------------- negative controls


def test_constant_killing_rate_fails():
    target = mixture_10d()
    nu = laplace_regeneration(target)
    wrong = RateDistortion(nu, target.logdensity, power=1.0)  # gamma = c_tilde, constant
    sampler = restore.JumpRestore(target.logdensity, RandomWalk(0.6), wrong, log_rate=0.0)
    report = _check(sampler, target, jax.random.key(21), num_lanes=5000)
    assert not report.passed and report.min_p_value < 1e-10, str(report)


def test_kill_rate_with_a_state_dependent_scaling_fails():
    target = mixture_2d()
    nu = laplace_regeneration(target)
    wrong = RateDistortion(nu, target.logdensity, power=0.5)  # gamma = c sqrt(u / p)
    sampler = restore.JumpRestore(target.logdensity, RandomWalk(1.0), wrong, log_rate=0.0)
    report = _check(sampler, target, jax.random.key(22), num_lanes=5000)
    assert not report.passed and report.min_p_value < 1e-10, str(report)


def test_non_invariant_local_kernel_presented_as_invariant_fails():
    target = mixture_2d()
    sampler = jump_restore(target, UnadjustedRandomWalk(1.0), laplace_regeneration(target), tour_length=5.0)
    report = _check(sampler, target, jax.random.key(23), num_lanes=5000)
    assert not report.passed and report.min_p_value < 1e-10, str(report)


class DriftingCorrelatedWalk(CorrelatedRandomWalk):
    """Negative control: a correlated walk with a drift along its first axis, accepted by Metropolis's
    symmetric test (the reverse proposal's density left out)."""

    def propose(self, key, point, logdensity_fn):
        y, aux = super().propose(key, point, logdensity_fn)
        return y + 0.3 * self.scale_tril[:, 0], aux


def test_a_correlated_walk_with_an_asymmetric_proposal_fails():
    target = mixture_2d()
    sampler = jump_restore(target, DriftingCorrelatedWalk(_correlated_factor(2)), laplace_regeneration(target), tour_length=5.0)
    report = _check(sampler, target, jax.random.key(29), num_lanes=5000)
    assert not report.passed and report.min_p_value < 1e-10, str(report)


class SymmetricallyTestedGuidedWalk(GuidedRandomWalk):
    """Negative control: the guided walk accepted by Metropolis's symmetric test (the reverse
    proposal's density left out), which is wrong where the step size changes with the position."""

    def accept(self, key, point, candidate, aux):
        return metropolis_accept(key, point, candidate, candidate.logdensity - point.logdensity)


def test_a_guided_walk_without_the_reverse_density_fails():
    target = mixture_2d()
    wrong = _guided_walk(2, scales=(0.2, 1.0, 4.0), kind=SymmetricallyTestedGuidedWalk)
    sampler = jump_restore(target, wrong, laplace_regeneration(target), tour_length=5.0)
    report = _check(sampler, target, jax.random.key(31), num_lanes=5000)
    assert not report.passed and report.min_p_value < 1e-10, str(report)


class PoweredAcceptance(RandomWalk):
    """Negative control: a Metropolis test with `(p'/p)^0.8`, which leaves `p^0.8` invariant instead of `p`."""

    def accept(self, key, point, candidate, aux):
        return metropolis_accept(key, point, candidate, 0.8 * (candidate.logdensity - point.logdensity))


def test_acceptance_with_a_power_of_the_ratio_fails_at_the_defaults():
    """A mild distortion that the projections alone miss: the log density's distribution shows it."""
    target = mixture_2d()
    sampler = jump_restore(target, PoweredAcceptance(1.0), broad_regeneration(target), tour_length=2.0)
    report = stationarity_test(sampler, jax.random.key(1), target.sample)
    assert not report.passed and report.min_p_value < 1e-8, str(report)
    assert min(report.p_values, key=report.p_values.get) == "KS log p"


def test_an_inexact_simulation_is_reported():
    """A thinning bound far below the kill rate: every violation is counted and a warning says so."""
    process = restore.Restore(
        lambda x: -0.5 * jnp.sum(x**2), BrownianMotion(), Gaussian(jnp.zeros(1), 4.0), log_rate=0.0, bound=0.5
    )
    sample = lambda key, n: jax.random.normal(key, (n, 1))
    with pytest.warns(RuntimeWarning, match="exceeded the thinning bound at [1-9]"):
        report = stationarity_test(process, jax.random.key(2), sample, num_lanes=500, time=1.0)
    assert 0 < report.details["num_bound_exceeded"] <= report.details["num_steps"]
