"""Checks 2 and 3 of the validation protocol: ergodicity and calibrated standard errors."""

import jax
import numpy as np

import restore
from restore.local import MALA, RandomWalk
from restore.testing import calibration_test, ergodicity_test
from tests._models import (
    UnadjustedRandomWalk,
    banana,
    broad_regeneration,
    laplace_regeneration,
    mixture_2d,
    mixture_10d,
    mode_indicator,
    second_moments,
)

LOG_Z = 2.5  # the samplers see the target times e^2.5, so Z is known but not 1


def _unnormalised(target):
    return lambda x: target.logdensity(x) + LOG_Z


def test_mode_weights_moments_tour_length_and_z_on_a_10d_mixture():
    target = mixture_10d()
    sampler = restore.JumpRestore(_unnormalised(target), RandomWalk(0.6), laplace_regeneration(target), tour_length=5.0)
    truths = {
        "modes": (mode_indicator(target), target.weights),
        "x": (lambda x: x[:3], target.mean[:3]),
        "x**2": (lambda x: x[:3] ** 2, second_moments(target)[:3]),
    }
    report = ergodicity_test(sampler, jax.random.key(31), truths, num_lanes=512, num_steps=1500, log_z=LOG_Z)
    assert report.passed, (str(report), report.p_values)
    stats = report.details["result"].tour_statistics()
    assert abs(stats.mean_duration - 5.0) < 5 * stats.mean_duration_se + 0.05 * 5.0  # pilot Z is itself an estimate
    assert not stats.heavy_tailed


def test_banana_with_mala_and_time_weights():
    target = banana()
    sampler = restore.JumpRestore(_unnormalised(target), MALA(0.3), broad_regeneration(target), tour_length=3.0)
    truths = {"x": (lambda x: x, target.mean), "x**2": (lambda x: x**2, second_moments(target))}
    report = ergodicity_test(sampler, jax.random.key(32), truths, num_lanes=512, num_steps=1500, log_z=LOG_Z, weights="time")
    assert report.passed, (str(report), report.p_values)


def test_a_kernel_that_does_not_leave_the_target_invariant_fails_ergodicity():
    """Negative control: a random walk that accepts every move biases moments and mode weights."""
    target = mixture_2d()
    sampler = restore.JumpRestore(_unnormalised(target), UnadjustedRandomWalk(1.2), laplace_regeneration(target), tour_length=2.0)
    truths = {
        "modes": (mode_indicator(target), target.weights),
        "x": (lambda x: x, target.mean),
        "x**2": (lambda x: x**2, second_moments(target)),
    }
    report = ergodicity_test(sampler, jax.random.key(36), truths, num_lanes=256, num_steps=1000, log_z=LOG_Z)
    assert not report.passed, (str(report), report.p_values)


def test_erratum_c_read_as_the_expected_lifetime_fails_the_tour_length_check():
    """Seed erratum: c is the kill *rate*; taking it as the mean lifetime gives tours of length 1/T, not T."""
    target = mixture_2d()
    nu = laplace_regeneration(target)
    tour_length = 4.0
    wrong = restore.JumpRestore(_unnormalised(target), RandomWalk(1.0), nu, log_rate=LOG_Z + np.log(tour_length))
    result = restore.sample(wrong, jax.random.key(33), num_lanes=256, num_steps=500, progress=False)
    stats = result.tour_statistics()
    assert abs(stats.mean_duration - tour_length) / stats.mean_duration_se > 50


def test_standard_errors_are_calibrated_over_replications():
    target = mixture_2d()
    sampler = restore.JumpRestore(_unnormalised(target), RandomWalk(1.2), laplace_regeneration(target), tour_length=2.0)
    truths = {
        "x0": (lambda x: x[0], float(target.mean[0])),
        "mode 1": (lambda x: (target.assign_mode(x) == 1).astype(x.dtype), float(target.weights[1])),
    }
    report = calibration_test(sampler, jax.random.key(34), truths, num_replications=200, lanes_per_replication=8, num_steps=1000)
    assert report.passed, (str(report), {k: v for k, v in report.details.items() if "coverage" in k})


def test_miscalibrated_standard_errors_fail_calibration():
    """Negative control: lanes treated as replicates of a too-short MH run understate the error."""
    target = mixture_10d()
    mh = restore.MixtureMH(_unnormalised(target), RandomWalk(0.6), laplace_regeneration(target), 0.01)
    truths = {"mode 2": (lambda x: (target.assign_mode(x) == 2).astype(x.dtype), float(target.weights[2]))}
    report = calibration_test(mh, jax.random.key(35), truths, num_replications=100, lanes_per_replication=4, num_steps=60)
    assert not report.passed
