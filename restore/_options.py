"""Options of a run, as objects: which draws to keep (`SaveDraws`) and where to checkpoint (`Checkpoint`).

`restore.sample` and `restore.autosample` take them (`save=`, `checkpoint=`), as Diffrax's
`diffeqsolve` takes a `SaveAt`: one object per concern, checked when it is built, so a
wrong setting fails where it is written, not deep inside a run.
"""

from __future__ import annotations

import math
import os
from typing import NamedTuple

import equinox as eqx

from ._validation import check_integer, check_interval


class DrawPlan(NamedTuple):
    """How a run of given size stores its draws (`SaveDraws.plan`).

    Attributes:
        thin: one state in every `thin` steps of each lane is stored.
        stored: draws stored per lane.
        rows: rows per lane of the draws buffer (at least `stored`; part of the compiled program).
        note: a message when the budget, not the user, thinned the draws; else `None`.
    """

    thin: int
    stored: int
    rows: int
    note: str | None


class SaveDraws(eqx.Module):
    """Which states a run keeps, with their weights, for post-hoc work (plots, ArviZ, refits).

    The estimates do not need them: observables are integrated on the device as the run
    goes. Memory for the draws is fixed by `max_draws` whatever the number of steps.

    Arguments:
        max_draws: budget of stored draws over all lanes. When the run makes more states,
            every `thin`-th step is stored, with a message (logged, shown with the progress
            bar, and in `result.summary()`); `0` stores none.
        thin: store every `thin`-th state (overrides the budget's choice).
        rows: rows per lane of the buffer of draws (default: the draws stored per lane
            rounded up to a power of two, within `max_draws`). The buffer is part of the
            compiled program, so runs of other lengths given the same `rows` share one
            program (`restore.autosample` gives its stages the final run's). At least the
            number of draws stored per lane.
    """

    max_draws: int
    thin: int | None
    rows: int | None

    def __init__(self, max_draws: int = 100_000, thin: int | None = None, rows: int | None = None):
        self.max_draws = check_integer(max_draws, "max_draws", minimum=0)
        self.thin = None if thin is None else check_integer(thin, "thin")
        self.rows = None if rows is None else check_integer(rows, "rows", minimum=0)

    def plan(self, num_steps: int, num_lanes: int, dim: int = 0, itemsize: int = 8) -> DrawPlan:
        """The thinning, draws per lane and buffer rows of a run of `num_lanes` x `num_steps`
        (`dim` and `itemsize` size the message about thinning)."""
        max_draws = int(self.max_draws)
        thin = self.thin
        if thin is None:
            thin = max(1, math.ceil(num_steps * num_lanes / max_draws)) if max_draws > 0 else num_steps + 1
        thin = int(thin)
        stored = 0 if max_draws <= 0 else min(math.ceil(num_steps / thin), max(max_draws // num_lanes, 0))
        rows = _rounded_rows(stored, num_lanes, max_draws) if self.rows is None else int(self.rows)
        if rows < stored:
            raise ValueError(f"SaveDraws(rows={rows}) is fewer than the {stored} draws this run stores per lane")
        note = None
        if self.thin is None and thin > 1 and stored > 0:
            note = (
                f"thinned to the draws budget max_draws={max_draws:,}: {num_lanes:,} lanes x {num_steps:,} steps "
                f"make {num_lanes * num_steps:,} states, so one state in every {thin} steps of each lane is stored "
                f"({stored * num_lanes:,} draws, {stored * num_lanes * dim * itemsize / 2**20:.3g} MiB); "
                "raise SaveDraws(max_draws=...) or set SaveDraws(thin=...) to keep more"
            )
        return DrawPlan(thin, stored, rows, note)


#: `restore.sample`'s default: up to 100,000 draws, thinned evenly.
DEFAULT_DRAWS = SaveDraws()


def _rounded_rows(stored: int, num_lanes: int, max_draws: int) -> int:
    """Rows of the draws buffer: `stored` rounded up to a power of two, within the budget.

    The buffer's shape is part of the compiled program; rounding it up lets runs of
    other lengths (most of all, several short runs) share one program. The extra rows are
    never written and are cut off the result.
    """
    if stored == 0:
        return 0
    return min(1 << (stored - 1).bit_length(), max(max_draws // num_lanes, stored))


class Checkpoint(eqx.Module):
    """Where and when a run saves its full state, so that it can be resumed.

    A checkpoint holds the lane states, per-lane sums, tour histogram and tail buffers,
    stored draws and the step count (keys are derived from the run's key and the step
    count, so they need no saving). It is written atomically every `every_steps` steps
    and/or `every_seconds` seconds, when the step budget is spent, on Ctrl-C, and when
    the run is finished. If the file exists (and `resume`), the run continues from it: an
    interrupted and resumed run gives results bit-identical to an uninterrupted one with
    the same key and arguments, and a finished checkpoint returns its result at once. A
    checkpoint of another run (other key, sizes, sampler parameters, observables or
    devices) is refused with a `CheckpointError` that says what differs. With several
    processes, process 0 writes the file, which must be on a file system that every
    process sees.

    Arguments:
        path: the file.
        every_steps: save at the end of the first chunk at or after every `every_steps`
            steps (chunk boundaries do not move, so a run computes the same numbers with
            or without checkpoints; raise `num_chunks` for finer saves).
        every_seconds: save when this many seconds have passed since the last save
            (checked between chunks); `None` for step-based saves only.
        resume: continue from an existing file (default); `False` starts afresh and
            overwrites it.
    """

    path: str | os.PathLike
    every_steps: int | None
    every_seconds: float | None
    resume: bool

    def __init__(
        self, path: str | os.PathLike, every_steps: int | None = None, every_seconds: float | None = 60.0, resume: bool = True
    ):
        if not isinstance(path, (str, os.PathLike)):
            raise TypeError(f"Checkpoint path must be a file name (str or os.PathLike), got {type(path).__name__}")
        if not isinstance(resume, bool):
            raise TypeError(f"resume must be True or False, got {resume!r}")
        self.path, self.resume = path, resume
        self.every_steps = None if every_steps is None else check_integer(every_steps, "every_steps")
        self.every_seconds = check_interval(every_seconds, "every_seconds")


def as_checkpoint(checkpoint: Checkpoint | str | os.PathLike | None) -> Checkpoint | None:
    """A `Checkpoint`, from itself or from a file name (saved every 60 s, resumed if it exists)."""
    if checkpoint is None or isinstance(checkpoint, Checkpoint):
        return checkpoint
    if isinstance(checkpoint, (str, os.PathLike)):
        return Checkpoint(checkpoint)
    raise TypeError(f"checkpoint must be a restore.Checkpoint or a file name, got {type(checkpoint).__name__}")
