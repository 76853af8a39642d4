"""Restore renders report the tail of their tour durations, and warn when a few tours dominate.

A run-wide buffer keeps the longest finished tours; `render` fits the Pareto shape
`tour_k_hat` of the durations and warns above `TAIL_WARNING`. The buffer is checked exactly against tours
rebuilt step by step, the total against the regenerative identity `E[T] = Z / c`, and the
warning on integrands whose tours have a known tail: `lum(u) = u_2^(-a)` with a small step
too short to leave a bright start, so a tour lasts about `lum / c` events and
`P(T > t) ~ t^(-1/a)`, a Pareto tail of shape `a`.
"""

import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import restore.render as rr
from restore import UnreliableEstimateWarning
from restore._exceedances import largest
from restore.local import KelemenMutation
from restore.render._restore_renderer import TAIL_WARNING
from targets import AnalyticImage

TARGET = AnalyticImage.default(dim=3, resolution=(8, 8), num_bumps=3)


class PowerImage:
    """A 3-d PSS integrand `lum(u) = min(u_2^(-a), 1e5)` on a 4x4 film, grey."""

    dim, resolution, num_pixels = 3, (4, 4), 16

    def __init__(self, a: float):
        self.a = a

    def jax_evaluate(self, u):
        lum = jnp.minimum(jnp.maximum(u[:, 2], 1e-30) ** -self.a, 1e5)
        return lum, jnp.stack([lum, lum, lum], -1)

    def pixel_index(self, u):
        x = jnp.minimum(jnp.floor(u[:, 0] * 4).astype(jnp.int32), 3)
        y = jnp.minimum(jnp.floor(u[:, 1] * 4).astype(jnp.int32), 3)
        return y * 4 + x


def test_the_buffer_keeps_exactly_the_longest_tours():
    """Rebuild every tour's duration from the steps (the holding times `1 / (1 + gamma)` of
    its events, the killing event's included) and compare with the buffer, lane by lane, and the total."""
    renderer = rr.MetropolisRestore(tour_length=4, n_bootstrap=4096)
    lanes, steps = 16, 400
    state = jax.jit(lambda k: renderer.init(TARGET, k, lanes))(jax.random.key(0))

    def body(s, k):
        held = 1.0 / (1.0 + jnp.exp(s.lanes.log_kill_rate))  # the event's expected holding time
        after = renderer.step(TARGET, k, s)
        return after, (held, after.tour_moves == 0)  # no moves yet: the lane was killed

    final, (held, killed) = jax.jit(lambda s, k: jax.lax.scan(body, s, jax.random.split(k, steps)))(
        state, jax.random.key(1)
    )
    held, killed = np.asarray(held, np.float64), np.asarray(killed)
    tours = [[] for _ in range(lanes)]
    running = np.zeros(lanes)
    for i in range(steps):
        running += held[i]
        for lane in np.flatnonzero(killed[i]):
            tours[lane].append(running[lane])
            running[lane] = 0.0
    kept = largest(jax.tree.map(np.asarray, final.tails), 0)
    assert kept.threshold[0] == -np.inf  # the buffer never filled: it holds every tour
    for lane in range(lanes):
        mine = np.sort(kept.rows[kept.lane == lane, 0])
        np.testing.assert_allclose(mine, np.sort(tours[lane]), rtol=1e-4)
    np.testing.assert_allclose(np.asarray(final.tour_duration), running, rtol=1e-4)
    finished = np.concatenate([np.asarray(t) for t in tours])
    assert math.isclose(float(final.tally.duration), finished.sum(), rel_tol=1e-4)
    assert math.isclose(float(final.tally.duration_sq), np.sum(finished**2), rel_tol=1e-4)
    assert int(final.tally.kills) == sum(map(len, tours)) > 5 * lanes


def test_total_duration_of_complete_tours_is_z_over_c():
    """A tour's expected duration is `Z / c` (module docstring of the Restore renderer); with
    long tours (L = 16) and a short run a large share of it is spent in the speculative
    finishing steps, which must be counted too."""
    renderer = rr.MetropolisRestore(tour_length=16, n_bootstrap=16384)
    lanes, steps = 2048, 48
    result = rr.render(TARGET, renderer, key=jax.random.key(2), evaluations=renderer.init_cost(lanes) + steps * lanes,
                       num_lanes=lanes, progress=False)
    st = result.statistics
    assert isinstance(st, rr.RestoreStatistics)
    tours = st.tours_completed
    assert tours == st.tours_started and result.finishing_steps > 0
    mean = TARGET.Z / st.rate  # E[T] = Z / c
    # the relative standard error of a mean of N terms with Kish's effective size n is
    # sqrt(1 / n - 1 / N) (the terms' coefficient of variation over sqrt(N))
    relative_se = math.sqrt(1 / st.effective_tours - 1 / tours)
    assert abs(st.tour_duration_mean / mean - 1) < 4 * relative_se, (st.tour_duration_mean, mean, relative_se)
    assert 1 < st.effective_tours < tours and st.tour_k_hat < TAIL_WARNING, st


@pytest.mark.parametrize("a, heavy", [(0.3, False), (0.95, True)])
def test_heavy_tailed_tours_are_flagged(a, heavy):
    """Durations with a Pareto tail of shape `a`: `a = 0.95` (no finite variance) must warn,
    `a = 0.3` must not."""
    renderer = rr.MetropolisRestore(KelemenMutation(1e-7, 1e-6), n_bootstrap=4096)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = rr.render(PowerImage(a), renderer, key=jax.random.key(0), evaluations=4096 + 256 * 400,
                           num_lanes=256, progress=False)
    flagged = [w for w in caught if issubclass(w.category, UnreliableEstimateWarning)]
    assert isinstance(result.statistics, rr.RestoreStatistics)
    k = result.statistics.tour_k_hat
    if heavy:
        assert k > TAIL_WARNING and len(flagged) == 1 and "few long tours" in str(flagged[0].message), k
    else:
        assert k < 0.5 and not flagged, k


@pytest.mark.parametrize("a", [0.3, 0.95])
def test_pssmlt_reports_the_tail_of_the_luminance_behind_its_z_hat(a):
    """Under uniform draws `lum = u_2^(-a)` has a Pareto tail of shape exactly `a`: PSSMLT's
    bootstrap must find it, and warn that its `Z_hat` error is not to be trusted when `a`
    leaves no finite variance."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = rr.render(PowerImage(a), rr.PSSMLT(n_bootstrap=65536), key=jax.random.key(1),
                           evaluations=65536 + 256 * 4, num_lanes=256, progress=False)
    flagged = [w for w in caught if issubclass(w.category, UnreliableEstimateWarning)]
    assert isinstance(result.statistics, rr.PSSMLTStatistics)
    k = result.statistics.z_k_hat
    assert abs(k - a) < 0.15, k
    assert len(flagged) == (a > 0.5) and all("Z_hat" in str(w.message) for w in flagged)


def test_renderers_without_tours_report_no_tail():
    result = rr.render(TARGET, rr.PSSMLT(n_bootstrap=1024), key=jax.random.key(0), evaluations=1024 + 64 * 20,
                       num_lanes=64, progress=False)
    assert isinstance(result.statistics, rr.PSSMLTStatistics) and not hasattr(result.statistics, "tour_k_hat")
