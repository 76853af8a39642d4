"""General-layer benchmark: the cost of Brownian Restore against its thinning bound, and jump
Restore's overhead on the general layer.

Prints, measured side by side in one run:

1. Brownian-motion Restore on `N(0, S)` (the published example, `log c_tilde = 2.07`) for a
   range of thinning bounds `Gamma`: wall time per unit of simulated time (it grows with
   `Gamma`: one density, gradient and Hessian evaluation per candidate event), the share
   of candidate events that kill, the share that violate the bound, and the error of the
   second moments.
2. Jump Restore density evaluations per second over raw `jit(vmap(logdensity))` on the
   10-d mixture of `benchmark_core.py` (the general layer must not slow it down).

Usage: python examples/benchmark_general.py [--lanes 256] [--steps 4000]
"""

from __future__ import annotations

import argparse
import platform
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)
sys.path.insert(0, str(Path(__file__).parent))

from benchmark_core import raw_rate, sampler_rate

import restore
from restore.dynamics import BrownianMotion
from restore.local import RandomWalk
from restore.regeneration import Gaussian, laplace_mixture
from targets.analytic import well_separated_gaussian_mixture

S = np.array([[1.2, 0.4], [0.4, 0.8]])
PRECISION = jnp.asarray(np.linalg.inv(S))


def logdensity(x):
    return -0.5 * x @ PRECISION @ x


def brownian_row(bound: float, lanes: int, steps: int, repeats: int) -> dict:
    process = restore.Restore(logdensity, BrownianMotion(), Gaussian(jnp.zeros(2), jnp.eye(2)), log_rate=2.07, bound=bound)
    kwargs = dict(num_lanes=lanes, num_steps=steps, progress=False, save=restore.SaveDraws(0), num_chunks=1, finish_tours=False)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        restore.sample(process, jax.random.key(0), **kwargs)  # compile
        results = [restore.sample(process, jax.random.key(i + 1), **kwargs) for i in range(repeats)]
    walls = np.array([r.wall_time for r in results])
    simulated = np.array([float(np.sum(r.sums.all_t)) for r in results])
    last = results[-1]
    candidates = lanes * steps - int(np.sum(last.sums.num_iw))  # steps that drew a tour start are not candidates
    second = last.estimate("x**2", method="lanes")
    error = np.sqrt(np.mean((second.value - np.diag(S)) ** 2))
    return {
        "bound": bound,
        "seconds per unit time per lane": float(np.median(walls / simulated)),
        "kill share": int(np.sum(last.sums.num_regenerations)) / candidates,
        "violation share": last.num_bound_exceeded / candidates,
        "max gamma/Gamma": last.max_bound_ratio,
        "rmse second moments": float(error),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lanes", type=int, default=256)
    parser.add_argument("--steps", type=int, default=4000)
    parser.add_argument("--bounds", type=float, nargs="+", default=[10.0, 30.0, 100.0, 300.0, 1000.0])
    args = parser.parse_args()
    print(f"machine: {platform.processor() or platform.machine()}, {jax.device_count()} {jax.default_backend()} device(s), jax {jax.__version__}")

    print(f"\n1. Brownian Restore on N(0, S), log c_tilde = 2.07, {args.lanes} lanes x {args.steps} steps, median of 3")
    header = ["bound", "seconds per unit time per lane", "kill share", "violation share", "max gamma/Gamma", "rmse second moments"]
    print("   " + " | ".join(header))
    rows = [brownian_row(b, args.lanes, args.steps, 3) for b in args.bounds]
    for row in rows:
        print("   " + " | ".join(f"{row[h]:.4g}" for h in header))
    base = rows[0]["seconds per unit time per lane"]
    print("   cost per unit time relative to the smallest bound: " + ", ".join(f"{r['seconds per unit time per lane'] / base:.2f}" for r in rows))

    target = well_separated_gaussian_mixture(10, 3, separation=8.0)
    starts = 6.0 * jax.random.normal(jax.random.key(0), (64, 10))
    nu = laplace_mixture(target.logdensity, starts, tails="student_t", df=5.0, weights="equal")
    jr = restore.JumpRestore(target.logdensity, RandomWalk(2.38 / np.sqrt(10)), nu, tour_length=10.0).calibrate(jax.random.key(99))[0]
    x0 = target.sample(jax.random.key(1), 512)
    raw = raw_rate(target.logdensity, x0, 1500, repeats=3)
    ours = sampler_rate(jr, 512, 1500, repeats=3)
    print("\n2. jump Restore on the general layer, 10-d mixture, 512 lanes x 1500 steps (median of 3)")
    print(f"   raw jit(vmap(logdensity)): {raw:,.0f}/s   jump Restore: {ours:,.0f}/s   ratio {ours / raw:.4f}")


if __name__ == "__main__":
    main()
