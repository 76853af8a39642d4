"""The renderer interface: functional `init` / `step` over NamedTuple states, plus tallies.

A renderer state is a NamedTuple with (at least) two fields the driver relies on:
- `params`: constants fixed at `init` (e.g. the kill-rate constant, a bootstrap `Z`).
- `tally`: a NamedTuple of additive sums (the film `(P, 3)` and event counts). Sums are
  additive over steps, so the driver moves them to float64 host totals after every
  chunk and zeroes them on the device: float32 films and int32 counts never have to
  hold more than one chunk.
The image is `scale(params, totals) * film`, a formula written with arithmetic operators
only so it works on device arrays (inside `jit`) and on NumPy host totals alike.
`statistics(params, totals)` reads the diagnostics off the host totals into a typed record,
a `RenderStatistics`.
"""

from __future__ import annotations

import abc
import dataclasses
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int, PRNGKeyArray

from .._chunk import run_steps
from .._estimates import UnreliableEstimateWarning
from .._point import Point
from .._warnings import warn
from ._film import film_image
from ._pss import evaluate_points

#: `warn_tail` warns when a renderer's tail shape is above this: PSIS's bound beyond which a
#: mean of such terms is unreliable even with many of them.
TAIL_WARNING = 0.7


def xp_of(*arrays):
    """`jax.numpy` if any argument is a JAX array, else NumPy."""
    return jnp if any(isinstance(a, jax.Array) for a in arrays) else np


def ratio(num, den):
    """`num / den`, NaN where `den == 0` (no data yet), for JAX or NumPy arrays."""
    xp = xp_of(num, den)
    den = xp.asarray(den)
    return xp.where(den != 0, num / xp.where(den != 0, den, 1), xp.nan)


def check_lanes(lanes: Any) -> int:
    if isinstance(lanes, bool) or not isinstance(lanes, (int, np.integer)) or lanes < 1:
        raise ValueError(f"lanes must be a positive integer, got {lanes!r}")
    return int(lanes)


def check_count(value: Any, name: str, minimum: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def zero_tally(state):
    """The state with its tally zeroed (after the driver has drained it)."""
    return state._replace(tally=jax.tree.map(jnp.zeros_like, state.tally))


def host_tally_dtype(x):
    """The host dtype a device tally leaf is summed in: float64 for floats, int64 otherwise."""
    return np.float64 if jnp.issubdtype(x.dtype, jnp.floating) else np.int64


def host_tally(tally, total=None):
    """Add a device tally to float64 / int64 host totals (or start them)."""
    as_host = lambda x: np.asarray(x, host_tally_dtype(x))  # noqa: E731
    tally = jax.tree.map(as_host, tally)
    return tally if total is None else jax.tree.map(np.add, total, tally)


def host_params(params):
    """Renderer constants as float64 NumPy scalars (for exact host-side formulas)."""
    return jax.tree.map(lambda x: np.asarray(x, np.float64), params)


def lane_keys(key: PRNGKeyArray, n: int) -> PRNGKeyArray:
    """The `n` lanes' keys of a step, `split(key, n)`, computed once (an optimisation barrier).

    Without the barrier XLA fuses the split into the kernels that draw from each lane's key,
    and hashes the lane's key again for every word they draw, which makes the Metropolis
    Restore and PSSMLT steps measurably slower (`docs/benchmarks.md`). The bits are the same.
    (`restore.sample`'s loop, which derives its lane keys by `fold_in`, showed no such gain,
    so the core step has no barrier.)
    """
    return jax.lax.optimization_barrier(jax.random.split(key, n))


def bootstrap_points(target, key: PRNGKeyArray, num: int, batch: int, with_grad: bool = False) -> Point:
    """`num` uniform points (rounded up to whole batches) evaluated in batches of at most
    `batch` lanes (one batch call at a time), as one `Point` of arrays."""
    size = min(num, batch)
    chunks = -(-num // size)
    u = jax.random.uniform(key, (chunks * size * target.dim,), jnp.float32).reshape(chunks, size, target.dim)
    point = jax.lax.map(lambda v: evaluate_points(target, v, with_grad), u)
    return jax.tree.map(lambda x: x.reshape((chunks * size,) + x.shape[2:]), point)


def resample(key: PRNGKeyArray, weights: Float[Array, " B"], n: int) -> Int[Array, " n"]:
    """`n` i.i.d. indices drawn with probability proportional to `weights` (inverse CDF:
    `O(B + n log B)`, where `jax.random.categorical` would draw `n x B` Gumbel variables)."""
    cumulative = jnp.cumsum(weights)
    u = jax.random.uniform(key, (n,), cumulative.dtype) * cumulative[-1]
    return jnp.clip(jnp.searchsorted(cumulative, u, side="right"), 0, weights.shape[0] - 1)


def bootstrap_size(num: int, lanes: int) -> int:
    """The number of evaluations `bootstrap_points` makes."""
    size = min(num, lanes)
    return -(-num // size) * size


@dataclasses.dataclass(frozen=True)
class RenderStatistics:
    """A renderer's diagnostics: a frozen record of Python numbers, one subclass per renderer
    family (`RestoreStatistics`, `PSSMLTStatistics`, `ERPTStatistics`, `UniformStatistics`).

    Read the fields as attributes (`result.statistics.tours_completed`); `as_dict()` gives
    them by name, for tables and logs. Rates and ratios are NaN where there is no data yet.
    """

    def as_dict(self) -> dict[str, float]:
        """The fields by name, in declaration order."""
        return {field.name: getattr(self, field.name) for field in dataclasses.fields(self)}

    def tail_warning(self) -> str | None:
        """What `render` warns (`UnreliableEstimateWarning`) when a few samples decide the image:
        the renderer's tail shape is above `TAIL_WARNING`; None otherwise, and by default."""
        return None


class AbstractRenderer(eqx.Module):
    """A PSS renderer: `init(target, key, lanes)`, `step(target, key, state)`, `image`.

    Structural choices (mutation, tour length, chain length) are fields of the module;
    the target is passed to every call so that renderers stay small pytrees and one
    renderer serves many targets. `step` evaluates the target a fixed number of times,
    `step_cost(lanes)`, so budgets in evaluations are exact.
    """

    uses_gradient: ClassVar[bool] = False
    #: the field of the renderer's statistics holding its tail shape (none by default)
    tail_statistic: ClassVar[str | None] = None
    #: whether `finish` has work to do after the budget (then `render` calls it)
    finishes: ClassVar[bool] = False

    @abc.abstractmethod
    def init(self, target, key: PRNGKeyArray, lanes: int):
        """A fresh state with `lanes` parallel lanes (costs `init_cost(lanes)` evaluations)."""

    @abc.abstractmethod
    def step(self, target, key: PRNGKeyArray, state):
        """One step of every lane (costs `step_cost(lanes)` evaluations)."""

    @abc.abstractmethod
    def init_cost(self, lanes: int) -> int:
        """Target evaluations made by `init`."""

    @abc.abstractmethod
    def step_cost(self, lanes: int) -> int:
        """Target evaluations made by one `step`."""

    @abc.abstractmethod
    def scale(self, target, params, tally):
        """The factor turning the film sum into the image estimate (see each renderer)."""

    @abc.abstractmethod
    def statistics(self, params, tally, state=None) -> RenderStatistics:
        """The renderer's diagnostics (acceptance rate, tours, ...) from host-side params and
        tally totals (`host_params`, `host_tally`). With the final `state` (after a render)
        they include the tail diagnostics read off the state (e.g. Restore's tail shape of
        the tour durations), NaN without it."""

    def warn_tail(self, statistics: RenderStatistics) -> None:
        """Warn (`UnreliableEstimateWarning`) when a few samples decide the image
        (`statistics.tail_warning()`)."""
        message = statistics.tail_warning()
        if message is not None:
            warn(message, UnreliableEstimateWarning)

    def check(self, params) -> None:
        """Raise `ValueError` if `init` found the target unusable (host-side, concrete params)."""

    def open_tours(self, state) -> int:
        """Lanes with unfinished work that `finish` must complete before the image is unbiased
        (host-side; 0 for renderers whose estimate is valid after any step)."""
        return 0

    def smallest_finishing_batch(self) -> int:
        """The smallest batch of points a finishing step evaluates (`render` compiles a program
        for each quarter of its first batch down to this one, and picks the smallest that holds
        the open tours): 256 by default."""
        return 256

    def stop_starting(self, state):
        """The state with no new work starting (before `finish`); unchanged by default."""
        return state

    def finish(self, target, key: PRNGKeyArray, state, max_steps=None, slots=None):
        """Complete the open work after the budget (e.g. Restore's open tours), each step
        evaluating `slots` points (default: one per lane); returns the state and the steps
        taken (at most `max_steps` if given). Nothing to do by default."""
        return state, jnp.zeros((), jnp.int32)

    def run(self, target, key: PRNGKeyArray, state, num_steps: Int[Array, ""] | int):
        """`num_steps` steps, the `i`-th with the key `fold_in(key, i)`, on the chunk runner
        of sampling and rendering (`restore._chunk.run_steps`: the count may be traced, so
        one program serves every chunk length)."""
        return run_steps(lambda i, s: self.step(target, jax.random.fold_in(key, i), s), state, num_steps)[0]

    def image(self, target, state, tally=None) -> Float[Array, "H W 3"]:
        """The image estimate `(H, W, 3)` from `state`, or from host `tally` totals (float64)."""
        if tally is None:
            params, tally = state.params, state.tally
        else:
            params = host_params(state.params)
        return film_image(tally.film, target.resolution, self.scale(target, params, tally))
