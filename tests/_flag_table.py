"""The reliability flag over a graded family of regenerations and targets: per setting, the share of
replications flagged, the coverage of the 95% interval among reliable and among flagged replications,
the worst |z| of a reliable one, and how much farther off the flagged estimates are than the reliable
ones (their root-mean-square errors' ratio, per estimate). `python -m tests._flag_table` prints the table
(in float64, as the tests run it)."""

from __future__ import annotations

import math
import warnings
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import gammaln
from jaxtyping import Array
from scipy import stats

import restore
from restore.regeneration import Gaussian, StudentT

#: Lanes per replication, replications per setting, steps per run.
LANES, REPLICATIONS, STEPS = 16, 150, 1000
#: The two estimates of every replication.
ESTIMATES = ("P(x > 1)", "log Z")
#: Below this many estimates on either side, a root-mean-square error is too noisy to compare.
MIN_SIDE = 10
Z95 = float(stats.norm.isf(0.025))


class Setting(NamedTuple):
    """A Student-t target (`df = inf`: a standard normal) and a regeneration from near-target to poor."""

    df: float
    regeneration: str  # "target", "wide", "narrow" or "poor"

    @property
    def near_target(self) -> bool:
        return self.regeneration == "target"

    def label(self) -> str:
        return f"{'normal' if math.isinf(self.df) else f't, df {self.df:g}'}, {self.regeneration}"


class LogDensity(eqx.Module):
    """The standard normal or Student-t log density (normalised, so log Z = 0).

    The degrees of freedom are an array, not a constant of a closure: the settings then share
    three compiled programs (normal or Student-t target, Gaussian or Student-t regeneration)
    instead of compiling one each.
    """

    df: Array
    inverse_df: Array  # `x**2 * (1 / df)`, as XLA computes `x**2 / df` for a constant `df`: the same bits
    const: Array
    normal: bool = eqx.field(static=True)

    def __init__(self, df: float):
        self.normal = math.isinf(df)
        const = -0.5 * math.log(2 * math.pi) if self.normal else gammaln((df + 1) / 2) - gammaln(df / 2) - 0.5 * math.log(df * math.pi)
        self.df = jnp.asarray(1.0 if self.normal else df)
        self.inverse_df, self.const = 1.0 / self.df, jnp.asarray(float(const))

    def __call__(self, x: Array) -> Array:
        if self.normal:
            return -0.5 * x[0] ** 2 + self.const
        return self.const - (self.df + 1) / 2 * jnp.log1p(x[0] ** 2 * self.inverse_df)


def tail_indicator(x: Array) -> Array:
    """The observable `1{x > 1}` (one function for every setting: one compiled program)."""
    return (x[0] > 1.0).astype(x.dtype)[None]


def regeneration(setting: Setting):
    """The regeneration: the target itself, or Gaussians of standard deviation 2, 0.85 and 0.7."""
    if setting.regeneration == "target":
        return Gaussian(jnp.zeros(1), 1.0) if math.isinf(setting.df) else StudentT(jnp.zeros(1), 1.0, setting.df)
    sd = {"wide": 2.0, "narrow": 0.85, "poor": 0.7}[setting.regeneration]
    return Gaussian(jnp.zeros(1), sd**2)


SETTINGS = tuple(Setting(df, r) for df in (math.inf, 4.0, 3.0, 2.0) for r in ("target", "wide", "narrow", "poor"))


class Row(NamedTuple):
    """What the flag did in one setting, over the estimates of every replication."""

    setting: Setting
    estimates: int
    flagged: float
    reliable_coverage: float
    flagged_coverage: float
    worst_reliable_z: float
    errors: np.ndarray  # `(REPLICATIONS, len(ESTIMATES))`: each estimate minus its truth
    reliable: np.ndarray  # `(REPLICATIONS, len(ESTIMATES))`: marked reliable

    @property
    def error_ratio(self) -> tuple[float, ...]:
        """Per estimate: the RMS error of the flagged over that of the reliable (NaN: a side under `MIN_SIDE`)."""
        return tuple(error_ratio(self.errors[:, i], self.reliable[:, i]) for i in range(len(ESTIMATES)))


def replications(setting: Setting, key) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`(z, reliable, error)` of P(x > 1) and log Z in every replication (two estimates each, in that order)."""
    sampler = restore.JumpRestore(LogDensity(setting.df), restore.local.RandomWalk(1.0), regeneration(setting), tour_length=3.0)
    sf = float(stats.norm.sf(1.0) if math.isinf(setting.df) else stats.t.sf(1.0, setting.df))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = restore.sample(
            sampler, key, num_lanes=REPLICATIONS * LANES, num_steps=STEPS, save=restore.SaveDraws(0), progress=False,
            observables={"tail": tail_indicator},
        )  # fmt: skip
        z, reliable, error = [], [], []
        for r in range(REPLICATIONS):
            lanes = slice(r * LANES, (r + 1) * LANES)
            for est, truth in ((result.estimate("tail", lanes=lanes), sf), (result.normalising_constant(lanes=lanes), 0.0)):
                z.append(float(np.ravel(est.z_score(truth))[0]))
                reliable.append(bool(np.all(est.reliable)))
                error.append(float(np.ravel(est.value)[0]) - truth)
    return np.array(z), np.array(reliable), np.array(error)


def error_ratio(error: np.ndarray, reliable: np.ndarray) -> float:
    """Root-mean-square error of the flagged estimates over that of the reliable ones (NaN: a side under `MIN_SIDE`)."""
    if min(np.sum(reliable), np.sum(~reliable)) < MIN_SIDE:
        return math.nan
    rms = lambda e: float(np.sqrt(np.mean(e**2)))  # noqa: E731
    return rms(error[~reliable]) / rms(error[reliable])


def row(setting: Setting, key) -> Row:
    """The flag's record in one setting."""
    z, reliable, error = replications(setting, key)
    covered = np.abs(z) < Z95
    mean = lambda a: float(np.mean(a)) if a.size else math.nan  # noqa: E731
    worst = float(np.max(np.abs(z[reliable]))) if reliable.any() else math.nan
    per_estimate = lambda a: a.reshape(-1, len(ESTIMATES))  # noqa: E731
    return Row(
        setting, z.size, mean(~reliable), mean(covered[reliable]), mean(covered[~reliable]), worst, per_estimate(error), per_estimate(reliable)
    )


def table(seed: int = 0) -> list[Row]:
    """Every setting, each with its own fixed key."""
    return [row(s, jax.random.key(seed + i)) for i, s in enumerate(SETTINGS)]


def markdown(rows: list[Row]) -> str:
    """The table as Markdown."""
    show = lambda v, f: "-" if math.isnan(v) else format(v, f)  # noqa: E731
    lines = [
        "| target, regeneration | flagged | coverage, reliable | coverage, flagged | worst reliable \\|z\\| "
        f"| RMS error, flagged / reliable ({', '.join(ESTIMATES)}) |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r.setting.label()} | {round(r.flagged * r.estimates)} of {r.estimates} | {show(r.reliable_coverage, '.3f')} "
            f"| {show(r.flagged_coverage, '.3f')} | {show(r.worst_reliable_z, '.2f')} | {', '.join(show(v, '.2f') for v in r.error_ratio)} |"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    jax.config.update("jax_enable_x64", True)  # as the test suite runs it (`tests/conftest.py`)
    print(markdown(table()))
