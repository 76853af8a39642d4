"""Do the estimates of `restore.sample` cover the truth? Coverage of 95% intervals over seeds.

On three targets with exact answers, runs `restore.sample` with `--seeds` keys and prints,
for each estimate, the share of runs whose 95% interval (estimate +- 1.96 standard
errors) covers the truth, among all runs and among those marked reliable, the median
|z| and the largest |z| of a reliable run:

1. the 10-d standard normal of `benchmark_speed.py` (Gaussian regeneration): the mean, the
   second moment and log Z;
2. the demo's 10-d mixture of three Gaussians (Student-t Laplace mixture): the mode weights
   and log Z;
3. a 1-d Student-t target (df 4) regenerated from a too-narrow Gaussian: the mean, the
   probability of `x > 1` and log Z, where some runs have heavy-tailed tours.

The script uses only the public API, so the same file can be run against another version
of the library (`PYTHONPATH=/path/to/other/checkout python examples/calibration_check.py`)
to compare the two in distribution.

Usage: python examples/calibration_check.py [--seeds 20] [--lanes 256] [--steps 1000]
"""

from __future__ import annotations

import argparse
import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import gammaln
from scipy import stats

jax.config.update("jax_enable_x64", True)

import restore  # noqa: E402
from restore.local import RandomWalk  # noqa: E402
from restore.regeneration import Gaussian, laplace_mixture  # noqa: E402
from targets.analytic import well_separated_gaussian_mixture  # noqa: E402


def _gaussian(dim: int = 10):
    def normal(x):
        return -0.5 * jnp.sum(x**2)

    sampler = restore.JumpRestore(normal, RandomWalk(0.75), Gaussian(jnp.zeros(dim), 2.25 * jnp.eye(dim)), tour_length=10.0)
    truths = {"x[0]": ("x", 0, 0.0), "x**2[0]": ("x**2", 0, 1.0), "log Z": (None, None, 0.5 * dim * math.log(2 * math.pi))}
    return sampler, None, truths


def _mixture(dim: int = 10):
    target = well_separated_gaussian_mixture(dim, 3, separation=8.0)
    starts = 6.0 * jax.random.normal(jax.random.key(0), (64, dim))
    laplace = laplace_mixture(target.logdensity, starts, tails="student_t", df=5.0, weights="equal")
    sampler = restore.JumpRestore(target.logdensity, RandomWalk(2.38 / math.sqrt(dim)), laplace, tour_length=10.0)
    observables = {"modes": lambda x: jax.nn.one_hot(target.assign_mode(x), 3)}
    weights = np.asarray(target.weights)
    truths = {f"mode {k}": ("modes", k, float(weights[k])) for k in range(3)}
    truths["log Z"] = (None, None, 0.0)
    return sampler, observables, truths


def _student_t(df: float = 4.0):
    def logdensity(x):
        return gammaln((df + 1) / 2) - gammaln(df / 2) - 0.5 * math.log(df * math.pi) - (df + 1) / 2 * jnp.log1p(x[0] ** 2 / df)

    sampler = restore.JumpRestore(logdensity, RandomWalk(1.0), Gaussian(jnp.zeros(1), 0.49), tour_length=3.0)
    observables = {"x": lambda x: x, "tail": lambda x: (x[0] > 1.0).astype(x.dtype)[None]}
    truths = {"x": ("x", 0, 0.0), "P(x > 1)": ("tail", 0, float(stats.t.sf(1.0, df))), "log Z": (None, None, 0.0)}
    return sampler, observables, truths


TARGETS = {"10-d Gaussian": _gaussian, "10-d mixture of 3": _mixture, "Student-t, poor regeneration": _student_t}


def run(seeds: int, lanes: int, steps: int) -> None:
    print(f"restore {getattr(restore, '__file__', '?')}: {seeds} seeds, {lanes} lanes x {steps} steps each")
    print(f"{'target':30s} {'estimate':10s} {'cover (all)':>12s} {'cover (rel.)':>13s} {'reliable':>9s} {'med |z|':>8s} {'max |z| rel.':>13s}")
    for name, build in TARGETS.items():
        sampler, observables, truths = build()
        z = {label: [] for label in truths}
        ok = {label: [] for label in truths}
        for seed in range(seeds):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                result = restore.sample(
                    sampler, jax.random.key(seed), num_lanes=lanes, num_steps=steps, observables=observables, progress=False, save=restore.SaveDraws(0)
                )
                for label, (obs, index, truth) in truths.items():
                    est = result.normalising_constant() if obs is None else result.estimate(obs)
                    value = np.ravel(est.value)[0 if index is None else index]
                    se = np.ravel(est.standard_error)[0 if index is None else index]
                    reliable = np.ravel(est.reliable)[0 if index is None else index]
                    z[label].append((value - truth) / se)
                    ok[label].append(bool(reliable))
        for label in truths:
            zs, rel = np.abs(np.asarray(z[label])), np.asarray(ok[label])
            inside = zs < 1.96
            cover_rel = f"{np.mean(inside[rel]):.2f}" if rel.any() else "-"
            worst = f"{np.max(zs[rel]):.2f}" if rel.any() else "-"
            print(f"{name:30s} {label:10s} {np.mean(inside):12.2f} {cover_rel:>13s} {rel.sum():>5d}/{len(rel):<3d} {np.median(zs):8.2f} {worst:>13s}")
            name = ""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--lanes", type=int, default=256)
    parser.add_argument("--steps", type=int, default=1000)
    args = parser.parse_args()
    run(args.seeds, args.lanes, args.steps)


if __name__ == "__main__":
    main()
