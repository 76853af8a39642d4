"""Core benchmark: jump Restore overhead per evaluation, and its error against the MH baseline.

Prints ratios measured side by side in one run (medians over repeats or seeds):

1. jump Restore density evaluations per second over raw `jit(vmap(logdensity))`
   evaluations per second on the same batch (one evaluation per step is the limit);
2. RMSE of the mode-weight estimates, jump Restore over the MH mixture baseline with the
   same random-walk kernel and the same large-step distribution, at equal evaluations.

Usage: python examples/benchmark_core.py [--seeds 5] [--lanes 512] [--steps 1500]
"""

from __future__ import annotations

import argparse
import platform
import warnings

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import restore  # noqa: E402
from restore.bench import raw_rate  # noqa: E402  (re-exported for benchmark_general)
from restore.local import RandomWalk  # noqa: E402
from restore.regeneration import laplace_mixture  # noqa: E402
from targets.analytic import well_separated_gaussian_mixture  # noqa: E402


def sampler_rate(sampler, lanes: int, steps: int, repeats: int) -> float:
    """Evaluations (= steps) per second of restore.sample, compilation excluded (the open tours
    are dropped, so the runs warn that their tour-based estimates lean; this measures speed)."""
    kwargs = dict(num_lanes=lanes, num_steps=steps, progress=False, save=restore.SaveDraws(0), num_chunks=1, finish_tours=False)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", restore.UnreliableEstimateWarning)
        restore.sample(sampler, jax.random.key(0), **kwargs)  # compile
        times = [restore.sample(sampler, jax.random.key(i + 1), **kwargs).wall_time for i in range(repeats)]
    return lanes * steps / float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--lanes", type=int, default=512)
    parser.add_argument("--steps", type=int, default=1500)
    parser.add_argument("--dim", type=int, default=10)
    parser.add_argument("--tour-length", type=float, default=10.0)
    args = parser.parse_args()

    target = well_separated_gaussian_mixture(args.dim, 3, separation=8.0)
    starts = 6.0 * jax.random.normal(jax.random.key(0), (64, args.dim))
    nu = laplace_mixture(target.logdensity, starts, tails="student_t", df=5.0, weights="equal")
    local = RandomWalk(2.38 / np.sqrt(args.dim))
    jr = restore.JumpRestore(target.logdensity, local, nu, tour_length=args.tour_length).calibrate(jax.random.key(99))[0]
    mh = restore.MixtureMH(target.logdensity, local, nu, large_step_probability=1.0 / args.tour_length)
    print(f"machine: {platform.processor() or platform.machine()}, {jax.device_count()} {jax.default_backend()} device(s), jax {jax.__version__}")
    print(f"target: {args.dim}-d mixture of 3 Gaussians, weights {np.round(np.asarray(target.weights), 4).tolist()}")

    x0 = target.sample(jax.random.key(1), args.lanes)
    raw = raw_rate(target.logdensity, x0, args.steps, repeats=3)
    ours = sampler_rate(jr, args.lanes, args.steps, repeats=3)
    base = sampler_rate(mh, args.lanes, args.steps, repeats=3)
    print("\n1. evaluations per second (median of 3, compilation excluded)")
    print(f"   raw jit(vmap(logdensity)): {raw:,.0f}/s   jump Restore: {ours:,.0f}/s   MH mixture: {base:,.0f}/s")
    print(f"   jump Restore / raw = {ours / raw:.3f}   (goal >= 0.5)")

    one_hot = lambda x: jax.nn.one_hot(target.assign_mode(x), 3, dtype=x.dtype)  # noqa: E731
    truth = np.asarray(target.weights)
    errors = {"restore": [], "mh": []}
    for seed in range(args.seeds):
        for name, sampler in (("restore", jr), ("mh", mh)):
            result = restore.sample(
                sampler, jax.random.key(1000 + seed), num_lanes=args.lanes, num_steps=args.steps,
                observables={"modes": one_hot}, progress=False, save=restore.SaveDraws(0),
            )
            errors[name].append(np.sqrt(np.mean((result.estimate("modes").value - truth) ** 2)))
    r, m = np.asarray(errors["restore"]), np.asarray(errors["mh"])
    print(f"\n2. RMSE of mode weights at {args.lanes * args.steps:,} evaluations each, {args.seeds} seeds")
    print(f"   jump Restore: {np.round(r, 4).tolist()}")
    print(f"   MH mixture:   {np.round(m, 4).tolist()}")
    pooled = np.sqrt(np.mean(r**2)) / np.sqrt(np.mean(m**2))
    print(f"   root-mean-square over seeds, Restore / MH = {pooled:.3f}   (goal <= 0.8)")
    print(f"   median of per-seed ratios = {np.median(r / m):.3f}")


if __name__ == "__main__":
    main()
