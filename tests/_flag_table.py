"""The reliability flag over a graded family of regenerations and targets: per setting, the share of
replications flagged, the coverage of the 95% interval among reliable and among flagged replications,
and the worst |z| of a reliable one. `python -m tests._flag_table` prints the table."""

from __future__ import annotations

import math
import warnings
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import gammaln
from scipy import stats

import restore
from restore.regeneration import Gaussian, StudentT

#: Lanes per replication, replications per setting, steps per run.
LANES, REPLICATIONS, STEPS = 16, 150, 1000
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


def logdensity(df: float):
    """The standard normal or Student-t log density (normalised, so log Z = 0)."""
    if math.isinf(df):
        return lambda x: -0.5 * x[0] ** 2 - 0.5 * math.log(2 * math.pi)
    const = float(gammaln((df + 1) / 2) - gammaln(df / 2) - 0.5 * math.log(df * math.pi))
    return lambda x: const - (df + 1) / 2 * jnp.log1p(x[0] ** 2 / df)


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


def replications(setting: Setting, key) -> tuple[np.ndarray, np.ndarray]:
    """`(z, reliable)` of P(x > 1) and log Z in every replication (two estimates each)."""
    sampler = restore.JumpRestore(logdensity(setting.df), restore.local.RandomWalk(1.0), regeneration(setting), tour_length=3.0)
    sf = float(stats.norm.sf(1.0) if math.isinf(setting.df) else stats.t.sf(1.0, setting.df))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = restore.sample(
            sampler, key, num_lanes=REPLICATIONS * LANES, num_steps=STEPS, save=restore.SaveDraws(0), progress=False,
            observables={"tail": lambda x: (x[0] > 1.0).astype(x.dtype)[None]},
        )  # fmt: skip
        z, reliable = [], []
        for r in range(REPLICATIONS):
            lanes = slice(r * LANES, (r + 1) * LANES)
            for est, truth in ((result.estimate("tail", lanes=lanes), sf), (result.normalising_constant(lanes=lanes), 0.0)):
                z.append(float(np.ravel(est.z_score(truth))[0]))
                reliable.append(bool(np.all(est.reliable)))
    return np.array(z), np.array(reliable)


def row(setting: Setting, key) -> Row:
    """The flag's record in one setting."""
    z, reliable = replications(setting, key)
    covered = np.abs(z) < Z95
    mean = lambda a: float(np.mean(a)) if a.size else math.nan  # noqa: E731
    worst = float(np.max(np.abs(z[reliable]))) if reliable.any() else math.nan
    return Row(setting, z.size, mean(~reliable), mean(covered[reliable]), mean(covered[~reliable]), worst)


def table(seed: int = 0) -> list[Row]:
    """Every setting, each with its own fixed key."""
    return [row(s, jax.random.key(seed + i)) for i, s in enumerate(SETTINGS)]


def markdown(rows: list[Row]) -> str:
    """The table as Markdown."""
    show = lambda v, f: "-" if math.isnan(v) else format(v, f)  # noqa: E731
    lines = [
        "| target, regeneration | flagged | coverage, reliable | coverage, flagged | worst reliable \\|z\\| |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r.setting.label()} | {round(r.flagged * r.estimates)} of {r.estimates} | {show(r.reliable_coverage, '.3f')} "
            f"| {show(r.flagged_coverage, '.3f')} | {show(r.worst_reliable_z, '.2f')} |"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    print(markdown(table()))
