"""The interface of the evidence benchmark's methods: a problem and a key in, `log Z`, moments and costs out."""

from __future__ import annotations

import abc
import math
from collections.abc import Callable
from typing import Literal, NamedTuple

import jax
import numpy as np
from jaxtyping import Array, PRNGKeyArray

Status = Literal["ok", "capped", "failed", "skipped"]


class EvidenceOutput(NamedTuple):
    """What one run of one method estimated and what it cost.

    Standard errors are NaN (or `None` for arrays) where the method reports none from a
    single run. `evaluations` counts every evaluation of the target's log density a run
    made, a gradient included (a value and its gradient count as one), in every stage:
    mode finding, pilots, tempering steps, likelihood calls.
    """

    log_z: float
    log_z_se: float
    mean: np.ndarray | None  # (d,)
    mean_se: np.ndarray | None
    second_moment: np.ndarray | None  # (d,) E[x_i^2]
    second_moment_se: np.ndarray | None
    positive: float  # Many Well: estimated P(x_{2i} > 0), averaged over pairs; NaN elsewhere
    positive_se: float
    evaluations: int
    wall_time: float  # seconds, compilation included
    compile_time: float  # seconds of tracing and XLA compilation inside the run
    status: Status = "ok"
    k_hat: float = math.nan  # Pareto tail index of the tour weights, where the method reports it
    reliable: bool | None = None  # the method's own verdict on its error bars, where it gives one
    notes: str = ""

    @classmethod
    def empty(cls, status: Status, notes: str, wall_time: float = 0.0, compile_time: float = 0.0, evaluations: int = 0) -> EvidenceOutput:
        """A run with no estimates: a failure (with the error message) or a skipped method."""
        nan = math.nan
        return cls(nan, nan, None, None, None, None, nan, nan, evaluations, wall_time, compile_time, status, notes=notes)

    @property
    def run_time(self) -> float:
        """Wall time minus compilation."""
        return max(self.wall_time - self.compile_time, 0.0)


class EvidenceRunner(abc.ABC):
    """A method, configured as its users would configure it, that estimates `log Z` on any evidence problem.

    Attributes:
        name: short unique name, e.g. `"smc-hmc"`.
        family: `"restore"`, `"smc"` or `"nested"`.
    """

    name: str
    family: str

    def unavailable(self) -> str | None:
        """Why this method cannot run here (a missing package or function), or `None` when it can."""
        return None

    @abc.abstractmethod
    def run(self, problem, key: PRNGKeyArray) -> EvidenceOutput:
        """Estimate `log Z` (and moments) of `problem.logdensity`, knowing only `problem.box`."""


class CountedDensity:
    """A log density that counts its evaluations on the host, for stages whose cost is not known in advance.

    Every evaluation (under `jit`, `vmap`, `grad`, `hessian` and loops alike) makes one
    `jax.debug.callback`; a gradient or a Hessian evaluated through the same trace counts
    once. Slower than the bare density, so use it only around stages like mode finding.
    """

    def __init__(self, logdensity: Callable[[Array], Array]):
        self._logdensity = logdensity
        self.count = 0

    def _tick(self, _) -> None:
        self.count += 1

    def __call__(self, x: Array) -> Array:
        jax.debug.callback(self._tick, x[0])
        return self._logdensity(x)


def short_message(error: BaseException, limit: int = 200) -> str:
    """`Type: first line of the message`, shortened to `limit` characters, for a failure row."""
    text = f"{type(error).__name__}: {str(error).strip().splitlines()[0] if str(error).strip() else ''}"
    return text if len(text) <= limit else text[: limit - 3] + "..."


def weighted_moments(draws: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`E[x]` and `E[x^2]` of weighted draws (weights normalised here)."""
    w = np.asarray(weights, np.float64)
    w = w / np.sum(w)
    x = np.asarray(draws, np.float64)
    return w @ x, w @ (x * x)


def right_well_share(draws: np.ndarray, weights: np.ndarray) -> float:
    """Weighted share of double-well coordinates `x_{2i}` that are positive (Many Well)."""
    w = np.asarray(weights, np.float64)
    return float(w @ np.mean(np.asarray(draws)[:, 0::2] > 0, axis=1) / np.sum(w))
