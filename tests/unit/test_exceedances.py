"""The run-wide buffer of the largest rows: exact above its thresholds, through compactions, subsets and merges."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from restore._exceedances import Largest, compact, init_exceedances, largest, log_scores, merge, offer, select_lanes

LANES, WIDTH, SCORING = 16, 3, 1  # rows (T, F, log w): two magnitudes and a logarithm


def _steps(seed: int, steps: int):
    """Rows a run would offer: per step and lane a positive duration, a signed integral and a log weight,
    with heavy tails; about half the lanes offer a row at each step."""
    rng = np.random.default_rng(seed)
    t = rng.pareto(1.5, size=(steps, LANES)) + 0.01
    f = rng.standard_t(2, size=(steps, LANES)) * t
    w = rng.normal(size=(steps, LANES)) * 2
    rows = np.stack([t, f, w], axis=-1)
    return rows, rng.random((steps, LANES)) < 0.5


def _fill(rows, offered, capacity=64, batch=8):
    buffer = init_exceedances(capacity, WIDTH, jnp.float64)
    lanes = jnp.arange(LANES, dtype=jnp.int32)
    step = jax.jit(lambda b, r, o: offer(b, r, lanes, o, SCORING, batch))
    for r, o in zip(rows, offered):
        buffer = step(buffer, jnp.asarray(r), jnp.asarray(o))
    return buffer


def _exact(entries: Largest, rows, offered, lanes=None) -> bool:
    """Per column, the rows kept above the column's threshold are exactly the offered rows above it."""
    flat = rows[offered]
    lane = np.broadcast_to(np.arange(LANES), offered.shape)[offered]
    if lanes is not None:
        flat, lane = flat[np.isin(lane, lanes)], lane[np.isin(lane, lanes)]
    scores, kept = log_scores(flat, SCORING, np), log_scores(entries.rows, SCORING, np)
    for c in range(WIDTH):
        expected = sorted(zip(lane[scores[:, c] > entries.threshold[c]], flat[scores[:, c] > entries.threshold[c], c]))
        found = sorted(zip(entries.lane[kept[:, c] > entries.threshold[c]], entries.rows[kept[:, c] > entries.threshold[c], c]))
        if expected != found:
            return False
    return True


@pytest.fixture(scope="module")
def filled():
    rows, offered = _steps(0, 400)
    return rows, offered, _fill(rows, offered)


def test_the_buffer_holds_every_row_above_its_thresholds(filled):
    rows, offered, buffer = filled
    entries = largest(buffer, SCORING)
    assert np.all(np.isfinite(entries.threshold))  # every column's threshold rose: the buffer was compacted
    assert int(offered.sum()) > 40 * buffer.capacity
    assert _exact(entries, rows, offered)
    # each column keeps a good share of its largest values, and they are the largest of all
    for c in range(WIDTH):
        scores = log_scores(rows[offered], SCORING, np)[:, c]
        kept = np.sort(entries.rows[log_scores(entries.rows, SCORING, np)[:, c] > entries.threshold[c], c])
        assert kept.size >= 4
        top = np.sort(rows[offered][:, c][np.argsort(scores)[-kept.size :]])
        np.testing.assert_array_equal(kept, top)


def test_a_lowered_threshold_is_caught(filled):
    """Negative control: claiming a lower threshold than the buffer's makes the check fail."""
    rows, offered, buffer = filled
    entries = largest(buffer, SCORING)
    assert not _exact(entries._replace(threshold=entries.threshold - 1.0), rows, offered)


def test_subsets_of_lanes_and_merges_are_exact(filled):
    rows, offered, buffer = filled
    entries = largest(buffer, SCORING)
    assert _exact(select_lanes(entries, slice(0, 5), LANES), rows, offered, lanes=np.arange(5))
    # two buffers over disjoint lanes, merged: exact above the higher thresholds
    left = np.arange(LANES) < 7
    a = largest(_fill(rows, offered & left), SCORING)
    b = largest(_fill(rows, offered & ~left), SCORING)
    merged = merge([a, b], SCORING)
    assert np.all(merged.threshold == np.maximum(a.threshold, b.threshold))
    assert _exact(merged, rows, offered)


def test_a_device_axis_is_merged(filled):
    rows, offered, buffer = filled
    stacked = jax.tree.map(lambda x: jnp.stack([x, x]), buffer)
    both = largest(stacked, SCORING)
    assert both.rows.shape[0] == 2 * largest(buffer, SCORING).rows.shape[0]  # the same rows twice, above the same threshold...
    assert not _exact(both, rows, offered)  # ...count twice: a merge is for disjoint lanes only


def test_compaction_keeps_at_most_half_and_never_lowers_a_threshold():
    rows, offered = _steps(3, 50)
    buffer = init_exceedances(1024, WIDTH, jnp.float64)
    flat = jnp.asarray(rows[offered][:1024])
    buffer = buffer._replace(rows=flat, lane=jnp.zeros(1024, jnp.int32), filled=jnp.asarray(1024, jnp.int32))
    half = jax.jit(lambda b: compact(b, SCORING))(buffer)
    assert 0 < int(half.filled) <= 512
    assert np.all(np.asarray(half.threshold) > -np.inf)
    again = jax.jit(lambda b: compact(b, SCORING))(half._replace(threshold=half.threshold + 0.5))
    assert np.all(np.asarray(again.threshold) >= np.asarray(half.threshold) + 0.5)
