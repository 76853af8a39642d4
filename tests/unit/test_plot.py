"""Plots of a run: the numbers behind them agree with the result, and every plot draws.

The run samples a half-normal with a regeneration that puts half its tours where the
target is zero: those tours end at once with length zero, and must count among the
shortest in the tour-length distribution.
"""

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
            sampler, jax.random.key(0), num_lanes=32, num_steps=500, progress=False, num_chunks=10, max_draws=32 * 100
        )


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
    with pytest.raises(ValueError, match="one number"):
        plot.running_estimate(run, lambda x: np.concatenate([x, x], axis=-1))
    no_trace = restore.SampleResult(**{**run.__dict__, "trace": None})
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
