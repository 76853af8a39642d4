"""Per-chunk totals of a run: kill rate and acceptance over time, recorded between chunks."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class RunTrace(NamedTuple):
    """What each jitted chunk of a run did, summed over lanes.

    Recorded on the host from the sums drained after each chunk of the step budget, so it
    costs nothing per step (the steps that finish the open tours after the budget are not
    traced). A run resumed from a checkpoint traces the chunks run since it resumed.

    Attributes:
        step: steps per lane at the end of each chunk.
        lane_steps: steps taken by all lanes in the chunk.
        time: simulated (continuous) time of all lanes in the chunk.
        accepted: accepted local moves (or MH large steps) in the chunk.
        regenerations: kills followed by a regeneration in the chunk.
    """

    step: np.ndarray
    lane_steps: np.ndarray
    time: np.ndarray
    accepted: np.ndarray
    regenerations: np.ndarray

    @property
    def kill_rate(self) -> np.ndarray:
        """Regenerations per unit of simulated time, per chunk (`c = 1 / mean tour length` in stationarity)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.time > 0, self.regenerations / self.time, np.nan)

    @property
    def acceptance(self) -> np.ndarray:
        """Accepted moves per step, per chunk."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.lane_steps > 0, self.accepted / self.lane_steps, np.nan)


def chunk_totals(sums, step: int, steps_taken: int) -> tuple:
    """One chunk's row of a `RunTrace`, from the chunk's per-lane sums (before they join the totals)."""
    total = lambda name: float(np.sum(np.asarray(getattr(sums, name), np.float64)))
    lane_steps = int(np.asarray(sums.all_t).shape[0]) * int(steps_taken)
    return (int(step), lane_steps, total("all_t"), total("num_accepted"), total("num_regenerations"))


def run_trace(rows: list[tuple]) -> RunTrace | None:
    """The trace of a run from its chunk rows (`None` when no chunk ran)."""
    if not rows:
        return None
    columns = list(zip(*rows, strict=True))
    kinds = (np.int64, np.int64, np.float64, np.float64, np.float64)
    return RunTrace(*(np.asarray(c, k) for c, k in zip(columns, kinds, strict=True)))


def merge_traces(traces: list[RunTrace | None]) -> RunTrace | None:
    """Traces of runs over disjoint lanes with the same chunks, added up (`None` if they differ)."""
    present = [t for t in traces if t is not None]
    if len(present) != len(traces) or len({tuple(t.step) for t in present}) != 1:
        return None
    first = present[0]
    add = lambda name: np.sum([getattr(t, name) for t in present], axis=0)
    return first._replace(lane_steps=add("lane_steps"), time=add("time"), accepted=add("accepted"), regenerations=add("regenerations"))
