"""Plots of a run: the numbers behind them agree with the result, and every plot draws.

The run samples a half-normal with a regeneration that puts half its tours where the
target is zero: those tours end at once with length zero, and must count among the
shortest in the tour-length distribution. Every plot takes the run as `restore.sample`
returns it and as `restore.autosample` wraps it (an `AutoResult`), and observables by name.
"""

import dataclasses
import subprocess
import sys
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

matplotlib = pytest.importorskip("matplotlib")
matplotlib.use("Agg")

import matplotlib.pyplot as plt

import restore
from restore import plot
from restore.local import RandomWalk
from restore.regeneration import Gaussian


def half_normal(x):
    return jnp.where(x[0] > 0, -0.5 * jnp.sum(x**2), -jnp.inf)


def sides(x):
    """One-hot: the state is at most 1, or above 1 (weights 0.683 and 0.317)."""
    return jnp.stack([x[0] <= 1.0, x[0] > 1.0]).astype(x.dtype)


@pytest.fixture(scope="module")
def run():
    sampler = restore.JumpRestore(
        half_normal,
        RandomWalk(1.0),
        Gaussian(jnp.zeros(1), 2.0),
        log_rate=np.log(0.5 * np.sqrt(2 * np.pi)) - np.log(4.0),
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return restore.sample(
            sampler, jax.random.key(0), num_lanes=32, num_steps=500, progress=False, num_chunks=10, save=restore.SaveDraws(32 * 100),
            observables={"x": lambda x: x, "sides": sides},
        )  # fmt: skip


@pytest.fixture(scope="module")
def auto(run):
    """The run as `restore.autosample` returns its final run."""
    return restore.AutoResult(run, None, None, (), 0, 0.0, True)


def test_the_tour_tail_is_the_runs(run):
    tail = plot.tour_tail(run)
    stats = run.tour_statistics()
    assert tail.num_tours == stats.num_tours and tail.k_hat == pytest.approx(stats.k_hat)
    assert tail.mean_duration == pytest.approx(stats.mean_duration)
    # The histogram's survival function agrees with the exact longest tours wherever both are known
    known = tail.edges >= tail.largest[-1]
    counted = np.array([np.sum(tail.largest >= edge) for edge in tail.edges[known]])
    np.testing.assert_allclose(tail.survival[known] * tail.num_tours, counted)
    # Half the tours start where the target is zero and last no time: the shortest, not of length 1
    assert tail.survival[np.searchsorted(tail.edges, 1e-3)] < 0.7
    above = tail.largest[tail.largest > tail.threshold]
    fitted = tail.fitted_survival(above)
    assert np.all(np.diff(fitted) >= 0) and fitted[-1] <= len(above) / tail.num_tours + 1e-12


def test_the_running_estimate_ends_at_the_draws_estimate(run):
    running = plot.running_estimate_values(run, lambda x: x[..., 0])
    final = run.estimate_draws(lambda x: x[..., 0])
    assert running.value[-1] == pytest.approx(float(final.value), rel=1e-12)
    assert running.standard_error[-1] == pytest.approx(float(final.standard_error), rel=1e-12)
    assert running.step[-1] == run.draws.shape[0] * run.thin and np.all(np.diff(running.step) > 0)
    assert abs(running.value[-1] - np.sqrt(2 / np.pi)) < 4 * running.standard_error[-1]


def test_the_trace_adds_up(run):
    trace = run.trace
    assert trace.step[-1] == 500 and np.sum(trace.lane_steps) == 32 * 500
    assert np.sum(trace.accepted) == np.sum(run.sums.num_accepted) or run.finishing_steps > 0
    assert np.sum(trace.accepted) <= np.sum(run.sums.num_accepted)
    rate = np.sum(trace.regenerations) / np.sum(trace.time)
    assert rate == pytest.approx(1 / run.tour_statistics().mean_duration, rel=0.15)
    assert np.all((trace.acceptance >= 0) & (trace.acceptance <= 1))


def test_every_plot_draws(run):
    ax = plot.tour_lengths(run)
    assert "k_hat" in ax.get_title()
    ax = plot.running_estimate(run, lambda x: x[..., 0], truth=np.sqrt(2 / np.pi), label="mean")
    assert len(ax.lines) == 2
    kill, accept = plot.traces(run)
    assert kill.get_title() == "kill rate" and len(accept.lines) == 2
    ax = plot.mode_weights(
        restore.Estimate(np.array([0.3, 0.7]), np.array([0.01, 0.02])),
        truth=[0.25, 0.75],
        others={"other": [0.5, 0.5]},
        labels=["a", "b"],
    )
    assert [t.get_text() for t in ax.get_xticklabels()] == ["a", "b"]
    plt.close("all")


def test_what_cannot_be_plotted(run):
    with pytest.raises(ValueError, match="weights"):
        plot.mode_weights(np.array([0.5, 0.5]), others={"other": [1.0, 0.0, 0.0]})
    no_trace = dataclasses.replace(run, trace=None)
    with pytest.raises(ValueError, match="trace"):
        plot.traces(no_trace)


def test_matplotlib_is_needed_only_for_figures():
    code = (
        "import sys\n"
        "import restore, restore.plot, restore.render, restore.bench, targets\n"
        "print('matplotlib' in sys.modules)\n"
        "sys.modules['matplotlib'] = None  # as if it were not installed\n"
        "try:\n"
        "    restore.plot.mode_weights([0.5, 0.5])\n"
        "except ImportError as err:\n"
        "    print(err)\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        cwd=Path(__file__).resolve().parents[2],
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    imported, message = done.stdout.strip().splitlines()
    assert imported == "False" and "restore-mcmc[plot]" in message


def test_every_plot_takes_an_autosample_result(run, auto):
    for mine, its in zip(plot.tour_tail(auto), plot.tour_tail(run)):
        np.testing.assert_array_equal(mine, its)
    assert "k_hat" in plot.tour_lengths(auto).get_title()
    for observable in ("sides", lambda x: x[..., :1]):
        by_auto, by_run = plot.running_estimate_values(auto, observable), plot.running_estimate_values(run, observable)
        np.testing.assert_array_equal(by_auto.value, by_run.value)
    assert len(plot.running_estimate(auto, "x").lines) == 1
    kill, _ = plot.traces(auto)
    assert kill.get_title() == "kill rate"
    ax = plot.mode_weights(auto, name="sides", truth=[0.683, 0.317])
    bars = [float(v) for v in ax.lines[0].get_ydata()]
    np.testing.assert_allclose(bars, run.estimate("sides").value)
    plt.close("all")


def test_observables_by_name_are_the_runs_own(run):
    by_name = plot.running_estimate_values(run, "sides")
    final = run.estimate_draws(jax.vmap(jax.vmap(sides)))
    np.testing.assert_allclose(by_name.value[-1], final.value, rtol=1e-12)
    np.testing.assert_allclose(by_name.standard_error[-1], final.standard_error, rtol=1e-12)
    ax = plot.running_estimate(run, "sides", truth=[0.683, 0.317])
    assert [line.get_label() for line in ax.lines[::2]] == ["sides[0]", "sides[1]"] and ax.get_ylabel() == "sides"
    with pytest.raises(KeyError, match="streamed observables are"):
        plot.running_estimate(run, "mu")
    with pytest.raises(TypeError, match="restore.sample or restore.autosample"):
        plot.tour_lengths(run.draws)
    plt.close("all")


def test_numpyro_sites_by_name():
    pytest.importorskip("numpyro")
    import numpyro
    import numpyro.distributions as dist

    from targets.numpyro import NumPyroTarget

    def model():
        numpyro.sample("mu", dist.Normal(0.0, 1.0))
        numpyro.sample("sigma", dist.HalfNormal(1.0))

    target = NumPyroTarget(model)
    sampler = restore.JumpRestore(
        target.logdensity, RandomWalk(1.0), Gaussian(jnp.zeros(2), 1.5), log_rate=np.log(0.25)
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = restore.sample(
            sampler, jax.random.key(1), num_lanes=16, num_steps=200, progress=False, save=restore.SaveDraws(16 * 50),
            observables=target.observables("mu", "sigma"),
        )  # fmt: skip
    sigma = plot.running_estimate_values(result, "sigma")
    final = result.estimate_draws(lambda x: target.constrain(x)["sigma"])
    np.testing.assert_allclose(sigma.value[-1], final.value, rtol=1e-12)
    ax = plot.running_estimate(result, "sigma", truth=np.sqrt(2 / np.pi))
    assert ax.get_title() == "running estimate of sigma"
    plt.close("all")


def test_the_tour_axis_spans_the_data(run):
    tail = plot.tour_tail(run)
    left, right = plot.tour_lengths(run).get_xlim()
    share = lambda t: tail.survival[np.searchsorted(tail.edges, t)]
    # the first decade shown is where tours start to end: none of the fall is cut off, no empty decades
    assert share(left) >= 0.99 * tail.survival[0] and share(10 * left) < 0.95 * share(left)
    assert tail.largest[0] < right < 10 * tail.largest[0]
    plt.close("all")
