"""How strong are the checks of `restore.testing`? Deliberately broken kernels, and which check catches each.

On the 2-d mixture of two unequal Gaussians of `docs/how-to/validate.md` (weights 0.3 and
0.7, Student-t regeneration, mean tour length 2), jump Restore runs with a correct random
walk and with broken variants of it:

- Metropolis tests with `(p'/p)^a` for `a = 0.9, 0.8, 0.5` (they leave `p^a` invariant),
- an unadjusted random walk (every move accepted),
- MALA without its Hastings term (the proposal treated as symmetric),
- a kill rate whose constant is twice the `c_tilde` the sampler reports (`gamma = 2 c_tilde
  u / p`: still invariant, but tours last half as long as `Z / c_tilde` and `log Z` is
  off by `log 2`).

Each is put through `stationarity_test` (at its defaults, at smaller sizes, and with the
defaults it had before the log-density test and the larger reference sample were added)
and `ergodicity_test` (means, second moments, mode weights, mean tour duration and
`log Z`) at a few sizes. It prints a markdown table of the smallest p-value of each check,
and whether the check failed (`FAIL`) at its family-wise level `1e-3`.

Usage: python examples/validation_power.py [--quick]
"""

from __future__ import annotations

import argparse
import math
import time

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

import restore  # noqa: E402
from restore.local import MALA, RandomWalk, metropolis_accept  # noqa: E402
from restore.regeneration import AbstractRegeneration, StudentT  # noqa: E402
from restore.testing import ergodicity_test, stationarity_test  # noqa: E402
from targets.analytic import GaussianMixture  # noqa: E402

TARGET = GaussianMixture(
    jnp.array([[-2.5, 0.0], [2.0, 1.0]]),
    jnp.array([[[1.0, 0.3], [0.3, 0.6]], [[0.5, 0.0], [0.0, 1.5]]]),
    jnp.array([0.3, 0.7]),
)
NU = StudentT(TARGET.mean, 2.0 * TARGET.covariance, 5.0)


class TemperedWalk(RandomWalk):
    """Broken: a random walk whose Metropolis test uses `(p'/p)^power` (invariant for `p^power`)."""

    power: float

    def __init__(self, scale: float, power: float):
        super().__init__(scale)
        self.power = power

    def accept(self, key, point, candidate, aux):
        return metropolis_accept(key, point, candidate, self.power * (candidate.logdensity - point.logdensity))


class MALAWithoutHastings(MALA):
    """Broken: MALA's Langevin proposal accepted as if it were symmetric."""

    def accept(self, key, point, candidate, aux):
        return metropolis_accept(key, point, candidate, candidate.logdensity - point.logdensity)


class ScaledReference(AbstractRegeneration):
    """Broken: draws like `base` but reports `factor * u`, so the kill rate is `factor` times too large."""

    base: AbstractRegeneration
    log_factor: float
    dim: int

    def __init__(self, base: AbstractRegeneration, factor: float):
        self.base, self.log_factor, self.dim = base, math.log(factor), base.dim

    def sample(self, key, shape=()):
        return self.base.sample(key, shape)

    def log_prob(self, x):
        return self.base.log_prob(x) + self.log_factor


def samplers() -> dict[str, restore.JumpRestore]:
    log_rate = restore.JumpRestore(TARGET.logdensity, RandomWalk(1.0), NU, tour_length=2.0).calibrate(jax.random.key(0))[0].log_rate
    make = lambda local, nu=NU: restore.JumpRestore(TARGET.logdensity, local, nu, log_rate=log_rate)  # noqa: E731
    return {
        "correct random walk": make(RandomWalk(1.0)),
        "acceptance (p'/p)^0.9": make(TemperedWalk(1.0, 0.9)),
        "acceptance (p'/p)^0.8": make(TemperedWalk(1.0, 0.8)),
        "acceptance (p'/p)^0.5": make(TemperedWalk(1.0, 0.5)),
        "unadjusted random walk": make(TemperedWalk(1.0, 0.0)),
        "MALA without Hastings term": make(MALAWithoutHastings(0.5)),
        "kill-rate constant x2": make(RandomWalk(1.0), ScaledReference(NU, 2.0)),
    }


def stationarity(sampler, lanes: int, **kwargs) -> restore.testing.CheckReport:
    return stationarity_test(sampler, jax.random.key(1), TARGET.sample, num_lanes=lanes, time=5.0, **kwargs)


def ergodicity(sampler, lanes: int, steps: int) -> restore.testing.CheckReport:
    second = np.diag(np.asarray(TARGET.covariance)) + np.asarray(TARGET.mean) ** 2
    truths = {
        "x": (lambda x: x, TARGET.mean),
        "x**2": (lambda x: x**2, second),
        "modes": (lambda x: jax.nn.one_hot(TARGET.assign_mode(x), 2, dtype=x.dtype), TARGET.weights),
    }
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return ergodicity_test(sampler, jax.random.key(2), truths, num_lanes=lanes, num_steps=steps, log_z=0.0)


def cell(report) -> str:
    return f"{report.min_p_value:.1e}" + (" **FAIL**" if not report.passed else "")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer sizes (a smoke test)")
    args = parser.parse_args()
    lane_sizes = [2_000, 20_000] if args.quick else [1_000, 2_000, 5_000, 20_000]
    ergodic_sizes = [(64, 1_000)] if args.quick else [(64, 1_000), (512, 1_000)]

    columns = ["stationarity, previous defaults (20,000 lanes)"]
    columns += [f"stationarity, {n:,} lanes" for n in lane_sizes]
    columns += [f"ergodicity, {lanes} x {steps:,}" for lanes, steps in ergodic_sizes]
    print("| kernel | " + " | ".join(columns) + " |")
    print("|---" * (len(columns) + 1) + "|")
    start = time.perf_counter()
    for name, sampler in samplers().items():
        cells = [cell(stationarity(sampler, 20_000, logdensity=False, reference_factor=1))]
        cells += [cell(stationarity(sampler, n)) for n in lane_sizes]
        cells += [cell(ergodicity(sampler, lanes, steps)) for lanes, steps in ergodic_sizes]
        print(f"| {name} | " + " | ".join(cells) + " |", flush=True)
    print(f"\nsmallest p-value of each check; FAIL: rejected at family-wise level 1e-3 ({time.perf_counter() - start:.0f} s)")
    print(
        "stationarity: time 5, KS on 2 coordinates, 4 random projections and (new) log p, 10x reference draws (new); "
        "ergodicity: means, second moments, mode weights, mean tour duration = Z / c_tilde, log Z (tours)"
    )


if __name__ == "__main__":
    main()
