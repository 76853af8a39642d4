"""Speed of the core against BlackJAX RMH, side by side in one run.

For each set-up, on the same target with the same number of lanes and steps and the same
random-walk scale, it measures (compilation excluded from the rates; the contenders run
round-robin, and each ratio is the median over rounds of the same round's ratio, so a
load change on a shared machine hits all of them alike):

- BlackJAX RMH: `lax.scan` over `vmap(step)`, keeping a running sum of positions (the
  yardstick: the cheapest useful MCMC loop), and the same on `restore.unrolled_keys` (the
  keys restore's loops draw with: JAX's bits, the hash unrolled), to show how much of
  restore's speed is the keys;
- the bare jump-Restore step: `lax.scan` over `JumpRestore.step_lanes` (`vmap(step)`, with
  the next tours' starts drawn for the killed lanes only) with a running Rao-Blackwellised
  sum, on unrolled keys (the step alone, without the driver);
- `restore.sample` with `JumpRestore` (everything a user gets: the streamed tour sums,
  the tour histogram and tail records, default observables `x` and `x**2`);
- the same as a user calls it, with default arguments (50 chunks for the progress bar,
  thinned draws kept), timed over the whole call (the pilot and set-up included);
- `restore.sample` with `MixtureMH` (the Metropolis baseline with the same large step);

and prints steps per second, the ratio to BlackJAX, and the time to the first result of
one call (tracing, compilation, the pilot) against BlackJAX's compilation time. BlackJAX
runs first in each set-up, so the process's one-time start-up is charged to it.

Then a lanes sweep (set-up 1 at 512, 8,192 and 65,536 lanes, the same number of
lane-steps each: 512 x 12,800, 8,192 x 800, 65,536 x 100), which shows any cost that grows
with the lanes (host work between chunks, say): BlackJAX RMH, the bare step,
`restore.sample` for the budget's steps alone (`finish_tours=False`) and with its open
tours finished after the budget (`num_chunks=1, save=restore.SaveDraws(0)`, as the ratios of set-up 1),
the steps the finishing took, and the finished run's `log Z` error against the exact value.
`--sweep-only` runs the sweep alone, `--no-sweep` skips it.

`--sweep-lanes` and `--lane-steps` change the sweep's sizes (a GPU needs more lanes and
lane-steps than a CPU before its fixed costs stop dominating).

Usage: python examples/benchmark_speed.py [--lanes 512] [--steps 1500] [--dim 10] [--rounds 5] [--sweep-only | --no-sweep]
       [--sweep-lanes 512,8192,65536] [--lane-steps 6553600]
"""

from __future__ import annotations

import argparse
import math
import platform
import time
import warnings
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

import blackjax  # noqa: E402

import restore  # noqa: E402
from restore.local import RandomWalk  # noqa: E402
from restore.regeneration import Gaussian, laplace_mixture  # noqa: E402
from targets.analytic import well_separated_gaussian_mixture  # noqa: E402


class Contender(NamedTuple):
    """A prepared (compiled) run: `once(i)` runs it with key `i` and returns its seconds."""

    once: Callable[[int], float]
    compile_seconds: float


def blackjax_rmh(logdensity, scale: float, x0, steps: int, unrolled: bool = False) -> Contender:
    """BlackJAX's Gaussian random-walk Metropolis in a scan, with a running sum of positions
    (`unrolled`: on `restore.unrolled_keys`, the same draws as JAX's keys, as restore's loop runs)."""
    lanes, dim = x0.shape
    rmh = blackjax.additive_step_random_walk.normal_random_walk(logdensity, scale * jnp.ones(dim))

    def run(key, x0):
        key = restore.unrolled_keys(key) if unrolled else key

        def body(carry, key):
            states, total = carry
            states, _ = jax.vmap(rmh.step)(jax.random.split(key, lanes), states)
            return (states, total + states.position), None

        start = (jax.vmap(rmh.init)(x0), jnp.zeros_like(x0))
        return jax.lax.scan(body, start, jax.random.split(key, steps))[0][1]

    return _compiled(run, x0)


def bare_restore_step(sampler, lanes: int, steps: int) -> Contender:
    """`JumpRestore.step_lanes` in a scan, with a Rao-Blackwellised running sum, on
    `restore.unrolled_keys` (as `restore.sample` runs it)."""
    states = jax.vmap(sampler.init)(jax.random.split(jax.random.key(0), lanes))

    def run(key, states):
        key = restore.unrolled_keys(key)

        def body(carry, key):
            states, total = carry
            states, info = sampler.step_lanes(jax.random.split(key, lanes), states)
            return (states, total + info.expected_holding_time[:, None] * info.position), None

        start = (states, jnp.zeros_like(states.position))
        return jax.lax.scan(body, start, jax.random.split(key, steps))[0][1]

    return _compiled(run, states)


def _compiled(run, argument) -> Contender:
    start = time.perf_counter()
    compiled = jax.jit(run).lower(jax.random.key(0), argument).compile()
    compile_seconds = time.perf_counter() - start
    jax.block_until_ready(compiled(jax.random.key(0), argument))

    def once(i: int) -> float:
        start = time.perf_counter()
        jax.block_until_ready(compiled(jax.random.key(i), argument))
        return time.perf_counter() - start

    return Contender(once, compile_seconds)


def restore_sample(sampler, lanes: int, steps: int) -> Contender:
    """`restore.sample`'s run time (`wall_time`), and its first call's extra seconds: the whole
    first call minus the whole second one (tracing, compilation, the pilot)."""
    kwargs = dict(num_lanes=lanes, num_steps=steps, progress=False, save=restore.SaveDraws(0), num_chunks=1)
    calls = []
    for i in range(2):
        start = time.perf_counter()
        restore.sample(sampler, jax.random.key(i), **kwargs)
        calls.append(time.perf_counter() - start)
    return Contender(lambda i: restore.sample(sampler, jax.random.key(i), **kwargs).wall_time, calls[0] - calls[1])


def restore_sample_budget(sampler, lanes: int, steps: int) -> Contender:
    """`restore.sample` for the budget's steps alone: the open tours are dropped, not finished
    (the estimates of such a run lean towards short tours; this measures the loop)."""
    kwargs = dict(num_lanes=lanes, num_steps=steps, progress=False, save=restore.SaveDraws(0), num_chunks=1, finish_tours=False)
    restore.sample(sampler, jax.random.key(0), **kwargs)
    return Contender(lambda i: restore.sample(sampler, jax.random.key(i), **kwargs).wall_time, math.nan)


def restore_sample_defaults(sampler, lanes: int, steps: int) -> Contender:
    """A whole repeated `restore.sample` call with its default arguments (50 chunks, thinned draws
    kept, a progress report per chunk), as a user makes it: pilot, set-up and run included."""
    kwargs = dict(num_lanes=lanes, num_steps=steps, progress=False)

    def once(i: int) -> float:
        start = time.perf_counter()
        restore.sample(sampler, jax.random.key(i), **kwargs)
        return time.perf_counter() - start

    first = once(0)
    return Contender(once, first - once(1))


def report(name: str, contenders: dict[str, Contender], work: int, rounds: int) -> None:
    """Time the contenders round-robin, `rounds` times each, so that the machine's load changes
    hit all of them alike; the ratios are medians over rounds of same-round ratios."""
    times = {label: [] for label in contenders}
    for r in range(rounds):
        for label, contender in contenders.items():
            times[label].append(contender.once(r + 2))
    base = np.asarray(times["BlackJAX RMH"])
    base_compile = contenders["BlackJAX RMH"].compile_seconds
    print(f"\n{name}")
    print(f"{'':38s} {'M steps/s':>10s} {'/ BlackJAX':>11s} {'compile s':>10s} {'/ BlackJAX':>11s}")
    for label, contender in contenders.items():
        seconds = np.asarray(times[label])
        rate, ratio = work / float(np.median(seconds)), float(np.median(base / seconds))
        compile_seconds = contender.compile_seconds
        print(f"{label:38s} {rate / 1e6:10.3f} {ratio:11.2f} {compile_seconds:10.2f} {compile_seconds / base_compile:11.2f}")


def lanes_sweep(dim: int, rounds: int, lane_steps: int = 6_553_600, lanes_list: tuple[int, ...] = (512, 8192, 65536)) -> None:
    """Set-up 1 at each of `lanes_list` lanes, the same lane-steps each (module docstring).

    Runs that drop their open tours, or whose tours outlast 100 finishing steps, warn that
    their estimates lean or are unreliable; those warnings are silenced here (this measures speed)."""
    warnings.filterwarnings("ignore", category=restore.UnreliableEstimateWarning)
    warnings.filterwarnings("ignore", message=".*still had an open tour.*")
    jump = _setup_one(dim)
    print(f"\n3. lanes sweep: set-up 1, {lane_steps:,} lane-steps per run, rounds of {rounds}")
    print(f"{'lanes x steps':>16s} {'':31s} {'M steps/s':>10s} {'/ BlackJAX':>11s}")
    ratios = {}
    for lanes in lanes_list:
        steps = lane_steps // lanes
        x0 = jax.random.normal(jax.random.key(1), (lanes, dim))
        contenders = {
            "BlackJAX RMH": blackjax_rmh(_normal, 0.75, x0, steps),
            "JumpRestore step (no driver)": bare_restore_step(jump.calibrate(jax.random.key(9))[0], lanes, steps),
            "restore.sample, budget only": restore_sample_budget(jump, lanes, steps),
            "restore.sample": restore_sample(jump, lanes, steps),
        }
        times = {label: [] for label in contenders}
        for r in range(rounds):
            for label, contender in contenders.items():
                times[label].append(contender.once(r + 2))
        base = np.asarray(times["BlackJAX RMH"])
        finishing = restore.sample(jump, jax.random.key(1), num_lanes=lanes, num_steps=steps, progress=False, save=restore.SaveDraws(0), num_chunks=1)
        for label in contenders:
            seconds = np.asarray(times[label])
            ratio = float(np.median(base / seconds))
            ratios[lanes, label] = ratio
            size = f"{lanes:,} x {steps:,}" if label == "BlackJAX RMH" else "."
            print(f"{size:>16s} {label:31s} {lanes * steps / float(np.median(seconds)) / 1e6:10.3f} {ratio:11.2f}")
        print(f"{'':16s} finishing after the budget: {finishing.finishing_steps} steps, {finishing.unfinished_tours} tours still open")
        log_z, exact = finishing.normalising_constant(), 0.5 * dim * math.log(2 * math.pi)
        verdict = "reliable" if log_z.reliable else "UNRELIABLE"
        print(f"{'':16s} its log Z: error {log_z.value - exact:+.4f} ({(log_z.value - exact) / log_z.standard_error:+.1f} SE), {verdict}")
    most, fewest = max(lanes_list), min(lanes_list)
    for label in ("restore.sample, budget only", "restore.sample"):
        print(f"{label}: ratio at {most:,} lanes / ratio at {fewest:,} lanes = {ratios[most, label] / ratios[fewest, label]:.2f}")


def _normal(x):
    return -0.5 * jnp.sum(x**2)


def _setup_one(dim: int):
    """Set-up 1's sampler: standard normal target, Gaussian(0, 2.25 I) regeneration, RandomWalk(0.75), T = 10."""
    return restore.JumpRestore(_normal, RandomWalk(0.75), Gaussian(jnp.zeros(dim), 2.25 * jnp.eye(dim)), tour_length=10.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lanes", type=int, default=512)
    parser.add_argument("--steps", type=int, default=1500)
    parser.add_argument("--dim", type=int, default=10)
    parser.add_argument("--rounds", type=int, default=5)
    sweep = parser.add_mutually_exclusive_group()
    sweep.add_argument("--sweep-only", action="store_true", help="run the lanes sweep alone")
    sweep.add_argument("--no-sweep", action="store_true", help="skip the lanes sweep")
    parser.add_argument("--sweep-lanes", default="512,8192,65536", help="the sweep's lane counts, comma-separated")
    parser.add_argument("--lane-steps", type=int, default=6_553_600, help="lanes x steps of each run of the sweep")
    args = parser.parse_args()
    sweep_lanes = tuple(int(n) for n in args.sweep_lanes.split(","))
    lanes, steps, dim, rounds = args.lanes, args.steps, args.dim, args.rounds
    print(f"machine: {platform.processor() or platform.machine()}, {jax.device_count()} {jax.default_backend()} device(s), jax {jax.__version__}")
    if args.sweep_only:
        lanes_sweep(dim, min(rounds, 3), args.lane_steps, sweep_lanes)
        return
    print(f"{lanes} lanes x {steps} steps, {dim}-d, float64; compile s: BlackJAX's jit compilation, "
          "restore.sample's first call minus its run time (tracing, compilation, pilot)")

    normal = _normal
    gaussian = Gaussian(jnp.zeros(dim), 2.25 * jnp.eye(dim))
    local = RandomWalk(0.75)
    jump = _setup_one(dim)
    x0 = jax.random.normal(jax.random.key(1), (lanes, dim))
    report(
        "1. standard normal target, Gaussian(0, 2.25 I) regeneration, RandomWalk(0.75), T = 10",
        {
            "BlackJAX RMH": blackjax_rmh(normal, 0.75, x0, steps),
            "  the same, on restore.unrolled_keys": blackjax_rmh(normal, 0.75, x0, steps, unrolled=True),
            "JumpRestore step (no driver)": bare_restore_step(jump.calibrate(jax.random.key(9))[0], lanes, steps),
            "restore.sample(JumpRestore)": restore_sample(jump, lanes, steps),
            "  the same, default arguments": restore_sample_defaults(jump, lanes, steps),
            "restore.sample(MixtureMH)": restore_sample(
                restore.MixtureMH(normal, local, gaussian, large_step_probability=0.1), lanes, steps
            ),
        },
        lanes * steps,
        rounds,
    )

    target = well_separated_gaussian_mixture(dim, 3, separation=8.0)
    starts = 6.0 * jax.random.normal(jax.random.key(0), (64, dim))
    laplace = laplace_mixture(target.logdensity, starts, tails="student_t", df=5.0, weights="equal")
    scale = 2.38 / np.sqrt(dim)
    demo = restore.JumpRestore(target.logdensity, RandomWalk(scale), laplace, tour_length=10.0)
    x0 = target.sample(jax.random.key(1), lanes)
    report(
        f"2. the demo: 3-mode Gaussian mixture, Student-t Laplace mixture ({len(laplace.components)} components), T = 10",
        {
            "BlackJAX RMH": blackjax_rmh(target.logdensity, scale, x0, steps),
            "  the same, on restore.unrolled_keys": blackjax_rmh(target.logdensity, scale, x0, steps, unrolled=True),
            "JumpRestore step (no driver)": bare_restore_step(demo.calibrate(jax.random.key(9))[0], lanes, steps),
            "restore.sample(JumpRestore)": restore_sample(demo, lanes, steps),
            "  the same, default arguments": restore_sample_defaults(demo, lanes, steps),
            "restore.sample(MixtureMH)": restore_sample(
                restore.MixtureMH(target.logdensity, RandomWalk(scale), laplace, large_step_probability=0.1), lanes, steps
            ),
        },
        lanes * steps,
        rounds,
    )
    if not args.no_sweep:
        lanes_sweep(dim, min(rounds, 3), args.lane_steps, sweep_lanes)


if __name__ == "__main__":
    main()
