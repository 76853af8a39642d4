"""Run options as objects: what `SaveDraws` plans for a run, and what `Checkpoint` refuses."""

import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import restore
from restore._options import as_checkpoint
from restore._random import log_uniform


@pytest.mark.parametrize(
    "save, lanes, steps, plan",
    [
        (restore.SaveDraws(), 4, 100, (1, 100, 128)),  # everything fits: no thinning, rows a power of two
        (restore.SaveDraws(1_000), 2, 20_000, (40, 500, 500)),  # thinned to the budget: 40,000 states, 1,000 kept
        (restore.SaveDraws(0), 8, 50, (51, 0, 0)),  # none stored
        (restore.SaveDraws(thin=3), 4, 100, (3, 34, 64)),  # the user's thinning
        (restore.SaveDraws(rows=256), 4, 100, (1, 100, 256)),  # a buffer shared with longer runs
    ],
)
def test_save_draws_plans_thinning_draws_and_rows(save, lanes, steps, plan):
    got = save.plan(steps, lanes)
    assert (got.thin, got.stored, got.rows) == plan
    assert (got.note is not None) == (save.thin is None and got.thin > 1 and got.stored > 0)


def test_save_draws_note_names_the_budget_and_the_remedy():
    note = restore.SaveDraws(1_000).plan(20_000, 2, dim=3, itemsize=8).note
    assert note is not None and "max_draws=1,000" in note and "one state in every 40 steps" in note
    assert "SaveDraws(max_draws=...)" in note and "SaveDraws(thin=...)" in note


def test_save_draws_refuses_bad_settings():
    with pytest.raises(ValueError, match="max_draws must be a non-negative integer"):
        restore.SaveDraws(-1)
    with pytest.raises(ValueError, match="thin must be a positive integer"):
        restore.SaveDraws(thin=0)
    with pytest.raises(TypeError, match="rows must be a non-negative integer"):
        restore.SaveDraws(rows="many")
    with pytest.raises(ValueError, match="fewer than the 100 draws"):
        restore.SaveDraws(rows=64).plan(100, 4)


def test_sample_refuses_a_save_that_is_not_save_draws():
    sampler = restore.JumpRestore(lambda x: -0.5 * jnp.sum(x**2), restore.local.RandomWalk(1.0), restore.regeneration.Gaussian(jnp.zeros(1), 1.0), log_rate=0.0)
    with pytest.raises(TypeError, match="save must be a restore.SaveDraws"):
        restore.sample(sampler, jax.random.key(0), num_lanes=4, num_steps=10, progress=False, save=1000)


def test_checkpoint_takes_a_file_name_and_checks_its_cadence():
    assert as_checkpoint(None) is None
    assert as_checkpoint("run.ckpt") == restore.Checkpoint("run.ckpt")  # saved every 60 s, resumed if it exists
    plain = restore.Checkpoint(Path("run.ckpt"))
    assert (plain.every_steps, plain.every_seconds, plain.resume) == (None, 60.0, True)
    with pytest.raises(TypeError, match="Checkpoint path must be a file name"):
        restore.Checkpoint(3)
    with pytest.raises(TypeError, match="resume must be True or False"):
        restore.Checkpoint("run.ckpt", resume="yes")
    with pytest.raises(ValueError, match="every_seconds must be a positive number or None"):
        restore.Checkpoint("run.ckpt", every_seconds=math.inf)


def test_jump_event_kills_with_probability_gamma_over_r_plus_gamma_and_holds_one_over_r_plus_gamma():
    """The kill-or-move event that Restore's step and the speculative steps share, against its law."""
    n, log_gamma, log_r = 200_000, math.log(0.5), math.log(2.0)
    keys = jax.random.split(jax.random.key(0), 2 * n)
    uniforms = jax.vmap(lambda k: log_uniform(k, jnp.float32))(keys[:n])
    exponentials = jax.vmap(lambda k: jax.random.exponential(k, dtype=jnp.float32))(keys[n:])
    event = restore.jump_event(uniforms, exponentials, jnp.float32(log_gamma), jnp.float32(log_r))
    p_kill, mean_hold = 0.5 / 2.5, 1.0 / 2.5
    assert abs(float(jnp.mean(event.killed)) - p_kill) < 5 * math.sqrt(p_kill * (1 - p_kill) / n)
    np.testing.assert_allclose(event.expected_holding_time, mean_hold, rtol=1e-6)
    assert abs(float(jnp.mean(event.holding_time)) - mean_hold) < 5 * mean_hold / math.sqrt(n)
    # the edges: no kill where gamma = 0, a kill for sure where gamma = inf (zero density)
    edges = restore.jump_event(uniforms[:2], exponentials[:2], jnp.array([-jnp.inf, jnp.inf]), jnp.float32(log_r))
    assert not bool(edges.killed[0]) and bool(edges.killed[1]) and float(edges.expected_holding_time[1]) == 0.0
