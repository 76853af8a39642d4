"""The run driver and its result: estimates, draws, diagnostics, reproducibility."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import restore
from restore.local import RandomWalk
from restore.regeneration import Gaussian


def std_normal(x):
    return -0.5 * jnp.sum(x**2)


@pytest.fixture(scope="module")
def run():
    sampler = restore.JumpRestore(std_normal, RandomWalk(1.0), Gaussian(jnp.zeros(2), 2.0), tour_length=2.0)
    return restore.sample(sampler, jax.random.key(0), num_lanes=128, num_steps=800, progress=False, save=restore.SaveDraws(20_000))


def test_estimates_against_the_truth(run):
    for name, truth in (("x", 0.0), ("x**2", 1.0)):
        est = run.estimate(name)
        assert est.value.shape == (2,)
        assert np.all(np.abs(est.z_score(truth)) < 4.5)
        lanes = run.estimate(name, method="lanes")
        assert np.all(np.abs(lanes.z_score(truth)) < 4.5)
    log_z = np.log(2 * np.pi)
    for method in ("tours", "importance"):
        est = run.normalising_constant(method)
        assert abs(float(est.z_score(log_z))) < 4.5, method
    ess = run.ess("x")
    assert np.all(ess > 1000) and np.all(ess < 128 * 800)


def test_draws_arviz_and_summary(run):
    assert run.draws.shape[1:] == (128, 2) and run.draws.shape[0] * 128 <= 20_000
    est = run.estimate_draws(lambda x: x**2)
    assert np.all(np.abs(est.z_score(1.0)) < 4.5)
    idata = run.to_arviz()
    assert idata.posterior["x"].shape[:2] == (4, 32 * run.draws.shape[0])
    text = run.summary()
    assert "tours" in text and "log Z" in text
    stats = run.tour_statistics()
    assert stats.num_tours > 1000 and not stats.heavy_tailed


def test_same_key_same_result_and_lanes_do_not_depend_on_the_lane_count():
    sampler = restore.JumpRestore(std_normal, RandomWalk(1.0), Gaussian(jnp.zeros(2), 2.0), log_rate=0.0)
    a = restore.sample(sampler, jax.random.key(5), num_lanes=8, num_steps=200, progress=False, num_chunks=3)
    b = restore.sample(sampler, jax.random.key(5), num_lanes=8, num_steps=200, progress=False, num_chunks=7)
    c = restore.sample(sampler, jax.random.key(5), num_lanes=4, num_steps=200, progress=False)
    np.testing.assert_allclose(a.sums.sum_f, b.sums.sum_f, rtol=1e-13)  # chunk totals added in another order
    np.testing.assert_array_equal(a.draws, b.draws)
    np.testing.assert_array_equal(a.draws[:, :4], c.draws)


def test_heavy_tailed_tours_are_flagged():
    """A regeneration far wider than the target: most tours die at once, a few live long."""
    sampler = restore.JumpRestore(std_normal, RandomWalk(0.5), Gaussian(jnp.zeros(2), 400.0), tour_length=1.0)
    with pytest.warns(RuntimeWarning, match="tour-based estimates and their standard errors cannot be trusted"):
        result = restore.sample(sampler, jax.random.key(1), num_lanes=64, num_steps=500, progress=False)
    assert result.tour_statistics().heavy_tailed


def test_mh_results_use_lanes_and_refuse_tours():
    mh = restore.MixtureMH(std_normal, RandomWalk(1.0), Gaussian(jnp.zeros(2), 2.0), 0.1)
    result = restore.sample(mh, jax.random.key(2), num_lanes=64, num_steps=300, progress=False)
    assert np.all(np.abs(result.estimate("x").z_score(0.0)) < 4.5)
    with pytest.raises(ValueError, match="method='lanes'"):
        result.estimate("x", method="tours")
    with pytest.raises(KeyError, match="no observable named"):
        result.estimate("y")


def test_the_position_stays_available_with_custom_observables():
    sampler = restore.JumpRestore(std_normal, RandomWalk(1.0), Gaussian(jnp.zeros(2), 2.0), log_rate=0.0)
    kwargs = dict(num_lanes=16, num_steps=300, progress=False)
    norm = lambda x: jnp.sum(x**2)
    result = restore.sample(sampler, jax.random.key(3), observables={"norm": norm}, **kwargs)
    assert [slot.name for slot in result.observables.slots] == ["norm", "x"]
    assert result.estimate("x").value.shape == (2,) and np.all(np.abs(result.estimate("x").z_score(0.0)) < 4.5)
    assert abs(float(result.estimate("norm").z_score(2.0))) < 4.5
    # A mapping that defines "x" itself keeps its own.
    own = restore.sample(sampler, jax.random.key(3), observables={"x": norm}, **kwargs)
    assert [slot.name for slot in own.observables.slots] == ["x"] and own.estimate("x").value.shape == ()
    np.testing.assert_array_equal(own.estimate("x").value, result.estimate("norm").value)


def test_draw_rows_shares_one_program_between_runs_of_other_lengths_and_changes_nothing():
    sampler = restore.JumpRestore(std_normal, RandomWalk(1.0), Gaussian(jnp.zeros(2), 2.0), tour_length=2.0)
    sampler = sampler.calibrated_to(jnp.log(2 * jnp.pi))
    traced = []

    def listen(event, duration, **kwargs):
        if event.endswith("jaxpr_trace_duration"):
            traced.append(kwargs.get("fun_name"))

    def run(num_steps, **kwargs):
        return restore.sample(sampler, jax.random.key(3), num_lanes=16, num_steps=num_steps, progress=False, **kwargs)

    plain = run(40)
    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        short, long = run(40, save=restore.SaveDraws(rows=128)), run(120, save=restore.SaveDraws(rows=128))
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
    assert traced.count("advance") == 1  # the 40-step and the 120-step runs share the loop program
    assert short.draws.shape == plain.draws.shape == (40, 16, 2) and long.draws.shape == (120, 16, 2)
    np.testing.assert_array_equal(short.draws, plain.draws)
    np.testing.assert_array_equal(short.estimate("x").value, plain.estimate("x").value)
    with pytest.raises(ValueError, match="fewer than the 120 draws"):
        run(120, save=restore.SaveDraws(rows=64))


def test_calibrated_to_sets_the_rate_from_a_known_log_z_and_keeps_the_tour_length():
    sampler = restore.JumpRestore(std_normal, RandomWalk(1.0), Gaussian(jnp.zeros(2), 2.0), tour_length=2.0)
    calibrated = sampler.calibrated_to(1.5)
    assert calibrated.tour_length == (2.0,) and float(calibrated.log_rate) == pytest.approx(1.5 - np.log(2.0))
    piloted, pilot = sampler.calibrate(jax.random.key(0))
    assert float(piloted.log_rate) == float(sampler.calibrated_to(pilot.log_z).log_rate)
    with pytest.raises(ValueError, match="calibrated already"):
        calibrated.calibrated_to(1.0)
    with pytest.raises(ValueError, match="needs a sampler given a tour_length"):
        restore.JumpRestore(std_normal, RandomWalk(1.0), Gaussian(jnp.zeros(2), 2.0), log_rate=0.0).calibrated_to(1.0)


def test_the_tours_that_outlast_the_budget_are_finished_in_a_narrow_batch(monkeypatch):
    """A lane may take up to `restore._run_loop.NARROW_FINISHING_STEPS` times the budget's steps to end
    its open tour. Below `NARROW_FINISH_LANES` lanes every lane steps first, for the budget's steps, and
    the tours still open go to the narrow batch, where a long tour holds one slot. In a 20-step run a
    fifth of the open tours outlast 20 more steps: capped there (`finish_tours=20`), they are left open
    and `log Z` is off by 6 standard errors, flagged unreliable (the negative control); by default every
    tour ends and `log Z` is right, with the same tours, and the same per-lane sums, as a run that
    finishes in the narrow batch alone (lane `i`'s `j`-th finishing step has one key in both)."""
    sampler = restore.JumpRestore(std_normal, RandomWalk(0.75), Gaussian(jnp.zeros(2), 2.25 * jnp.eye(2)), tour_length=10.0)
    kwargs = dict(num_lanes=256, num_steps=20, progress=False, save=restore.SaveDraws(0))
    log_z = np.log(2 * np.pi)
    with pytest.warns(RuntimeWarning, match="still had an open tour after 20 extra steps"):
        capped = restore.sample(sampler, jax.random.key(0), finish_tours=20, **kwargs)
    assert capped.unfinished_tours > 20 and capped.finishing_steps == 20
    with pytest.warns(restore.UnreliableEstimateWarning):
        estimate = capped.normalising_constant()
    assert not estimate.reliable and abs(float(estimate.z_score(log_z))) > 4
    handed = restore.sample(sampler, jax.random.key(0), **kwargs)
    assert handed.unfinished_tours == 0 and 20 < handed.finishing_steps <= 200
    estimate = handed.normalising_constant()
    assert estimate.reliable and abs(float(estimate.z_score(log_z))) < 3
    monkeypatch.setattr("restore._run_loop.NARROW_FINISH_LANES", 1)  # 256 lanes finish 8 at a time from the start
    narrow = restore.sample(sampler, jax.random.key(0), **kwargs)
    assert narrow.finishing_steps == handed.finishing_steps and narrow.unfinished_tours == 0
    for field in ("num_tours", "max_tour", "open_steps", "sum_f", "sum_t", "sum_t2"):
        np.testing.assert_array_equal(getattr(narrow.sums, field), getattr(handed.sums, field), err_msg=field)
    np.testing.assert_allclose(narrow.sums.all_t, handed.sums.all_t, rtol=1e-12)  # summed in another order
    with pytest.raises(ValueError, match="finish_tours"):
        restore.sample(sampler, jax.random.key(0), finish_tours=0, **kwargs)


def test_dropped_open_tours_mark_the_tour_based_estimates():
    """`finish_tours=False` leaves the tours open at the budget's end out: in a 20-step run that is most
    of the long ones, and `log Z` comes out 17 standard errors low. The result says so (`tours_dropped`,
    every open tour counted as unfinished) and marks the tour-based estimates unreliable, with a warning
    that names the cause; the same run with its tours finished is right and reliable (the control)."""
    sampler = restore.JumpRestore(std_normal, RandomWalk(0.75), Gaussian(jnp.zeros(2), 2.25 * jnp.eye(2)), tour_length=10.0)
    kwargs = dict(num_lanes=256, num_steps=20, progress=False, save=restore.SaveDraws(0))
    log_z = np.log(2 * np.pi)
    with pytest.warns(restore.UnreliableEstimateWarning, match="left out; finish the open tours"):
        dropped = restore.sample(sampler, jax.random.key(0), finish_tours=False, **kwargs)
    assert dropped.tours_dropped and dropped.unfinished_tours > 200 and dropped.tour_statistics().heavy_tailed
    with pytest.warns(restore.UnreliableEstimateWarning, match=r"dropped \(finish_tours=False\)"):
        estimate = dropped.normalising_constant()
    assert not estimate.reliable and float(estimate.z_score(log_z)) < -10
    finished = restore.sample(sampler, jax.random.key(0), **kwargs)
    assert not finished.tours_dropped and finished.unfinished_tours == 0
    estimate = finished.normalising_constant()
    assert estimate.reliable and abs(float(estimate.z_score(log_z))) < 3


def test_narrow_finishing_in_calls_of_any_length_gives_the_same_bits_and_ctrl_c_keeps_the_budget(monkeypatch):
    """The narrow batch finishes in calls of `FINISHING_CALL` steps (a progress bar and Ctrl-C
    between them); a lane's sums join the totals once, after the last call, so calls of 3 steps
    give the same bits as calls of 128. Ctrl-C during the finishing returns the budget's result
    (the open tours dropped, as `finish_tours=False` does), marked interrupted."""
    sampler = restore.JumpRestore(std_normal, RandomWalk(0.75), Gaussian(jnp.zeros(2), 2.25 * jnp.eye(2)), tour_length=10.0)
    kwargs = dict(num_lanes=256, num_steps=20, progress=False, save=restore.SaveDraws(0))
    monkeypatch.setattr("restore._run_loop.NARROW_FINISH_LANES", 1)
    whole = restore.sample(sampler, jax.random.key(0), **kwargs)
    monkeypatch.setattr("restore._run.FINISHING_CALL", 3)
    calls = []
    finish = restore._run.finish
    monkeypatch.setattr("restore._run.finish", lambda *args: calls.append(1) or finish(*args))
    pieces = restore.sample(sampler, jax.random.key(0), **kwargs)
    assert len(calls) > 10 and pieces.finishing_steps == whole.finishing_steps > 20
    for field in whole.sums._fields:
        np.testing.assert_array_equal(getattr(pieces.sums, field), getattr(whole.sums, field), err_msg=field)
    assert pieces.sums.num_tours.sum() > restore.sample(sampler, jax.random.key(0), finish_tours=False, **kwargs).sums.num_tours.sum()

    def interrupted(*args):
        if len(calls) == 3:
            raise KeyboardInterrupt
        calls.append(1)
        return finish(*args)

    calls.clear()
    monkeypatch.setattr("restore._run.finish", interrupted)
    with pytest.warns(UserWarning, match="interrupted while finishing"):
        stopped = restore.sample(sampler, jax.random.key(0), **kwargs)
    dropped = restore.sample(sampler, jax.random.key(0), finish_tours=False, **kwargs)
    assert stopped.interrupted and stopped.finishing_steps == 0 and stopped.tours_dropped
    with pytest.warns(restore.UnreliableEstimateWarning, match="the run was interrupted"):
        assert not stopped.normalising_constant().reliable
    for field in dropped.sums._fields:
        np.testing.assert_array_equal(getattr(stopped.sums, field), getattr(dropped.sums, field), err_msg=field)
