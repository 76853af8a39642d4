"""Bounded memory: a run of 3 x 10^5 steps needs no more memory than one of 10^4 steps, and
stored draws stay within their budget, with a message when that thins them."""

import json
import logging
import os
import subprocess
import sys
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import pytest

import restore

SCRIPT = Path(__file__).parents[1] / "_memory_run.py"


def test_peak_memory_does_not_grow_with_the_number_of_steps():
    completed = subprocess.run(
        [sys.executable, str(SCRIPT), "300000"], capture_output=True, text=True, env=dict(os.environ), timeout=600
    )
    assert completed.returncode == 0, completed.stderr
    report = json.loads(completed.stdout.strip().splitlines()[-1])
    assert report["num_steps"] == 300_000
    # Streaming sums added to the run's totals every chunk, on the device: the 30x longer run allocates nothing new.
    growth = report["peak_after_long_mib"] - report["peak_after_short_mib"]
    assert growth < 16.0, report
    assert report["draws"] == [[0, 2, 1], [0, 2, 1]]  # stored draws are capped separately (below)
    assert abs(report["mean_x2"] - 1.0) < 0.05  # and the 6 x 10^5 states give the right answer


def test_stored_draws_are_thinned_to_the_budget_with_a_message(caplog):
    sampler = restore.JumpRestore(
        lambda x: -0.5 * jnp.sum(x**2), restore.local.RandomWalk(1.0), restore.regeneration.Gaussian(jnp.zeros(1), 2.0),
        log_rate=0.0,
    )
    with caplog.at_level(logging.INFO, logger="restore"):
        result = restore.sample(sampler, jax.random.key(0), num_lanes=2, num_steps=20_000, save=restore.SaveDraws(1_000), progress=False)
    assert result.draws.shape == (500, 2, 1) and result.thin == 40
    note = "max_draws=1,000: 2 lanes x 20,000 steps make 40,000 states, so one state in every 40 steps of each lane is stored"
    assert note in result.draws_note and note in caplog.text
    assert "stored draws: 500 per lane, one every 40 steps (thinned to the draws budget" in result.summary()
    # said to the user once, when the draws are used (the streamed estimates use every step)
    with pytest.warns(restore.ThinnedDrawsWarning, match=note):
        result.estimate_draws(lambda x: x[..., 0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result.estimate_draws(lambda x: x[..., 0])
    unthinned = restore.sample(sampler, jax.random.key(0), num_lanes=2, num_steps=100, save=restore.SaveDraws(1_000), progress=False)
    assert unthinned.thin == 1 and unthinned.draws_note is None
