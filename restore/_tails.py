"""The largest tours of a run, kept on the device, and the tail shapes `k_hat` read off them.

The run loop offers every step of a lane that ends a tour or draws a tour start to a
run-wide buffer (`_exceedances`: every row with a score above its column's threshold,
which rises as the buffer fills, with its lane) as a row `(T, F_1, ..., F_m, log w)`: the
duration and observable integrals of the tour that ended (zeros if none did), scored by
`log T` and each `log |F_j|`, and the log importance weight `log p(y) - log q(y)` of the
start drawn (`-inf` if none was). Every tour whose duration or any `|F_j|` is above that
column's threshold is in the buffer with all its numbers, and every start whose weight
is above its threshold.

So after the run the largest values of the whole run (or of any group of lanes) are
known exactly above a bound, and the Pareto shape of each tail that matters can be
fitted (`_pareto`):

- the tour durations `T` (the `"tours"` estimate of `log Z` is their mean);
- the residuals `|F_j - pi_hat_j T|` of the ratio estimator of each component (or, when
  too few of the largest residuals are certain, the heavier of the tails of `|F_j|` and
  `T`, which bounds it);
- the importance weights (the `"importance"` estimate of `log Z`).

For residuals, which depend on the final `pi_hat`, a tour not in the buffer has
`T <= exp(threshold_T)` and `|F_j| <= exp(threshold_j)`, so
`|F_j - pi_hat T| <= exp(threshold_j) + |pi_hat| exp(threshold_T)`, and every residual
above that bound is known.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from ._exceedances import Exceedances, Largest, init_exceedances, largest, merge
from ._exceedances import select_lanes as select_rows
from ._pareto import pareto_k, pareto_k_log, tail_length, tail_square_excess

#: The buffer has about this many rows per lane (so that groups of lanes have tails of their own)...
ROWS_PER_LANE = 64
#: ...at least this many...
MIN_ROWS = 2**16
#: ...and at most this many numbers in all.
MAX_ELEMENTS = 2**23
#: The last number of a row, the log importance weight, is a logarithm already (`_exceedances.Scoring`).
SCORING = 1

TourTailBuffers = Exceedances
"""The run's largest tours and tour starts, on the device: rows `(T, F_1, ..., F_m, log w)`."""

TourTails = Largest
"""The run's largest tours and tour starts, on the host (`Largest` rows, float64)."""


def _power_of_two_at_most(n: float) -> int:
    return 1 << max(int(n).bit_length() - 1, 1)


def tail_rows(num_lanes: int, size: int) -> int:
    """Rows of the buffer: a power of two near `ROWS_PER_LANE` per lane, within the memory cap, and
    at least four per lane (room for every lane's row of a step and a batch after a compaction: `_run_loop._events`)."""
    power = lambda n: 1 << max(int(n - 1).bit_length(), 1)
    wanted = min(max(power(ROWS_PER_LANE * num_lanes), MIN_ROWS), _power_of_two_at_most(MAX_ELEMENTS / (size + 3)))
    return int(max(wanted, power(4 * num_lanes)))


def init_tails(rows: int, size: int, dtype) -> TourTailBuffers:
    """An empty buffer of `rows` rows (`tail_rows`) for `size` observable components."""
    return init_exceedances(rows, size + 2, dtype)


def tail_rows_of(duration: Array, integral: Array, ended: Array, log_importance_weight: Array, drawn: Array) -> Array:
    """The rows `(T, F_1, ..., F_m, log w)` of some lanes (zeros where no tour ended, `-inf` where no start was drawn)."""
    return jnp.concatenate(
        [jnp.where(ended, duration, 0.0)[:, None], jnp.where(ended[:, None], integral, 0.0), jnp.where(drawn, log_importance_weight, -jnp.inf)[:, None]],
        axis=1,
    )


def wanted_tours(
    tails: TourTailBuffers,
    duration: Float[Array, " N"],
    integral: Float[Array, "N m"],
    ended: Bool[Array, " N"],
    log_importance_weight: Float[Array, " N"],
    drawn: Bool[Array, " N"],
) -> Bool[Array, " N"]:
    """The lanes whose tour that ended or start drawn has a score above its column's threshold
    (compared on the lanes' own arrays, without building their rows)."""
    bound = jnp.exp(tails.threshold[:-1])
    tour = (duration > bound[0]) | jnp.any(jnp.abs(integral) > bound[1:], axis=1)
    return (ended & tour) | (drawn & (log_importance_weight > tails.threshold[-1]))


def tour_tails(buffers: TourTailBuffers) -> TourTails:
    """The host form of the buffer (buffers kept per device merged)."""
    return largest(buffers, SCORING)


def merge_tails(parts: list[TourTails], lane_offsets: list[int]) -> TourTails:
    """The tails of runs over disjoint lanes (`first_lane` parts), as one run's."""
    return merge([p._replace(lane=p.lane + o) for p, o in zip(parts, lane_offsets, strict=True)], SCORING)


def select_lanes(tails: TourTails, lanes, num_lanes: int) -> TourTails:
    """The tails of some lanes (an index, slice or mask), for estimates from groups of lanes."""
    return select_rows(tails, lanes, num_lanes)


def _finite(values: np.ndarray) -> np.ndarray:
    return values[np.isfinite(values)]


def longest_durations(tails: TourTails) -> np.ndarray:
    """The run's longest tour durations (every one above the buffer's threshold), longest first."""
    return np.sort(_finite(tails.column(0, SCORING)))[::-1]


def duration_k(tails: TourTails, num_tours: int) -> float:
    """`k_hat` of the tour durations."""
    return pareto_k(longest_durations(tails), num_tours)


def importance_k(tails: TourTails, num_starts: int) -> float:
    """`k_hat` of the importance weights at tour starts."""
    return pareto_k_log(_finite(tails.column(tails.rows.shape[1] - 1, SCORING)), num_starts)


def signed_square_excess(terms: np.ndarray, num_tours: int) -> float:
    """`tail_square_excess` of the largest `|terms|`, times the skew of their squares:
    `|sum sign(t) t^2| / sum t^2` over the `tail_length` largest.

    What the excess corrects is one-sided: a run that met none of a heavy tail's rare terms
    misses them on one side, so its estimate is off towards the other side by as much as its
    error bar is too short. Where the largest terms fall on both sides alike (a symmetric
    tail) those misses cancel, and the plain standard error holds (the t statistic of a
    symmetric sum errs on the safe side, Efron 1969): the excess is scaled away.
    """
    terms = np.asarray(terms, np.float64)
    terms = terms[np.isfinite(terms)]
    top = terms[np.argsort(-np.abs(terms))[: tail_length(num_tours)]]
    squares = float(np.sum(top**2))
    if not squares > 0:
        return 0.0
    skew = abs(float(np.sum(np.sign(top) * top**2))) / squares
    return skew * tail_square_excess(np.abs(terms), num_tours)


def duration_square_excess(tails: TourTails, num_tours: int, mean: float) -> float:
    """`signed_square_excess` of the deviations `T - mean` of the longest tours."""
    return signed_square_excess(longest_durations(tails) - mean, num_tours)


def residual_square_excess(tails: TourTails, column: int, value: float, num_tours: int) -> float:
    """`signed_square_excess` of the largest residuals `F_j - value * T` of component `column`
    among the tours the buffer holds (every tour above the buffer's thresholds)."""
    if tails.rows.shape[1] <= 2 + column:
        return 0.0
    tour = tails.rows[:, 0] > 0  # rows of a start alone hold no tour
    return signed_square_excess(tails.rows[tour, 1 + column] - value * tails.rows[tour, 0], num_tours)


def residual_k(tails: TourTails, column: int, value: float, num_tours: int) -> float:
    """`k_hat` of the residuals `|F_j - value * T|` of component `column` of the observables."""
    tours = tails
    if tours.rows.shape[1] <= 2 + column:
        return math.nan
    tour = tours.rows[:, 0] > 0  # rows of a start alone hold no tour
    t, f = tours.rows[tour, 0], tours.rows[tour, 1 + column]
    residual = np.abs(f - value * t)
    residual = residual[np.isfinite(residual)]
    bound = math.exp(tours.threshold[1 + column]) + abs(value) * math.exp(tours.threshold[0])
    certain = residual[residual > bound]
    if certain.size > tail_length(num_tours):
        return pareto_k(certain, num_tours)
    # Too few residuals are certain to be the largest: bound the tail instead. Since
    # |F - pi T| <= |F| + |pi| T, the residuals' tail is no heavier than the heavier of
    # the tails of |F_j| and T, each known exactly above its own threshold.
    magnitudes = np.abs(_finite(tours.column(1 + column, SCORING)))
    return max(pareto_k(magnitudes, num_tours), duration_k(tails, num_tours))
