"""The run driver that `restore.sample` and `restore.render.render` share.

A run is a sequence of jitted chunks separated by host steps. The driver owns the host
side: how long each chunk is (a fixed length, or sized from the measured time per step
under a time budget), the progress meter, the checkpoint cadence (every so many steps
and/or seconds, when the budget is spent, on Ctrl-C) and Ctrl-C itself. What a run
accumulates is pluggable: the caller's `advance(n)` runs a chunk of at most `n` steps
with its own accumulators (the lane sums, tour histogram and tail buffers of
`restore.sample`; the film of a renderer) and commits the new state in one assignment,
so an interrupt never leaves a chunk half counted.

`advance(n)` may also return at once, with the chunk dispatched to the device and a
function that waits for it, commits it and returns its steps. Under a step budget the
driver then dispatches the next chunk before it waits for the last one, so the device
never waits for the host between chunks (the host's work per chunk, a few scalars for
the progress bar, overlaps the device's).

After the budget, the open tours are run to their end by `drive_finishing`: calls of the
caller's finishing program, with their own progress bar, until none is open.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import signal
import threading
import time
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from rich.progress import Progress, TaskID


@dataclasses.dataclass(frozen=True)
class Budget:
    """When a run stops: after `steps` steps per lane, after `seconds` of wall time, or at the first of both.

    Under a time budget the first chunk is a single step (to measure the time per step)
    and later chunks are cut to the time left, in slices of at most a twentieth of the
    budget (and 2 s), so that the run stops within about one step of the budget.
    """

    steps: int | None = None
    seconds: float | None = None

    def __post_init__(self):
        if self.steps is None and self.seconds is None:
            raise ValueError("a budget needs steps, seconds or both")


@dataclasses.dataclass(frozen=True)
class Outcome:
    """How a driven run ended: steps per lane done, whether Ctrl-C stopped it, and the wall time
    spent (earlier sessions of a resumed run included)."""

    steps: int
    interrupted: bool
    elapsed: float


class Meter:
    """A rich progress bar, advanced between chunks; a no-op when disabled.

    Arguments:
        enabled: show the bar.
        description: the text before the bar.
        total: the budget in the bar's unit.
        unit: e.g. `"steps"`, `"evals"`, `"s"`.
        completed: units already done (a resumed run).
    """

    def __init__(self, enabled: bool, description: str, total: float, unit: str, completed: float = 0):
        self.enabled, self.description, self.total, self.unit, self.completed = (
            enabled,
            description,
            total,
            unit,
            completed,
        )
        self._bar: Progress | None = None
        self._task: TaskID | None = None

    @contextlib.contextmanager
    def shown(self) -> Iterator[Meter]:
        if not self.enabled:
            yield self
            return
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

        done = (
            "{task.completed:,.0f}/{task.total:,.0f}" if self.unit != "s" else "{task.completed:.3g}/{task.total:.3g}"
        )
        columns = (
            TextColumn("{task.description}"),
            BarColumn(),
            TextColumn(done + " " + self.unit),
            TextColumn("{task.fields[rate]}"),
            TimeElapsedColumn(),
            TimeRemainingColumn(),
        )
        with Progress(*columns, transient=False) as bar:
            self._bar = bar
            self._task = bar.add_task(self.description, total=self.total, rate="")
            bar.update(self._task, completed=self.completed)  # (a float: `add_task` takes whole numbers)
            try:
                yield self
            finally:
                self._bar = None

    def update(self, completed: float, rate: str = "") -> None:
        if self._bar is not None and self._task is not None:
            self._bar.update(self._task, completed=min(completed, self.total), rate=rate)


@contextlib.contextmanager
def _interrupt_deferred() -> Iterator[None]:
    """Ctrl-C inside waits until the block has ended (in the main thread; elsewhere it cannot come)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if caught:
        raise KeyboardInterrupt


def drive(
    advance: Callable[[int], int | Callable[[], int]],
    *,
    budget: Budget,
    chunk: int,
    done: int = 0,
    spent: float = 0.0,
    meter: Meter | None = None,
    report: Callable[[int, float], tuple[float, str]] = lambda steps, elapsed: (steps, ""),
    on_chunk: Callable[[], None] | None = None,
    save: Callable[[int, float], None] | None = None,
    save_every_steps: int | None = None,
    save_every_seconds: float | None = None,
) -> Outcome:
    """Run chunks until the budget is spent or Ctrl-C, with progress and checkpoints.

    Arguments:
        advance: `advance(n)` runs at most `n` more steps (a chunk may stop early), commits
            them and returns the steps taken; or dispatches them and returns a function
            that waits for the chunk, commits it and returns the steps taken (pipelined:
            with a step budget only, the next chunk is dispatched before the last is
            waited for).
        budget: when to stop.
        chunk: steps per chunk (the chunk boundaries fix the random keys: with a step
            budget the same arguments give the same chunks, so results do not depend on
            checkpoints or interrupts).
        done: steps already done (a resumed run).
        spent: wall time already spent (a resumed run).
        meter: the progress meter.
        report: `(steps done, elapsed) -> (meter position, rate text)`.
        on_chunk: called after every committed chunk (progressive output).
        save: `save(steps done, elapsed)` writes a checkpoint of the committed state: called
            every `save_every_steps` steps (at the first chunk boundary at or after each
            multiple) and every `save_every_seconds`, when the budget is spent, and on
            Ctrl-C once a chunk was committed.

    Returns:
        The `Outcome`.
    """
    meter = meter or Meter(False, "", 1, "")
    start = time.perf_counter()
    first, last_save, interrupted = done, time.perf_counter(), False
    saved = done
    elapsed = lambda: spent + time.perf_counter() - start  # noqa: E731

    def next_mark(steps: int) -> float:
        return math.inf if save_every_steps is None else (steps // save_every_steps + 1) * save_every_steps

    def write():
        nonlocal last_save, saved
        if save is not None and done > saved:  # only progress is worth a write
            save(done, elapsed())
            last_save, saved = time.perf_counter(), done

    mark = next_mark(done)
    waiting: list[Callable[[], int]] = []  # a dispatched chunk not yet waited for (pipelined advances)
    dispatched = done

    def finish_chunk(steps: int, may_save: bool = True) -> None:
        nonlocal done, mark
        done += steps
        meter.update(*report(done, elapsed()))
        if on_chunk is not None:
            on_chunk()
        if may_save and save_due():
            write()
            mark = next_mark(done)

    def save_due() -> bool:
        return save is not None and (
            done >= mark or (save_every_seconds is not None and time.perf_counter() - last_save >= save_every_seconds)
        )

    def wait_for_chunk(may_save: bool = True) -> None:
        """Wait for the oldest chunk in flight and commit it. Ctrl-C takes effect once it is
        committed and counted (the run and the steps done always agree); the chunk stays in
        flight if its wait raises."""
        with _interrupt_deferred():
            steps = waiting[0]()
            waiting.pop(0)
            finish_chunk(steps, may_save)

    with meter.shown():
        try:
            while budget.steps is None or dispatched < budget.steps:
                n = chunk if budget.steps is None else min(chunk, budget.steps - dispatched)
                if budget.seconds is not None:
                    if elapsed() >= budget.seconds and done > 0:  # at least one step, ever
                        break
                    if done == first:
                        n = 1  # measure the time per step before committing to a chunk
                    else:
                        per_step = max((time.perf_counter() - start) / (done - first), 1e-9)
                        slice_ = min(2.0, max(budget.seconds / 20, 0.05))
                        n = min(n, max(1, math.ceil(min(budget.seconds - elapsed(), slice_) / per_step)))
                if waiting and (save_due() or dispatched >= mark):  # save the chunk in flight before the next one takes its buffers
                    wait_for_chunk()
                with _interrupt_deferred():  # a dispatch is not cut in half, nor lost before it is queued or counted
                    outcome = advance(n)
                    if callable(outcome):
                        waiting.append(outcome)
                    else:
                        dispatched += outcome
                        finish_chunk(outcome)
                if callable(outcome):
                    dispatched += n
                    if budget.seconds is None:  # chunk sizes are known ahead: keep one chunk in flight
                        if len(waiting) > 1:
                            wait_for_chunk(may_save=False)  # the older one: its buffers went to the chunk just dispatched
                        continue
                    before = done
                    wait_for_chunk()
                    dispatched += done - before - n
            while waiting:
                wait_for_chunk()
        except KeyboardInterrupt:
            interrupted = True
            while waiting:  # the chunks in flight hold the run (the committed one gave them its buffers): wait for them, in order
                try:
                    wait_for_chunk(may_save=False)
                except KeyboardInterrupt:
                    continue
    write()
    return Outcome(done, interrupted, elapsed())


def drive_finishing(call: Callable[[], tuple[int, int, bool]], opened: int, progress: bool) -> int:
    """Run the open tours to their end after the budget: `call()` until it says it is over.

    `call` runs one call of the caller's finishing program (no tour starts in it), commits
    what it did and returns `(steps it took, tours still open, over)`. Between calls a progress
    bar counts the tours closed out of the `opened` ones; Ctrl-C stops the finishing there
    (a `KeyboardInterrupt` for the caller, which keeps the calls it committed). Returns the
    steps taken. Used by `restore.sample` (`_run.Run`) and `restore.render.render`.
    """
    meter = Meter(progress and opened > 0, "finishing the open tours (none start)", opened, "tours")
    steps = 0
    with meter.shown():
        while True:
            taken, still_open, over = call()
            steps += taken
            meter.update(opened - still_open, f"{still_open:,} open, {steps:,} steps")
            if over:
                return steps
