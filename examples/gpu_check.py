"""Check that a GPU machine runs the sampler and the renderer, and print their throughput.

1. Jump Restore on a 10-d mixture of three Gaussians, many lanes on the first GPU:
   steps per second (lanes x steps over the wall time, compilation excluded) of
   `restore.sample` with its open tours finished and for the budget's steps alone, of the
   bare jump-Restore step (`step_lanes` in a scan) and, if BlackJAX is installed, of
   BlackJAX's random-walk Metropolis on the same target, lanes, steps and scale, with the
   ratios to BlackJAX; and the mode weights against the truth.
2. If the `mitsuba` extra is installed: the Cornell box traced in primary sample space
   (Mitsuba's `cuda_ad_rgb` variant when a CUDA device is usable), in paths per second for
   plain batches, for a short Metropolis Restore render, and for Mitsuba's own `path`
   integrator.

Without a GPU it says so and exits with status 0 (status 1 with `--require-gpu`);
`--allow-cpu` runs the same measurements on the CPU instead (a dry run of the script).

Install: `pip install -e '.[cuda,mitsuba]'` (`jax[cuda12]`, an NVIDIA driver for CUDA 12).
Usage: python examples/gpu_check.py [--quick] [--require-gpu | --allow-cpu]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

# JAX takes 75% of the GPU's memory at start by default; Dr.Jit (Mitsuba) needs some too.
os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")

import jax  # noqa: E402
import numpy as np  # noqa: E402


def gpu_devices() -> list:
    try:
        return jax.devices("gpu")
    except RuntimeError:  # no GPU backend (the CPU-only jaxlib, or no usable device)
        return []


def _timed_scan(run, argument) -> tuple[float, float]:
    """(compile seconds, seconds of a second run) of `jax.jit(run)(key, argument)`."""
    start = time.perf_counter()
    compiled = jax.jit(run).lower(jax.random.key(0), argument).compile()
    compile_seconds = time.perf_counter() - start
    jax.block_until_ready(compiled(jax.random.key(0), argument))
    start = time.perf_counter()
    jax.block_until_ready(compiled(jax.random.key(1), argument))
    return compile_seconds, time.perf_counter() - start


def bare_step_seconds(sampler, lanes: int, steps: int) -> tuple[float, float]:
    """The jump-Restore step alone (`step_lanes` in a scan, a running Rao-Blackwellised sum)."""
    import restore

    states = jax.vmap(sampler.init)(jax.random.split(jax.random.key(0), lanes))

    def run(key, states):
        def body(carry, key):
            states, total = carry
            states, info = sampler.step_lanes(jax.random.split(key, lanes), states)
            return (states, total + info.expected_holding_time[:, None] * info.position), None

        key = restore.unrolled_keys(key)
        return jax.lax.scan(body, (states, jax.numpy.zeros_like(states.position)), jax.random.split(key, steps))[0][1]

    return _timed_scan(run, states)


def blackjax_seconds(logdensity, scale: float, x0, steps: int) -> tuple[float, float] | None:
    """BlackJAX's random-walk Metropolis in a scan over `vmap(step)`, a running sum of positions (`None` without BlackJAX)."""
    try:
        import blackjax
    except ImportError:
        return None
    lanes, dim = x0.shape
    rmh = blackjax.additive_step_random_walk.normal_random_walk(logdensity, scale * jax.numpy.ones(dim))

    def run(key, x0):
        def body(carry, key):
            states, total = carry
            states, _ = jax.vmap(rmh.step)(jax.random.split(key, lanes), states)
            return (states, total + states.position), None

        return jax.lax.scan(body, (jax.vmap(rmh.init)(x0), jax.numpy.zeros_like(x0)), jax.random.split(key, steps))[0][1]

    return _timed_scan(run, x0)


def check_sampler(lanes: int, steps: int) -> None:
    import warnings

    import restore
    from targets.analytic import well_separated_gaussian_mixture

    target = well_separated_gaussian_mixture(dim=10, num_modes=3)
    starts = 6.0 * jax.random.normal(jax.random.key(0), (64, 10))
    nu = restore.regeneration.laplace_mixture(target.logdensity, starts, tails="student_t", df=5)
    scale = 0.75
    sampler = restore.JumpRestore(target.logdensity, restore.local.RandomWalk(scale), nu, tour_length=10.0)
    modes = lambda x: jax.nn.one_hot(target.assign_mode(x), 3)  # noqa: E731
    kwargs = dict(num_lanes=lanes, observables={"modes": modes}, progress=False, save=restore.SaveDraws(0), num_chunks=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        start = time.perf_counter()
        restore.sample(sampler, jax.random.key(1), num_steps=10, **kwargs)  # compiles the loop once
        compile_seconds = time.perf_counter() - start
        result = restore.sample(sampler, jax.random.key(2), num_steps=steps, **kwargs)
        budget = restore.sample(sampler, jax.random.key(2), num_steps=steps, finish_tours=False, **kwargs)
    estimate = result.estimate("modes")
    work = lanes * steps
    print(f"sampler: jump Restore, 10-d mixture, {lanes:,} lanes x {steps:,} steps in {result.wall_time:.2f} s "
          f"(+{compile_seconds:.1f} s to compile; {result.finishing_steps} finishing steps, "
          f"{result.unfinished_tours} tours still open)")
    print(f"  mode weights {np.round(estimate.value, 4)} +- {np.round(estimate.standard_error, 4)} "
          f"(truth {np.round(np.asarray(target.weights), 4)})")
    rows = [("restore.sample", result.wall_time, compile_seconds), ("restore.sample, budget only", budget.wall_time, None)]
    bare_compile, bare = bare_step_seconds(sampler.calibrate(jax.random.key(9))[0], lanes, steps)
    rows.append(("jump-Restore step (no driver)", bare, bare_compile))
    peer = blackjax_seconds(target.logdensity, scale, target.sample(jax.random.key(3), lanes), steps)
    if peer is not None:
        rows.append(("BlackJAX RMH", peer[1], peer[0]))
    for label, seconds, compiled in rows:
        ratio = f"{peer[1] / seconds:6.3f} of BlackJAX" if peer is not None else ""
        compile_note = "" if compiled is None else f", compiled in {compiled:.1f} s"
        print(f"  {label:30s} {work / seconds:16,.0f} steps/s {ratio}{compile_note}")


def check_render(resolution: int, seconds: float, lanes: int) -> None:
    import importlib.util

    if not all(importlib.util.find_spec(name) is not None for name in ("mitsuba", "drjit")):
        print("render: skipped, the `mitsuba` extra is not installed (pip install -e '.[mitsuba]')")
        return
    import restore.render as rr
    from targets.mitsuba import PrimarySampleSpace, load_mitsuba, native_paths_per_second

    mi = load_mitsuba()
    target = PrimarySampleSpace("cornell_box", resolution=(resolution, resolution), max_depth=5)
    print(f"render: Cornell box {resolution}x{resolution}, max depth 5, Mitsuba variant {mi.variant()}")
    print(f"  {target.paths_per_second():,.0f} paths/s traced in primary sample space (batches of 65,536)")
    result = rr.render(target, rr.MetropolisRestore(), key=jax.random.key(0), seconds=seconds,
                       num_lanes=lanes, progress=False)
    print(f"  {result.evaluations_per_second:,.0f} paths/s with Metropolis Restore ({result.evaluations:,} paths in "
          f"{result.seconds:.1f} s, +{result.compile_seconds:.1f} s to compile)")
    print(f"  {native_paths_per_second(target.scene, max_depth=5):,.0f} paths/s with Mitsuba's own path integrator")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes (a smoke test)")
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--require-gpu", action="store_true", help="exit with status 1 when there is no GPU")
    mode.add_argument("--allow-cpu", action="store_true", help="without a GPU, measure on the CPU instead")
    args = parser.parse_args()

    gpus = gpu_devices()
    if not gpus:
        message = (
            f"no GPU: JAX sees only {jax.devices()} (backend {jax.default_backend()}). Install the CUDA build with "
            "pip install -e '.[cuda]' on a machine with an NVIDIA GPU and driver; "
            "jax.devices('gpu') must list it."
        )
        if not args.allow_cpu:
            print(f"gpu_check: skipped, {message}")
            return 1 if args.require_gpu else 0
        print(f"gpu_check: {message} Measuring on the CPU (--allow-cpu).")
    else:
        print(f"gpu_check: {len(gpus)} GPU(s): {', '.join(d.device_kind for d in gpus)}; jax {jax.__version__}")
    device = gpus[0] if gpus else jax.devices("cpu")[0]
    lanes, steps = (256, 200) if args.quick else (1 << 16, 2000)
    with jax.default_device(device):
        check_sampler(lanes, steps)
        check_render(16 if args.quick else 128, 1.0 if args.quick else 10.0, 256 if args.quick else 1 << 16)
    return 0


if __name__ == "__main__":
    sys.exit(main())
