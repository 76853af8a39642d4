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


class Donating:
    """Pipelined chunks: each dispatch takes the buffers of the newest carry (as a donated
    carry does) and returns a function that waits for the chunk and commits it. The wait
    for chunk `interrupt_wait` is interrupted once (Ctrl-C while the next chunk is in flight)."""

    class Carry:
        def __init__(self, steps):
            self.steps, self.deleted = steps, False

    def __init__(self, interrupt_wait=None):
        self.newest = self.committed = self.Carry(0)
        self.interrupt_wait, self.dispatched, self.saves = interrupt_wait, 0, []

    def __call__(self, n):
        index, out = self.dispatched, self.Carry(self.newest.steps + n)
        self.newest.deleted, self.newest, self.dispatched = True, out, self.dispatched + 1

        def wait():
            if index == self.interrupt_wait:
                self.interrupt_wait = None
                raise KeyboardInterrupt
            self.committed = out
            return n

        return wait

    def save(self, steps, _elapsed):
        assert not self.committed.deleted and self.committed.steps == steps, "a checkpoint of buffers given away"
        self.saves.append(steps)


def test_pipelined_chunks_commit_in_order_and_save_at_marks():
    chunks = Donating()
    outcome = drive(chunks, budget=Budget(steps=50), chunk=10, save=chunks.save, save_every_steps=20)
    assert outcome.steps == 50 and chunks.saves == [20, 40, 50] and chunks.committed.steps == 50


@pytest.mark.parametrize("interrupt_wait", [0, 2])
def test_ctrl_c_while_a_chunk_is_in_flight_commits_every_dispatched_chunk(interrupt_wait):
    """Interrupted while waiting for a chunk whose carry the next chunk already took: both
    chunks are waited for, in order, and the checkpoint holds the newest, live one."""
    chunks = Donating(interrupt_wait)
    outcome = drive(chunks, budget=Budget(steps=100), chunk=10, save=chunks.save)
    assert outcome.interrupted and outcome.steps == 10 * (interrupt_wait + 2) == chunks.committed.steps
    assert chunks.saves == [outcome.steps]
