"""The run driver shared by `restore.sample` and `restore.render.render`: chunks, budgets, checkpoints, Ctrl-C."""

import time

import pytest

from restore._driver import Budget, drive


class Chunks:
    """Records the chunk lengths asked for; optionally sleeps per step or stops on a given call."""

    def __init__(self, per_step=0.0, interrupt_at=None, short=None):
        self.asked, self.per_step, self.interrupt_at, self.short = [], per_step, interrupt_at, short

    def __call__(self, n):
        if self.interrupt_at is not None and len(self.asked) == self.interrupt_at:
            raise KeyboardInterrupt
        self.asked.append(n)
        time.sleep(self.per_step * n)
        return min(n, self.short) if self.short else n


def test_a_step_budget_is_cut_into_fixed_chunks_and_saved_at_marks_and_at_the_end():
    chunks, saves = Chunks(), []
    outcome = drive(chunks, budget=Budget(steps=23), chunk=5, save=lambda s, t: saves.append(s), save_every_steps=10)
    assert chunks.asked == [5, 5, 5, 5, 3] and outcome.steps == 23 and not outcome.interrupted
    assert saves == [10, 20, 23]


def test_short_chunks_are_followed_by_the_rest_of_the_budget():
    chunks = Chunks(short=4)  # e.g. tour records full: a chunk stops early
    outcome = drive(chunks, budget=Budget(steps=10), chunk=5)
    assert outcome.steps == 10 and chunks.asked == [5, 5, 2]


def test_ctrl_c_keeps_the_committed_chunks_and_saves_them():
    chunks, saves = Chunks(interrupt_at=2), []
    outcome = drive(chunks, budget=Budget(steps=100), chunk=10, save=lambda s, t: saves.append(s))
    assert outcome.interrupted and outcome.steps == 20 and saves == [20]


def test_a_resumed_run_starts_from_its_steps_and_writes_only_progress():
    chunks, saves = Chunks(), []
    outcome = drive(chunks, budget=Budget(steps=30), chunk=10, done=30, save=lambda s, t: saves.append(s))
    assert chunks.asked == [] and outcome.steps == 30 and saves == []


def test_a_time_budget_measures_one_step_first_and_stops_close_to_the_budget():
    chunks = Chunks(per_step=0.002)
    start = time.perf_counter()
    outcome = drive(chunks, budget=Budget(seconds=0.3), chunk=10_000)
    wall = time.perf_counter() - start
    assert chunks.asked[0] == 1 and max(chunks.asked) < 10_000
    assert 0.3 <= outcome.elapsed < 0.6 and wall < 1.0  # slices of 0.05 s: it overshoots by about one
    assert outcome.steps == sum(chunks.asked)


def test_a_budget_needs_steps_or_seconds():
    with pytest.raises(ValueError, match="steps, seconds"):
        Budget()
