"""`restore.sample`: many independent lanes of a sampler, every sum and tail kept on the device (`_run.Run`)."""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping

from jaxtyping import Array, PRNGKeyArray

from ._options import DEFAULT_DRAWS, Checkpoint, SaveDraws
from ._result import SampleResult
from ._run import Run, Weights
from ._sampler import AbstractSampler
from ._sharding import Devices


def sample(
    sampler: AbstractSampler,
    key: PRNGKeyArray,
    *,
    num_lanes: int,
    num_steps: int,
    observables: Mapping[str, Callable[[Array], Array]] | None = None,
    weights: Weights = "rao_blackwell",
    positions: Array | None = None,
    save: SaveDraws = DEFAULT_DRAWS,
    progress: bool = True,
    num_chunks: int = 50,
    finish_tours: bool | int = True,
    devices: Devices = None,
    checkpoint: Checkpoint | str | os.PathLike | None = None,
    first_lane: int = 0,
) -> SampleResult:
    """Run `num_lanes` independent lanes for `num_steps` steps each and stream estimates.

    Lanes start at draws of the regeneration distribution (each lane is then a
    regenerative process from its first step: no burn-in), or at `positions` (each lane's
    first, partial tour is then left out of the tour-based estimates). Observables are
    integrated against the holding times on the device as the run goes (constant memory).

    Arguments:
        sampler: `JumpRestore`, `Restore` or `MixtureMH` (a `restore.AbstractSampler`). One
            given a `tour_length` is calibrated first by a pilot estimate of `Z` (`result.pilot`).
        key: a JAX PRNG key. Lane `i` uses `fold_in(key, i)`-derived keys, so it follows the
            same path whatever `num_lanes` is.
        num_lanes: independent lanes, run in parallel.
        num_steps: steps per lane (one density evaluation each for random-walk and MALA moves).
        observables: names to functions of one state; default `{"x": x, "x**2": x**2}`
            (`"x"` is always streamed, so `result.estimate("x")` is always there).
        weights: `"rao_blackwell"` (holding times replaced by their means `1/(r + gamma)`,
            lower variance) or `"time"` (the sampled holding times).
        positions: optional `(num_lanes, d)` starting points.
        save: the draws to keep (`restore.SaveDraws`: a budget of 100,000 by default).
        progress: show a progress bar (updated between chunks: it costs nothing inside them),
            and one for the finishing of the open tours in a narrow batch.
        num_chunks: chunks the run is cut into, for the progress bar and checkpoints.
        finish_tours: after the budget, run each open tour to its end, so that the estimates are
            not biased to short tours (`False` drops them, and marks the tour-based
            estimates unreliable: `result.tours_dropped`): a lane may take up to ten times
            `num_steps` more steps (an integer: up to that many), in a batch narrower than the
            lanes (below 4,096 lanes a device, after a first `num_steps` steps of every lane).
        devices: split the lanes over devices (`None`: the default one; an int `n`: the first
            `n`; `"all"`; devices or a `jax.sharding.Mesh`), with the same per-lane paths as
            on one device; across hosts after `jax.distributed.initialize()` (`docs/scaling.md`).
        checkpoint: a `restore.Checkpoint`, or a file (saved every 60 s, resumed if it exists).
        first_lane: this run's first lane: parts `first_lane=0, n, 2n, ...` of one large run,
            joined by `restore.merge_results`, are bit-identical to one run of all the lanes.

    Returns:
        A `SampleResult`; on Ctrl-C, that of the chunks done so far (`interrupted`, checkpointed).
    """
    run = Run(
        sampler, key, num_lanes=num_lanes, num_steps=num_steps, observables=observables, weights=weights,
        positions=positions, save=save, progress=progress, num_chunks=num_chunks, finish_tours=finish_tours,
        devices=devices, checkpoint=checkpoint, first_lane=first_lane,
    )  # fmt: skip
    run.advance()
    run.finish()
    return run.result()
