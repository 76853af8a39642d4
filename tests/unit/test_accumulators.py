"""The per-lane sums: tour ends added at their lanes only, and chunks added to the run's totals on the device."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from restore._accumulators import LaneSums, add_events, fold, host_totals, init_histogram, init_lane_sums, init_totals

LANES, SIZE = 6, 3


def _events(rng, dtype):
    """One step's tour ends and starts at random lanes, as the run loop gathers them: distinct
    lanes in order, the batch padded with out-of-range lanes."""
    lanes = np.flatnonzero(rng.random(LANES) < 0.5)
    ended = rng.random(lanes.size) < 0.7
    drawn = rng.random(lanes.size) < 0.7
    t = rng.exponential(size=lanes.size)
    f = rng.normal(size=(lanes.size, SIZE)) * t[:, None]
    w = rng.normal(size=lanes.size)
    pad = 2  # slots of the batch that hold no lane
    index = np.concatenate([lanes, np.full(pad, LANES)])
    cat = lambda a, fill: np.concatenate([a, np.full((pad,) + a.shape[1:], fill, a.dtype)])
    args = (cat(ended, True), cat(drawn, True), cat(f, 1e6), cat(t, 1e6), cat(w, 1e6))  # padding would poison the sums
    return index, lanes, ended, drawn, t, f, w, tuple(jnp.asarray(a, dtype if a.dtype.kind == "f" else None) for a in args)


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
def test_events_give_the_sums_of_adding_each_tour_at_every_lane(dtype):
    """Adding the gathered lanes' tours equals adding, at every lane and every step, the tour
    that ended there or zero (the dense update; to the last bits, which XLA's fused
    multiply-adds may round otherwise than NumPy); padded slots change nothing."""
    rng = np.random.default_rng(1)
    sums = init_lane_sums(LANES, SIZE, dtype, jnp.zeros(LANES, bool))
    sums = sums._replace(sum_t=jnp.full(LANES, 2.5, dtype), num_tours=jnp.full(LANES, 7, jnp.int32))
    dense = jax.tree.map(np.asarray, sums)
    step = jax.jit(add_events)
    for _ in range(12):
        index, lanes, ended, drawn, t, f, w, args = _events(rng, dtype)
        sums = step(sums, jnp.asarray(index, jnp.int32), *args)
        e = np.zeros(LANES, bool)
        e[lanes] = ended
        d = np.zeros(LANES, bool)
        d[lanes] = drawn
        tt = np.zeros(LANES, dtype)
        tt[lanes] = t
        ff = np.zeros((LANES, SIZE), dtype)
        ff[lanes] = f
        ww = np.full(LANES, -np.inf, dtype)
        ww[lanes] = w
        tt, ff = np.where(e, tt, 0).astype(dtype), np.where(e[:, None], ff, 0).astype(dtype)
        ww = np.where(d, ww, -np.inf).astype(dtype)
        dense = dense._replace(
            sum_f=dense.sum_f + ff, sum_f2=dense.sum_f2 + ff * ff, sum_ft=dense.sum_ft + ff * tt[:, None],
            sum_t=dense.sum_t + tt, sum_t2=dense.sum_t2 + tt * tt, num_tours=dense.num_tours + e,
            max_tour=np.maximum(dense.max_tour, tt), num_iw=dense.num_iw + d,
            log_iw_sum=np.logaddexp(dense.log_iw_sum, ww), log_iw_sum2=np.logaddexp(dense.log_iw_sum2, 2 * ww),
        )  # fmt: skip
    tolerance = 1e-14 if dtype == jnp.float64 else 1e-6
    for name in ("sum_f", "sum_f2", "sum_ft", "sum_t", "sum_t2", "max_tour", "log_iw_sum", "log_iw_sum2"):
        np.testing.assert_allclose(np.asarray(getattr(sums, name)), getattr(dense, name), rtol=tolerance, err_msg=name)
    for name in ("num_tours", "num_iw"):
        np.testing.assert_array_equal(np.asarray(getattr(sums, name)), getattr(dense, name), err_msg=name)
    assert np.all(np.asarray(sums.max_tour) < 1e6)  # the padding never landed


def test_padding_at_a_lane_would_change_the_sums():
    """Negative control: the padded slots hold poison; pointing them at a real lane changes its sums."""
    rng = np.random.default_rng(2)
    sums = init_lane_sums(LANES, SIZE, jnp.float64, jnp.zeros(LANES, bool))
    index, *_, args = _events(rng, jnp.float64)
    right = add_events(sums, jnp.asarray(index, jnp.int32), *args)
    wrong = add_events(sums, jnp.asarray(np.where(index == LANES, 0, index), jnp.int32), *args)
    assert float(wrong.max_tour[0]) == 1e6 != float(right.max_tour[0])


def test_float32_totals_keep_their_precision():
    """A million chunks of one small term each, added to a large float32 total: compensated
    summation keeps the total exact to float32's last bits, plain float32 addition loses it."""
    sums = init_lane_sums(1, 1, jnp.float32, jnp.zeros(1, bool))
    histogram = init_histogram(jnp.float32)
    totals = init_totals(sums, histogram)
    totals = totals._replace(sums=totals.sums._replace(all_t=jnp.full(1, 1e4, jnp.float32)))
    chunk = sums._replace(all_t=jnp.full(1, 1e-3, jnp.float32))
    run = jax.jit(lambda totals: jax.lax.fori_loop(0, 10**6, lambda _, t: fold(t, chunk, histogram), totals))
    compensated = host_totals(run(totals))[0].all_t[0]
    exact = 1e4 + 10**6 * float(np.float32(1e-3))
    assert abs(compensated - exact) < 1e-6 * exact
    plain = run(totals._replace(error=None)).sums.all_t[0]  # negative control: no compensation
    assert abs(float(plain) - exact) > 100 * abs(compensated - exact)


def test_fold_takes_the_lanes_state_from_the_chunk():
    sums = init_lane_sums(LANES, SIZE, jnp.float64, jnp.zeros(LANES, bool))
    totals = init_totals(sums, init_histogram(jnp.float64))
    chunk = sums._replace(open_steps=jnp.arange(LANES, dtype=jnp.int32), sum_t=jnp.ones(LANES))
    folded = fold(fold(totals, chunk, init_histogram(jnp.float64)), chunk, init_histogram(jnp.float64))
    host, _ = host_totals(folded)
    assert isinstance(host, LaneSums)
    np.testing.assert_array_equal(host.open_steps, np.arange(LANES))  # state: the latest, not summed
    np.testing.assert_array_equal(host.sum_t, 2.0)  # sums: added
