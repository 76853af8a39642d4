"""`autosample`'s stages: what each one found, when to stop adapting, and which one the final run takes.

A stage that is not healthy can be so for two reasons that its tail shapes alone cannot
tell apart. Its tours found mass its regeneration covers poorly (heavy tails: the next fit
covers more), or they never went where that mass is (light tails, and a `log Z` short by
the mass missed). Missed mass pulls `log Z` down, whatever the tails say; an estimate far
above the truth needs a rare giant tour weight. So between stages that are not healthy, a
`log Z` well above another's is evidence that that stage's regeneration reaches mass the
other misses:

- the final run takes, among the stages whose `log Z` is not `MASS_SE` standard errors
  below the highest, the one with the lightest tail (`final_stage`);
- adapting goes on past `STALL_FROM` stages while one of the last `STALL` stages found
  mass (its `log Z` `MASS_SE` standard errors above every stage before it), up to
  `max_stages` (`keep_adapting`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple


class StageReport(NamedTuple):
    """What one stage of `autosample` did and found.

    Attributes:
        stage: 0 for the seeding chains, then 1, 2, ... for Restore stages.
        kind: `"seed"`, `"adapt"` (a Restore stage that chose the next regeneration)
            or `"final"`.
        family: the regeneration family of the stage (`"chains"` for seeding).
        num_components: its number of components.
        evaluations: log-density evaluations spent by the stage (pilot included).
        wall_time: seconds, compilation included.
        duration_k_hat: Pareto shape of the tour durations (NaN for seeding).
        importance_k_hat: Pareto shape of the importance weights at tour starts.
        effective_tours: effective number of tours as a share of the tours.
        log_z: the stage's `log Z` estimate from its tours (NaN for seeding).
        log_z_se: its standard error.
        healthy: the stage's tails are light enough to stop adapting.
    """

    stage: int
    kind: str
    family: str
    num_components: int
    evaluations: int
    wall_time: float
    duration_k_hat: float
    importance_k_hat: float
    effective_tours: float
    log_z: float
    log_z_se: float
    healthy: bool


#: A stage's `log Z` this many (combined) standard errors above another's: it reached mass the other missed.
MASS_SE = 3.0
#: Stages that are run whatever they find (unless one is healthy)...
STALL_FROM = 6
#: ...after which adapting stops once this many stages in a row found no mass (`keep_adapting`).
STALL = 3


def _tail(report: StageReport) -> float:
    """The heavier of a stage's two tail shapes (durations, importance weights): lower is better."""
    shapes = [k for k in (report.duration_k_hat, report.importance_k_hat) if math.isfinite(k)]
    return max(shapes) if len(shapes) == 2 else math.inf


def _has_log_z(report: StageReport) -> bool:
    return math.isfinite(report.log_z) and math.isfinite(report.log_z_se)


def _above(report: StageReport, other: StageReport) -> bool:
    """Whether `report`'s `log Z` is `MASS_SE` combined standard errors above `other`'s."""
    if not (_has_log_z(report) and _has_log_z(other)):
        return False
    return report.log_z - other.log_z > MASS_SE * math.hypot(report.log_z_se, other.log_z_se)


def final_stage(stages: Sequence[StageReport]) -> int:
    """The index (in `stages`) of the stage whose regeneration the final run takes: the first
    healthy one; else, among the stages not `MASS_SE` standard errors below the stage with the
    highest `log Z`, the one with the lightest tail (the first of equals)."""
    if not stages:
        raise ValueError("no stage to choose from")
    for i, s in enumerate(stages):
        if s.healthy:
            return i
    with_z = [s for s in stages if _has_log_z(s)]
    top = max(with_z, key=lambda s: s.log_z) if with_z else None
    candidates = [i for i, s in enumerate(stages) if top is None or not _above(top, s)]
    return min(candidates, key=lambda i: _tail(stages[i]))


def found_mass(stages: Sequence[StageReport], i: int) -> bool:
    """Whether stage `i`'s `log Z` is `MASS_SE` standard errors above that of every stage before it."""
    return i > 0 and _has_log_z(stages[i]) and all(_above(stages[i], s) or not _has_log_z(s) for s in stages[:i])


def keep_adapting(stages: Sequence[StageReport], max_stages: int) -> bool:
    """Whether to run another stage after `stages` (the Restore stages so far, none healthy):
    always before `STALL_FROM` stages, never from `max_stages` on, and in between while one of
    the last `STALL` stages found mass."""
    n = len(stages)
    if n >= max_stages:
        return False
    if n < STALL_FROM:
        return True
    return any(found_mass(stages, i) for i in range(n - STALL, n))
