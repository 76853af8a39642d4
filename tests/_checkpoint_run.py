"""A small run with a checkpoint, for the interruption tests (run as a script in a subprocess).

Usage: python _checkpoint_run.py CHECKPOINT OUT.npz

It samples with `checkpoint=CHECKPOINT` (resuming from it if it exists) and saves the
per-lane sums, draws and the `interrupted` flag to OUT.npz. It saves every 500 of its
8000 steps, so a signal sent once the first checkpoint exists lands between checkpoints.
"""

import sys

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

import restore  # noqa: E402

NUM_LANES, NUM_STEPS, CHECKPOINT_STEPS = 16, 8_000, 500


def logdensity(x):
    return jnp.logaddexp(-0.5 * jnp.sum((x - 2.0) ** 2), -0.5 * jnp.sum((x + 2.0) ** 2) + jnp.log(0.5))


def sampler():
    regeneration = restore.regeneration.Gaussian(jnp.zeros(2), 9.0 * jnp.eye(2))
    return restore.JumpRestore(logdensity, restore.local.RandomWalk(0.8), regeneration, log_rate=0.5)


def run(checkpoint=None, **kwargs):
    return restore.sample(
        sampler(),
        jax.random.key(7),
        num_lanes=NUM_LANES,
        num_steps=NUM_STEPS,
        save=restore.SaveDraws(4_000),
        progress=False,
        checkpoint=None if checkpoint is None else restore.Checkpoint(checkpoint, every_steps=CHECKPOINT_STEPS, every_seconds=None),
        **kwargs,
    )


def arrays(result) -> dict[str, np.ndarray]:
    out = {f"sums_{name}": np.asarray(value) for name, value in result.sums._asdict().items()}
    out.update(draws=result.draws, draw_weights=result.draw_weights, histogram=np.stack(result.histogram))
    return out


if __name__ == "__main__":
    result = run(sys.argv[1])
    np.savez(sys.argv[2], interrupted=result.interrupted, num_steps=result.num_steps, **arrays(result))
