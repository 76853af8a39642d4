"""Multi-start local optimisation with optimistix: one compiled, `vmap`ped solve from many starts.

Used by the searches for the constants of a Restore process (`restore._bounds`) and by the
mode finder of the Laplace mixtures (`restore.regeneration.find_modes`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, ArrayLike, Float

from ._compile import jit
from ._validation import as_float_array, check_integer, check_scalar_fn

ScalarFn = Callable[[Float[Array, " d"]], Float[Array, ""]]


class SearchResult(NamedTuple):
    """The outcome of `maximise`.

    Attributes:
        value: the largest finite value found (NaN when no start gave one).
        argmax: where it was found, shape `(d,)` (NaN when none).
        values: per start, the better finite value of the start itself and of
            the optimiser's end point (NaN when neither is finite), shape `(n,)`.
        argmaxes: the points of `values`, shape `(n, d)`.
        num_failed: how many optimisations ended at a non-finite point or a
            non-finite value (the start's own value still counts if finite).
        start_values: the function at every start, unfiltered, shape `(n,)`.
        end_values: the function at every end point, unfiltered, shape `(n,)`;
            with `start_values`, tells an infinite value (`+inf`) from a failure
            (`nan`).
    """

    value: float
    argmax: Float[Array, " d"]
    values: Float[Array, " n"]
    argmaxes: Float[Array, "n d"]
    num_failed: int
    start_values: Float[Array, " n"]
    end_values: Float[Array, " n"]


def default_solver(dtype: Any) -> optx.AbstractMinimiser:
    """BFGS with `rtol = atol = sqrt(machine epsilon)` of `dtype`."""
    tol = float(np.sqrt(np.finfo(dtype).eps))
    return optx.BFGS(rtol=tol, atol=tol)


def check_solver(solver: Any, dtype: Any) -> optx.AbstractMinimiser:
    """An optimistix minimiser, or the default one for `dtype` when `solver` is `None`."""
    if solver is None:
        return default_solver(dtype)
    if not isinstance(solver, optx.AbstractMinimiser):
        raise TypeError(f"`solver` must be an optimistix AbstractMinimiser, got {type(solver).__name__}.")
    return solver


def check_starts(starts: ArrayLike, *, finite: bool = True) -> Array:
    """Starting points: a non-empty floating `(n, d)` array, finite unless `finite=False`."""
    starts = as_float_array(starts, "starts")
    if starts.ndim != 2 or starts.shape[0] == 0 or starts.shape[1] == 0:
        raise ValueError(
            f"`starts` must be a non-empty 2-D array of shape (n, d) (one start per row), got shape {starts.shape}."
        )
    if finite and not np.all(np.isfinite(np.asarray(starts))):
        raise ValueError("`starts` must be finite (found NaN or inf entries).")
    return starts


def check_box(lower: ArrayLike, upper: ArrayLike, dtype: Any = None) -> tuple[Array, Array]:
    """A box `[lower, upper]`: finite 1-D corners of one shape `(d,)` with `lower < upper`."""
    lower, upper = as_float_array(lower, "lower"), as_float_array(upper, "upper")
    if dtype is None:
        dtype = jnp.result_type(lower.dtype, upper.dtype)
    # Checked on the host in numpy (no small XLA compilations).
    lo, hi = np.asarray(lower).astype(dtype), np.asarray(upper).astype(dtype)
    if lo.ndim != 1 or lo.shape[0] == 0 or lo.shape != hi.shape:
        raise ValueError(
            "`lower` and `upper` must be non-empty 1-D arrays of the same shape (d,), "
            f"got shapes {lo.shape} and {hi.shape}."
        )
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise ValueError("the box bounds `lower` and `upper` must be finite.")
    if not np.all(lo < hi):
        bad = np.nonzero(~(lo < hi))[0].tolist()
        raise ValueError(
            f"the box needs `lower < upper` in every coordinate; fails in coordinates {bad} "
            f"(lower={lo[bad].tolist()}, upper={hi[bad].tolist()})."
        )
    return jnp.asarray(lo), jnp.asarray(hi)


# Module-level and filter-jitted: the user's function (or an `eqx.Module`
# wrapping the user's functions) is a static argument hashed by identity, so a
# repeated call with the same functions, solver, box-or-not and shapes reuses
# the compilation.
@jit(filtered=True)
def solve(fn, solver, max_steps, starts, lower=None, upper=None):
    """Maximise `fn` from every row of `starts` (on the box `[lower, upper]` when given).

    Returns the values at the starts, the end points and the values at the end points.
    """
    bounded = lower is not None

    def to_y(z):
        if bounded:
            # Clipped: rounding must not put a point outside the box.
            return jnp.clip(lower + (upper - lower) * jax.nn.sigmoid(z), lower, upper)
        return z

    def objective(z, args):
        return -jnp.asarray(fn(to_y(z)), starts.dtype)

    if bounded:
        eps = jnp.finfo(starts.dtype).eps
        t = jnp.clip((starts - lower) / (upper - lower), eps, 1 - eps)
        z0 = jnp.log(t) - jnp.log1p(-t)
    else:
        z0 = starts

    def one(z):
        sol = optx.minimise(objective, solver, z, max_steps=max_steps, throw=False)
        return to_y(sol.value)

    ends = jax.vmap(one)(z0)
    value = jax.vmap(lambda y: jnp.asarray(fn(y), starts.dtype))
    return value(starts), ends, value(ends)


def maximise(
    fn: ScalarFn,
    starts: ArrayLike,
    *,
    lower: ArrayLike | None = None,
    upper: ArrayLike | None = None,
    max_steps: int = 256,
    solver: optx.AbstractMinimiser | None = None,
) -> SearchResult:
    """Maximise `fn` by local searches from many starts (optimistix BFGS).

    All starts are solved in one `vmap`ped, jitted `optx.minimise` of `-fn`
    (`throw=False`: a failed search does not raise). On a box the search runs
    in unconstrained coordinates `z`, with `y = lower + (upper - lower) *
    sigmoid(z)`, so every end point lies in the box (faces included, where the
    sigmoid saturates). Each start's result is the better of its own value and
    its end point's value, so the answer is never worse than the best start.
    Non-finite values (NaN, `+-inf`) count as failures and are ignored.

    This is a local search: it finds the global maximum only if some start
    lies in its basin of attraction. Spread the starts widely.

    Arguments:
        fn: maps one point `(d,)` to a real scalar; differentiable with JAX.
            Not jitted by the caller; it is jitted here (with the same `fn`,
            solver and shapes the compilation is reused).
        starts: starting points, shape `(n, d)`, finite (inside the box if one
            is given).
        lower: optional lower corner of a box to search in, shape `(d,)`.
        upper: optional upper corner, shape `(d,)`; give both or neither.
        max_steps: maximum number of BFGS steps per start.
        solver: an optimistix minimiser; defaults to BFGS with
            `rtol = atol = sqrt(machine epsilon)` of the dtype of `starts`.

    Returns:
        A `SearchResult`; its `value` is NaN when no finite value was found.

    Raises:
        ValueError: for malformed starts, box or options, or an `fn` that does
            not return a scalar.
        TypeError: if `fn` is not callable, `solver` is not an optimistix
            minimiser, or `max_steps` is not a number.
    """
    starts = check_starts(starts)
    n, d = starts.shape
    if (lower is None) != (upper is None):
        raise ValueError("give both `lower` and `upper` (a box), or neither.")
    if lower is not None and upper is not None:
        lower, upper = check_box(lower, upper, starts.dtype)
        if lower.shape != (d,):
            raise ValueError(f"the box has dimension {lower.shape[0]} but the starts have dimension {d}.")
        s, lo, hi = np.asarray(starts), np.asarray(lower), np.asarray(upper)
        outside = np.any((s < lo) | (s > hi), axis=1)
        if outside.any():
            raise ValueError(
                f"{int(outside.sum())} of {n} starts lie outside the box [lower, upper] "
                f"(first: row {int(np.argmax(outside))})."
            )
    check_scalar_fn(fn, d, starts.dtype, "fn")
    max_steps = check_integer(max_steps, "max_steps")
    solver = check_solver(solver, starts.dtype)

    return search(fn, solver, max_steps, starts, lower, upper)[0]


def search(fn, solver, max_steps, starts, lower, upper) -> tuple[SearchResult, np.ndarray]:
    """Run `solve` and summarise; also return the raw end points, shape `(n, d)`."""
    start_values, ends, end_values = jax.device_get(solve(fn, solver, max_steps, starts, lower, upper))
    result = summarise(np.asarray(starts), start_values, ends, end_values, starts.dtype)
    return result, np.asarray(ends)


def summarise(starts, start_values, ends, end_values, dtype) -> SearchResult:
    """Per start, keep the better finite of (start, end); then the overall best (host)."""
    start_values = np.asarray(start_values, dtype=np.float64)
    end_values = np.asarray(end_values, dtype=np.float64)
    ends = np.asarray(ends, dtype=np.float64)
    starts = np.asarray(starts, dtype=np.float64)
    end_ok = np.isfinite(end_values) & np.all(np.isfinite(ends), axis=1)
    start_ok = np.isfinite(start_values)
    s_val = np.where(start_ok, start_values, -np.inf)
    e_val = np.where(end_ok, end_values, -np.inf)
    use_end = end_ok & (e_val >= s_val)
    values = np.where(use_end, e_val, np.where(start_ok, s_val, np.nan))
    argmaxes = np.where(use_end[:, None], ends, starts)
    if np.any(np.isfinite(values)):
        i = int(np.nanargmax(values))
        value, argmax = float(values[i]), argmaxes[i]
    else:
        value, argmax = math.nan, np.full(starts.shape[1], np.nan)
    return SearchResult(
        value=value,
        argmax=jnp.asarray(argmax, dtype),
        values=jnp.asarray(values, dtype),
        argmaxes=jnp.asarray(argmaxes, dtype),
        num_failed=int(np.sum(~end_ok)),
        start_values=jnp.asarray(start_values, dtype),
        end_values=jnp.asarray(end_values, dtype),
    )
