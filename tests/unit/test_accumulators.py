"""The sums over complete tours and tour starts, added once per chunk from the tour records."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from restore._accumulators import add_recorded_tours, init_lane_sums
from restore._tour_records import init_records, record

LANES, SIZE, DEPTH = 6, 3, 5


def recorded(seed: int, dtype=jnp.float64):
    """Records of a few steps, as the run loop writes them: each lane ends tours and draws
    starts at random steps, so lanes hold different counts; slots past a lane's count keep
    whatever an earlier chunk left there."""
    rng = np.random.default_rng(seed)
    records = init_records(LANES, SIZE, DEPTH, dtype)
    stale = jnp.asarray(rng.normal(size=(LANES, DEPTH, SIZE)) * 1e6, dtype)  # an earlier chunk's leftovers
    records = records._replace(integral=stale, duration=jnp.full((LANES, DEPTH), 1e6, dtype))
    tours, starts = [[] for _ in range(LANES)], [[] for _ in range(LANES)]
    for _ in range(12):
        ended = rng.random(LANES) < 0.35
        drawn = rng.random(LANES) < 0.35
        ended &= np.asarray(records.count) < DEPTH  # a chunk stops before a buffer overflows
        drawn &= np.asarray(records.starts) < DEPTH
        t = rng.exponential(size=LANES)
        f = rng.normal(size=(LANES, SIZE)) * t[:, None]
        log_iw = rng.normal(size=LANES)
        args = (jnp.asarray(t, dtype), jnp.asarray(f, dtype), jnp.asarray(ended), jnp.asarray(log_iw, dtype), jnp.asarray(drawn))
        records = record(records, *args)
        for lane in range(LANES):
            if ended[lane]:
                tours[lane].append((np.asarray(args[0])[lane], np.asarray(args[1])[lane]))
            if drawn[lane]:
                starts[lane].append(np.asarray(args[3])[lane])
    return records, tours, starts


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
def test_recorded_tours_give_the_sums_of_adding_each_tour_when_it_ends(dtype):
    records, tours, starts = recorded(1, dtype)
    assert 0 < int(records.count.min()) and int(records.count.max()) == DEPTH  # lanes differ; one is full
    before = init_lane_sums(LANES, SIZE, dtype, jnp.zeros(LANES, bool))
    before = before._replace(sum_t=jnp.full(LANES, 2.5, dtype), num_tours=jnp.full(LANES, 7, jnp.int32))
    sums = jax.jit(add_recorded_tours)(before, records)
    for lane in range(LANES):
        # the tours in the order they ended, added one at a time in the run's dtype
        sum_t, sum_t2, max_t = dtype(2.5), dtype(0), dtype(0)
        sum_f, sum_f2, sum_ft = (np.zeros(SIZE, dtype) for _ in range(3))
        for t, f in tours[lane]:
            sum_t, sum_t2, max_t = sum_t + t, sum_t2 + t * t, max(max_t, t)
            sum_f, sum_f2, sum_ft = sum_f + f, sum_f2 + f * f, sum_ft + f * t
        np.testing.assert_array_equal(np.asarray(sums.sum_t)[lane], sum_t)
        np.testing.assert_array_equal(np.asarray(sums.sum_t2)[lane], sum_t2)
        np.testing.assert_array_equal(np.asarray(sums.max_tour)[lane], max_t)
        np.testing.assert_array_equal(np.asarray(sums.sum_f)[lane], sum_f)
        np.testing.assert_array_equal(np.asarray(sums.sum_f2)[lane], sum_f2)
        np.testing.assert_array_equal(np.asarray(sums.sum_ft)[lane], sum_ft)
        assert int(sums.num_tours[lane]) == 7 + len(tours[lane])
        assert int(sums.num_iw[lane]) == len(starts[lane])
        log_iw = np.asarray(starts[lane], np.float64)
        expected = np.logaddexp.reduce(log_iw) if len(log_iw) else -np.inf
        tolerance = 1e-12 if dtype == jnp.float64 else 1e-5
        np.testing.assert_allclose(float(sums.log_iw_sum[lane]), expected, rtol=tolerance)
        expected2 = np.logaddexp.reduce(2 * log_iw) if len(log_iw) else -np.inf
        np.testing.assert_allclose(float(sums.log_iw_sum2[lane]), expected2, rtol=tolerance)
    # the per-step fields are left alone
    np.testing.assert_array_equal(np.asarray(sums.all_t), np.asarray(before.all_t))
    np.testing.assert_array_equal(np.asarray(sums.open_f), np.asarray(before.open_f))


def test_slots_past_a_lanes_count_are_ignored():
    """Negative control: counting the stale slots of an earlier chunk changes the sums."""
    records, tours, _ = recorded(2)
    before = init_lane_sums(LANES, SIZE, jnp.float64, jnp.zeros(LANES, bool))
    sums = add_recorded_tours(before, records)
    assert np.all(np.asarray(sums.max_tour) < 1e6)
    full = records._replace(count=jnp.full(LANES, DEPTH, jnp.int32))
    wrong = add_recorded_tours(before, full)
    short = np.asarray(records.count) < DEPTH
    assert short.any()
    assert np.all(np.asarray(wrong.max_tour)[short] == 1e6)
    assert not np.allclose(np.asarray(wrong.sum_f)[short], np.asarray(sums.sum_f)[short])


def test_samplers_without_tours_keep_zero_tour_sums():
    before = init_lane_sums(LANES, SIZE, jnp.float64, jnp.zeros(LANES, bool))
    sums = add_recorded_tours(before, init_records(LANES, SIZE, 0, jnp.float64))
    for name in ("sum_f", "sum_t", "num_tours", "num_iw"):
        assert not np.any(np.asarray(getattr(sums, name)))
