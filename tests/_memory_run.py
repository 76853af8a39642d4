"""Peak memory of a short and a long run (run as a script in a subprocess; prints JSON).

Usage: python _memory_run.py NUM_STEPS

Runs 10^4 steps first (compilation, every buffer allocated), records the peak resident
set size, then runs NUM_STEPS steps with the same shapes and records the peak again.
"""

import json
import resource
import sys
import time

import jax
import jax.numpy as jnp

import restore

LANES = 2


def peak_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux reports KiB


def main(num_steps: int) -> dict:
    sampler = restore.JumpRestore(
        lambda x: -0.5 * jnp.sum(x**2), restore.local.RandomWalk(1.0), restore.regeneration.Gaussian(jnp.zeros(1), 2.0),
        log_rate=0.0,
    )
    run = lambda n: restore.sample(  # noqa: E731
        sampler, jax.random.key(0), num_lanes=LANES, num_steps=n, save=restore.SaveDraws(0), progress=False
    )
    short = run(10_000)
    before = peak_mib()
    start = time.perf_counter()
    long = run(num_steps)
    return {
        "peak_after_short_mib": before,
        "peak_after_long_mib": peak_mib(),
        "seconds": time.perf_counter() - start,
        "draws": [list(short.draws.shape), list(long.draws.shape)],
        "num_steps": long.num_steps,
        "mean_x2": float(long.estimate("x**2").value[0]),
    }


if __name__ == "__main__":
    print(json.dumps(main(int(sys.argv[1]))))
