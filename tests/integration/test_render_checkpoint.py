"""Renders that are interrupted and resumed from a checkpoint (on `AnalyticImage`, no Mitsuba)."""

import time

import jax
import numpy as np
import pytest

import restore
from restore._checkpoint import CheckpointError, read_header
from restore.render import ERPT, PSSMLT, MetropolisRestore, render
from targets import AnalyticImage

TARGET = AnalyticImage.default(dim=3, resolution=(8, 8), num_bumps=3)
BUDGET = dict(key=jax.random.key(2), evaluations=120_000, num_lanes=128, chunk=40, progress=False)


def _interrupt_after(chunks: int):
    calls = []

    def on_update(image, statistics):
        calls.append(1)
        if len(calls) == chunks:
            raise KeyboardInterrupt

    return on_update


@pytest.mark.parametrize("renderer", [MetropolisRestore(), ERPT(chain_length=4)], ids=lambda r: type(r).__name__)
def test_interrupted_and_resumed_render_is_bit_identical(renderer, tmp_path):
    checkpoint = tmp_path / "render.ckpt"
    reference = render(TARGET, renderer, **BUDGET)
    partial = render(TARGET, renderer, checkpoint=checkpoint, on_update=_interrupt_after(2), **BUDGET)
    assert partial.interrupted and 0 < partial.steps < reference.steps
    assert read_header(checkpoint)["steps"] == partial.steps
    resumed = render(TARGET, renderer, checkpoint=checkpoint, **BUDGET)
    assert not resumed.interrupted
    assert (resumed.steps, resumed.evaluations) == (reference.steps, reference.evaluations)
    np.testing.assert_array_equal(resumed.image, reference.image)
    assert resumed.statistics == reference.statistics
    again = render(TARGET, renderer, checkpoint=checkpoint, **BUDGET)  # finished: no compilation, no step
    np.testing.assert_array_equal(again.image, reference.image)
    assert again.compile_seconds < 1.0


def test_time_budget_counts_the_time_spent_before_the_interruption(tmp_path):
    checkpoint = tmp_path / "render.ckpt"
    budget = dict(key=jax.random.key(0), seconds=1.5, num_lanes=128, chunk=50, progress=False, checkpoint=checkpoint)
    first_update: list[float] = []

    def interrupt_after_a_second(image, statistics):  # of the run's own time (compilation is not counted)
        first_update.append(time.perf_counter())
        if first_update[-1] - first_update[0] > 1.0:
            raise KeyboardInterrupt

    partial = render(TARGET, MetropolisRestore(), on_update=interrupt_after_a_second, **budget)
    assert partial.interrupted and partial.seconds > 0.8
    start = time.perf_counter()
    resumed = render(TARGET, MetropolisRestore(), **budget)
    session = time.perf_counter() - start - resumed.compile_seconds - resumed.finishing_seconds
    assert resumed.steps > partial.steps
    # the budget's time over both sessions (the finishing of the open tours comes on top of it);
    # the second session spends what the first left, where one that forgot it would spend 1.5 s
    assert resumed.seconds - resumed.finishing_seconds == pytest.approx(1.5, abs=0.5)
    assert session < 1.5 - partial.seconds + 0.4
    assert read_header(checkpoint)["seconds_spent"] == pytest.approx(resumed.seconds, abs=0.1)


def test_checkpoint_of_another_render_is_refused(tmp_path):
    checkpoint = tmp_path / "render.ckpt"
    render(TARGET, MetropolisRestore(), checkpoint=checkpoint, **BUDGET)
    with pytest.raises(CheckpointError, match="renderer: checkpoint has"):
        render(TARGET, PSSMLT(), checkpoint=checkpoint, **BUDGET)
    with pytest.raises(CheckpointError, match="lanes: checkpoint has 128, this run has 64"):
        render(TARGET, MetropolisRestore(), checkpoint=checkpoint, **{**BUDGET, "num_lanes": 64})
    fresh = render(TARGET, PSSMLT(), checkpoint=restore.Checkpoint(checkpoint, resume=False), **BUDGET)
    assert not fresh.interrupted and "PSSMLT" in read_header(checkpoint)["renderer"]


def test_bad_checkpoint_settings_are_rejected():
    with pytest.raises(ValueError, match="every_seconds must be a positive number"):
        restore.Checkpoint("render.ckpt", every_seconds=0)
    with pytest.raises(TypeError, match="checkpoint must be a restore.Checkpoint or a file name"):
        render(TARGET, MetropolisRestore(), checkpoint=0.5, **BUDGET)


def test_a_render_saves_every_so_many_steps(tmp_path):
    """`Checkpoint(every_steps=...)`: a save at the end of the first chunk at or after every multiple."""
    checkpoint, seen = tmp_path / "render.ckpt", []

    def on_update(image, statistics):  # called before the chunk's own save: sees the one before
        seen.append(read_header(checkpoint)["steps"] if checkpoint.exists() else None)

    budget = {**BUDGET, "chunk": 10}
    result = render(TARGET, PSSMLT(), on_update=on_update, checkpoint=restore.Checkpoint(checkpoint, every_steps=30, every_seconds=None), **budget)
    assert seen[:4] == [None, None, None, 30] and result.steps > 60
    assert {s for s in seen if s is not None} == set(range(30, result.steps, 30)) - {result.steps}
    assert read_header(checkpoint)["steps"] == result.steps  # and the finished run at the end
    timed = tmp_path / "timed.ckpt"
    render(TARGET, PSSMLT(), on_update=lambda *_: seen.append(timed.exists()), checkpoint=timed, **budget)
    assert not any(seen[-3:])  # every 60 s only: no save within this short render but the last
