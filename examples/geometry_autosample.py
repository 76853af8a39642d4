"""`restore.autosample` on correlated and ill-conditioned targets with an exact `log Z`.

Four instances, each with fixed seeds and the box a user would state:

- `gauss50`: a 50-d Gaussian whose covariance has eigenvalues log-spaced over [1e-2, 1e2]
  (condition number 1e4) under a random rotation, log density shifted so that `log Z = 2.5`;
- `manywell16`: the 16-d Many Well (`targets.analytic.ManyWell`) seen through a random
  rotation, `x -> Q^T x` (the rotation keeps `log Z`);
- `banana10`: Haario's 10-d twisted Gaussian (b = 0.1, scale 10; `log Z = 0`), box +-50;
- `funnel10`: Neal's 10-d funnel (scale 3; `log Z = 0`), box +-6.

Each is run with `autosample`'s defaults (1,024 lanes, 1,000 steps); the script prints the
`log Z` error, its standard error, `|error| / SE`, whether the estimate is marked reliable, the
worst moment z-score (of `x` and `x**2` against the exact moments; then the worst among the
moments marked reliable, and how many are marked unreliable), the stages and the wall time.

With `--smc`, BlackJAX adaptive tempered SMC (4,096 particles, HMC moves, from the uniform
prior on the same box; `restore.bench.TemperedSMCRunner`, as the evidence benchmark runs it)
runs beside it on each problem, the peer a user would pick for `log Z`: its error and
worst mean error are printed on a line of their own (one run gives SMC no standard error,
so its moment errors are in units of the exact standard deviation). With `--nuts`,
BlackJAX NUTS after its window adaptation (4 chains from uniform starts in the box, 1,000
warm-up and 1,000 kept steps each, a dense mass matrix), the peer a user would pick for
moments: its worst mean error in exact standard deviations, gradient evaluations and wall
time (NUTS gives no `log Z`).

Usage: python examples/geometry_autosample.py [--problems gauss50,manywell16,banana10,funnel10] [--seed 0] [--smc] [--nuts]
"""

from __future__ import annotations

import argparse
import math
import time
import warnings

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import restore  # noqa: E402
from targets.analytic import random_rotation  # noqa: E402


def gauss50():
    """The rotated ill-conditioned Gaussian: log density, box, log Z, mean, second moment."""
    d, log_z = 50, 2.5
    q = random_rotation(d, 11)
    cov = q @ np.diag(np.logspace(-2, 2, d)) @ q.T
    mean = np.random.default_rng(12).uniform(-3, 3, d)
    precision = jnp.asarray(np.linalg.inv(cov))
    constant = log_z - 0.5 * np.linalg.slogdet(2 * math.pi * cov)[1]
    m = jnp.asarray(mean)

    def logdensity(x):
        r = x - m
        return -0.5 * r @ precision @ r + constant

    return logdensity, 40.0, log_z, mean, np.diag(cov) + mean**2


def manywell16():
    """The rotated 16-d Many Well: log density, box, log Z, mean, second moment."""
    from targets.analytic import ManyWell

    target = ManyWell(16)
    q = random_rotation(16, 21)
    qj = jnp.asarray(q)
    mean = q @ np.asarray(target.mean, np.float64)
    cov = q @ np.asarray(target.covariance, np.float64) @ q.T
    logdensity = lambda x: target.logdensity(qj.T @ x)  # noqa: E731
    return logdensity, 8.0, float(target.log_normalising_constant), mean, np.diag(cov) + mean**2


def banana10():
    """Haario's 10-d twisted Gaussian (`targets.analytic.Banana`, b = 0.1, scale 10): a curved ridge."""
    from targets.analytic import Banana

    target = Banana(10, curvature=0.1, scale=10.0)
    cov = np.asarray(target.covariance, np.float64)
    return target.logdensity, 50.0, 0.0, np.zeros(10), np.diag(cov)


def funnel10():
    """Neal's 10-d funnel (`targets.analytic.Funnel`, scale 3): scales that change by orders of magnitude.

    The second moments of `x_1..x_9` have no finite variance under the target (their fourth
    moments are `3 exp(2 scale^2)`-sized), so only `x` and `v = x_0`'s second moment are checked."""
    from targets.analytic import Funnel

    target = Funnel(10, scale=3.0)
    second = np.full(10, np.nan)
    second[0] = 9.0
    return target.logdensity, 6.0, 0.0, np.zeros(10), second


PROBLEMS = {"gauss50": gauss50, "manywell16": manywell16, "banana10": banana10, "funnel10": funnel10}


def _sd(mean: np.ndarray, second: np.ndarray) -> np.ndarray:
    """The target's standard deviations from its exact first and second moments."""
    return np.sqrt(np.maximum(second - mean**2, 1e-300))


def run(name: str, seed: int) -> dict:
    logdensity, half, log_z, mean, second = PROBLEMS[name]()
    d = mean.shape[0]
    clock = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = restore.autosample(logdensity, jax.random.key(seed), box=(-half, half), dim=d, progress=False)
        estimate = out.normalising_constant()
        first, second_moment = out.estimate("x"), out.estimate("x**2")
        z_mean = np.asarray(first.z_score(mean))
        z_second = np.asarray(second_moment.z_score(np.nan_to_num(second)))
        z_second = np.where(np.isnan(second), np.nan, z_second)  # moments left unchecked
        z = np.abs(np.concatenate([z_mean, z_second]))
        trusted = np.concatenate([np.broadcast_to(first.reliable, z_mean.shape), np.broadcast_to(second_moment.reliable, z_second.shape)])
    seconds = time.perf_counter() - clock
    error, se = float(estimate.value) - log_z, float(estimate.standard_error)
    return dict(
        problem=name, seed=seed, error=error, se=se, z=abs(error) / se, reliable=bool(estimate.reliable),
        moment_z=float(np.nanmax(z)), reliable_moment_z=float(np.nanmax(np.where(trusted, z, np.nan), initial=0.0)),
        unreliable_moments=int(np.sum(~trusted & ~np.isnan(z))), seconds=seconds,
        mean_sd=float(np.nanmax(np.abs(np.asarray(first.value) - mean) / _sd(mean, second))),
        stages=len(out.stages) - 2, final=f"{out.stages[-1].family} x{out.stages[-1].num_components}",
        evaluations=out.evaluations, healthy=out.healthy,
    )


class _BoxProblem:
    """What `restore.bench.TemperedSMCRunner` reads of a problem: the log density, the box, its uniform points."""

    def __init__(self, name: str, logdensity, half: float, d: int):
        self.name, self.logdensity, self.dim, self.hmc_steps, self.has_wells = name, logdensity, d, 10, False
        self.box = (np.full(d, -half), np.full(d, half))
        self.log_box_volume = float(d * math.log(2 * half))

    def uniform_points(self, key, n: int):
        return jax.random.uniform(key, (int(n), self.dim), minval=-self.box[1][0], maxval=self.box[1][0])


def run_smc(name: str, seed: int) -> dict:
    """Tempered SMC on the same problem and box: `log Z` error, worst moment error (in exact
    standard deviations: one run has no standard error), evaluations and wall time."""
    from restore.bench import TemperedSMCRunner

    logdensity, half, log_z, mean, second = PROBLEMS[name]()
    d = mean.shape[0]
    clock = time.perf_counter()
    out = TemperedSMCRunner(4096).run(_BoxProblem(name, logdensity, half, d), jax.random.key(seed))
    seconds = time.perf_counter() - clock
    sd = _sd(mean, second)
    moment_sd = np.abs(np.asarray(out.mean) - mean) / sd
    return dict(error=out.log_z - log_z, moment_sd=float(np.nanmax(moment_sd)), evaluations=out.evaluations, seconds=seconds,
                notes=out.notes)


def run_nuts(name: str, seed: int, chains: int = 4, warmup: int = 1000, kept: int = 1000) -> dict:
    """BlackJAX NUTS with window adaptation (dense mass matrix), `chains` chains from uniform starts
    in the box (`restore.bench.NUTSRunner`): worst mean error in exact standard deviations,
    gradient evaluations, wall time."""
    from restore.bench import NUTSRunner

    logdensity, half, _, mean, second = PROBLEMS[name]()
    d = mean.shape[0]
    clock = time.perf_counter()
    out = NUTSRunner(chains, warmup, kept).run(_BoxProblem(name, logdensity, half, d), jax.random.key(seed))
    seconds = time.perf_counter() - clock
    moment_sd = np.abs(np.asarray(out.mean) - mean) / _sd(mean, second)
    return dict(moment_sd=float(np.nanmax(moment_sd)), evaluations=out.evaluations, seconds=seconds)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--problems", default="gauss50,manywell16,banana10,funnel10")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--smc", action="store_true", help="run tempered SMC beside autosample")
    parser.add_argument("--nuts", action="store_true", help="run BlackJAX NUTS beside autosample")
    args = parser.parse_args()
    print("problem     seed  log Z error       SE   |err|/SE  reliable  worst moment z (reliable ones; unreliable)  stages  final regeneration         evaluations  wall s")
    for name in args.problems.split(","):
        r = run(name, args.seed)
        print(
            f"{r['problem']:<11} {r['seed']:>4} {r['error']:>+12.4f} {r['se']:>8.4f} {r['z']:>10.1f}  {str(r['reliable']):<8}"
            f"  {r['moment_z']:>14.1f} ({r['reliable_moment_z']:.1f}; {r['unreliable_moments']:>2})          {r['stages']:>6}  {r['final']:<26} {r['evaluations']:>11,}  {r['seconds']:>6.1f}",
            flush=True,
        )
        print(f"{'':<11} {'':>4} {'':>12}  (worst mean error {r['mean_sd']:.3f} sd)", flush=True)
        if args.smc:
            m = run_smc(name, args.seed)
            print(f"{'  smc-hmc':<11} {args.seed:>4} {m['error']:>+12.4f}  (worst mean error {m['moment_sd']:.3f} sd)"
                  f"  {m['evaluations']:>11,} evaluations  {m['seconds']:>6.1f} s  {m['notes']}", flush=True)
        if args.nuts:
            m = run_nuts(name, args.seed)
            print(f"{'  nuts':<11} {args.seed:>4} {'(no log Z)':>12}  (worst mean error {m['moment_sd']:.3f} sd)"
                  f"  {m['evaluations']:>11,} gradient evaluations  {m['seconds']:>6.1f} s (compilation included)", flush=True)


if __name__ == "__main__":
    main()
