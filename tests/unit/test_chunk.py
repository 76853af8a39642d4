"""`run_open_lanes`: every open lane takes exactly its own steps, whatever the batch's width,
how often it refills and how its iterations fall into calls."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from restore import _chunk
from restore._chunk import run_open_lanes

NUM_LANES = 40
# lane i's work takes LENGTHS[i] steps (0: closed from the start); a few long ones
LENGTHS = np.random.default_rng(0).geometric(0.15, NUM_LANES) * (np.arange(NUM_LANES) % 5 != 0)


def _step(slot_lanes, shared, slot_lane, slot_steps, live, _):
    """Each live slot adds one to its lane's counter and `lane + 1` to the shared total; its work
    ends at its lane's length. The other slots keep their lanes as they are."""
    counter = jnp.where(live, slot_lanes + 1, slot_lanes)
    shared = shared + jnp.sum(jnp.where(live, slot_lane + 1, 0), dtype=jnp.int32)
    return counter, shared, counter >= jnp.asarray(LENGTHS)[slot_lane]


def _finish(width: int, limit: int, per_call: int):
    run = jax.jit(lambda *a: run_open_lanes(_step, *a, width=width))
    lanes, shared = jnp.zeros(NUM_LANES, jnp.int32), jnp.zeros((), jnp.int32)
    taken, calls = jnp.zeros(NUM_LANES, jnp.int32), 0
    for _ in range(1000):  # a lane that never ends fails below
        still = (lanes < jnp.asarray(LENGTHS)) & (taken < limit)
        if not bool(jnp.any(still)):
            return np.asarray(lanes), int(shared), np.asarray(taken), calls
        lanes, shared, taken, _ = run(lanes, shared, still, taken, limit, per_call)
        calls += 1
    raise AssertionError("some lane never finished")


@pytest.mark.parametrize("share", [1, 8])
@pytest.mark.parametrize("width", [1, 3, 16, 64])
def test_every_open_lane_takes_its_own_steps_at_any_width_and_refill(width, share, monkeypatch):
    """A lane that is done waits in its slot until enough slots are (`REFILL_SHARE`); it is then
    written back unchanged, and one still held at the end of a call is written back too. So each
    lane ends with exactly its own steps (capped at `limit`), in one call or in calls of 5
    iterations, and the shared total counts each step once. A write-back that lost the waiting
    lanes, or a batch that stepped them, would change the counters."""
    monkeypatch.setattr(_chunk, "REFILL_SHARE", share)
    for limit in (1000, 12):
        wanted = np.minimum(LENGTHS, limit)
        for per_call in (10_000, 5):
            lanes, shared, taken, calls = _finish(width, limit, per_call)
            np.testing.assert_array_equal(lanes, wanted)
            np.testing.assert_array_equal(taken, wanted)
            assert shared == int(np.sum(wanted * (np.arange(NUM_LANES) + 1)))
            assert calls == 1 or per_call == 5
