"""Multi-start searches for the constants of a Restore process.

A Restore process kills its local dynamics at the rate

    gamma(y) = a(y) + c_tilde q(y) / p(y),      a = (L^* p) / p,

with `p` the unnormalised target, `q` the reference (regeneration) density and
`a` the generator adjoint ratio of the local dynamics (zero when they leave the
target invariant). Two constants must be searched for:

- `minimal_log_rate`: the smallest `c_tilde` with `gamma >= 0`, i.e.
  `sup_y (-a(y) p(y) / q(y))` over `{a < 0}`;
- `rate_bound`: a thinning bound `Gamma >= sup gamma` over a box.

Both are multi-start local searches (`restore._multistart`, optimistix BFGS) from the
given starts: they find lower bounds on the true suprema, never proofs.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from ._multistart import ScalarFn, check_box, check_starts, default_solver, search, solve
from ._random import uniform_draws
from ._validation import check_integer, check_scalar_fn


class MinimalRate(NamedTuple):
    """The outcome of `minimal_log_rate`.

    Attributes:
        log_rate: `log_sup + margin`, the suggested lower limit for `log c_tilde`;
            `-inf` when no point with `a < 0` was found (then any `c_tilde > 0`
            keeps `gamma >= 0` at every point searched).
        argmax: the point where `-a p / q` was largest, shape `(d,)` (NaN when
            `log_sup == -inf`).
        num_negative_starts: how many starts have `a < 0` (and a finite
            objective); the others were first moved towards `{a < 0}`.
        log_sup: the searched `log sup (-a p / q)`, without the margin.
        num_failed: how many local searches that started at a finite objective
            ended at a non-finite one (optimiser failures or NaN values).
    """

    log_rate: float
    argmax: Float[Array, " d"]
    num_negative_starts: int
    log_sup: float
    num_failed: int


class RateBound(NamedTuple):
    """The outcome of `rate_bound`.

    Attributes:
        bound: `safety * sup_found`, a thinning bound `Gamma` for the box.
        argmax: where the largest rate was found, shape `(d,)`.
        sup_found: the largest rate found in the box (a lower bound on the sup).
    """

    bound: float
    argmax: Float[Array, " d"]
    sup_found: float


# --------------------------------------------------------------------------- #
# minimal_log_rate
# --------------------------------------------------------------------------- #


class _RateObjective(eqx.Module):
    """The two objectives of `minimal_log_rate`, chosen by a traced flag so that
    both phases share one compilation (`lax.cond`: only one branch runs, so a
    NaN in the other cannot leak into gradients).

    - `log_phase=False`: `-max(a, 0)`, flat (zero gradient) on `{a < 0}`, so a
      search from a point with `a >= 0` stops as soon as it enters `{a < 0}`;
    - `log_phase=True`: `log(-a) + log p - log q` on `{a < 0}`, `-inf` elsewhere.
    """

    logdensity: ScalarFn
    adjoint_ratio: ScalarFn
    log_reference: ScalarFn
    log_phase: Array

    def __call__(self, y):
        # Local closures, not bound methods: `lax.cond` hashes its branches, and
        # a bound method would hash this module, whose `log_phase` is traced.
        def towards_negative(y):
            return -jax.nn.relu(jnp.asarray(self.adjoint_ratio(y), y.dtype))

        def log_deficit(y):
            a = jnp.asarray(self.adjoint_ratio(y), y.dtype)
            negative = a < 0
            log_p = jnp.asarray(self.logdensity(y), y.dtype)
            log_q = jnp.asarray(self.log_reference(y), y.dtype)
            value = jnp.log(jnp.where(negative, -a, 1.0)) + log_p - log_q
            return jnp.where(negative, value, -jnp.inf)

        return jax.lax.cond(self.log_phase, log_deficit, towards_negative, y)


def minimal_log_rate(
    logdensity: ScalarFn,
    adjoint_ratio: ScalarFn,
    log_reference: ScalarFn,
    starts: ArrayLike,
    *,
    margin: float = 0.0,
    max_steps: int = 256,
) -> MinimalRate:
    """Search for the smallest `c_tilde` that keeps the kill rate non-negative.

    The kill rate `gamma = a + c_tilde q / p` is `>= 0` everywhere iff
    `c_tilde >= sup_y (-a(y) p(y) / q(y))` over `{a < 0}`. This maximises
    `log(-a) + log p - log q` over `{a < 0}` in two local phases:
    first every start with `a >= 0` is moved downhill on `a` until it enters
    `{a < 0}` (starts already there stay put), then the log objective is
    maximised (`maximise`) from the starts and from those entry points.

    This is a search from the given starts, not a proof: the result is a
    *lower bound* on the safe value of `log c_tilde`. Regions of `{a < 0}`
    that no start reaches are missed. Add a `margin`, and rely on the sampler,
    which still checks `gamma >= 0` at run time and reports violations.

    When `a >= 0` at every start and every end point, `log_rate` is `-inf`:
    no point that needs a minimum was found, and any `c_tilde > 0` keeps
    `gamma >= 0` there (for invariant local dynamics `a = 0` and this is exact).

    Arguments:
        logdensity: `log p`, the unnormalised log target, one point `(d,)` ->
            scalar.
        adjoint_ratio: `a = (L^* p) / p`, the generator adjoint ratio of the
            local dynamics, one point -> real scalar (any sign).
        log_reference: `log q`, the log regeneration density, one point ->
            scalar.
        starts: starting points, shape `(n, d)`; spread them over the region
            where the target lives and beyond.
        margin: a safety margin `>= 0` added in log space
            (`log_rate = log_sup + margin`, i.e. `c_tilde` times `exp(margin)`).
        max_steps: maximum number of BFGS steps per start and phase.

    Returns:
        A `MinimalRate`.

    Raises:
        ValueError: for malformed inputs, or when `-a p / q` is infinite at a
            point found (e.g. `q = 0` where `a < 0`): then no finite
            `c_tilde` keeps `gamma >= 0`.
        TypeError: if one of the functions is not callable.
    """
    starts = check_starts(starts)
    d = starts.shape[1]
    for fn, name in (
        (logdensity, "logdensity"),
        (adjoint_ratio, "adjoint_ratio"),
        (log_reference, "log_reference"),
    ):
        check_scalar_fn(fn, d, starts.dtype, name)
    margin = float(margin)
    if not (math.isfinite(margin) and margin >= 0):
        raise ValueError(f"`margin` must be finite and >= 0, got {margin}.")
    max_steps = check_integer(max_steps, "max_steps")
    solver = default_solver(starts.dtype)

    def objective(log_phase: bool) -> _RateObjective:
        return _RateObjective(logdensity, adjoint_ratio, log_reference, jnp.asarray(log_phase))

    # Phase 1: move the starts with a >= 0 into {a < 0}, where possible. Starts
    # with a <= 0 (phase-1 value 0) stay where they are.
    values1, ends1, _ = jax.device_get(solve(objective(False), solver, max_steps, starts, None, None))
    s = np.asarray(starts)
    stay = np.asarray(values1) == 0
    ends1 = np.asarray(ends1)
    move = ~stay & np.all(np.isfinite(ends1), axis=1)
    entries = jnp.asarray(np.where(move[:, None], ends1, s), starts.dtype)
    # Phase 2: maximise the log objective from the starts in {a < 0} and the entry points.
    start_values, ends, end_values = jax.device_get(solve(objective(True), solver, max_steps, entries, None, None))
    start_values = np.asarray(start_values, dtype=np.float64)
    end_values = np.asarray(end_values, dtype=np.float64)
    ends = np.asarray(ends, dtype=np.float64)
    points = np.asarray(entries, dtype=np.float64)

    all_values = np.concatenate([start_values, end_values])
    all_points = np.concatenate([points, ends])
    finite_point = np.all(np.isfinite(all_points), axis=1)
    infinite = finite_point & (all_values == np.inf)
    if infinite.any():
        y = all_points[np.argmax(infinite)]
        raise ValueError(
            f"-a p / q is infinite at y = {y.tolist()} (a < 0 where the reference density q "
            "vanishes or the target p is infinite): no finite c_tilde keeps the kill rate "
            "non-negative. Use a reference density with support (and tails) covering the region "
            "where a < 0."
        )
    num_negative = int(np.sum(stay & np.isfinite(start_values)))
    # A failure: a search that started at a finite objective but ended non-finite.
    end_ok = np.isfinite(end_values) & np.all(np.isfinite(ends), axis=1)
    num_failed = int(np.sum(np.isfinite(start_values) & ~end_ok))

    usable = finite_point & np.isfinite(all_values)
    if usable.any():
        i = int(np.argmax(np.where(usable, all_values, -np.inf)))
        log_sup, argmax = float(all_values[i]), all_points[i]
    else:
        log_sup, argmax = -math.inf, np.full(d, np.nan)
    return MinimalRate(
        log_rate=log_sup + margin,
        argmax=jnp.asarray(argmax, starts.dtype),
        num_negative_starts=num_negative,
        log_sup=log_sup,
        num_failed=num_failed,
    )


# --------------------------------------------------------------------------- #
# rate_bound
# --------------------------------------------------------------------------- #


def rate_bound(
    kill_rate: ScalarFn,
    lower: ArrayLike,
    upper: ArrayLike,
    *,
    key: PRNGKeyArray,
    num_starts: int = 64,
    safety: float = 2.0,
    max_steps: int = 256,
) -> RateBound:
    """A thinning bound `Gamma >= sup gamma` over the box `[lower, upper]`.

    Maximises `kill_rate` over the box (`maximise` with the sigmoid
    reparametrisation) from `num_starts` points drawn uniformly in the box with
    `key`, plus the box centre, and returns `safety` times the largest rate
    found. The search finds a lower bound on the sup, hence the safety factor;
    a thinning sampler must still count candidates with `gamma > Gamma`.

    For diffusions `gamma` is usually unbounded on `R^d` (it grows with
    `|grad log p|^2`), so a bound only exists on a bounded region.

    Arguments:
        kill_rate: `gamma`, one point `(d,)` -> a real scalar `>= 0` (the rate
            itself, not its log); differentiable with JAX.
        lower: lower corner of the box, shape `(d,)`.
        upper: upper corner of the box, shape `(d,)`, with `lower < upper`.
        key: a JAX PRNG key for the random starts.
        num_starts: how many uniform random starts (the centre is added).
        safety: factor `>= 1` multiplying the sup found.
        max_steps: maximum number of BFGS steps per start.

    Returns:
        A `RateBound`.

    Raises:
        ValueError: for a malformed box or options, or when the rate is not
            finite at some point of the box (infinite or NaN, e.g. where the
            target density vanishes): choose a smaller region.
        TypeError: if `kill_rate` is not callable.
    """
    lower, upper = check_box(lower, upper)
    d = lower.shape[0]
    num_starts = check_integer(num_starts, "num_starts", minimum=0)
    safety = float(safety)
    if not (math.isfinite(safety) and safety >= 1):
        raise ValueError(f"`safety` must be finite and >= 1, got {safety}.")
    draws = np.asarray(uniform_draws(key, (int(num_starts), d), lower.dtype))
    lo, hi = np.asarray(lower), np.asarray(upper)
    starts = jnp.asarray(np.clip(np.concatenate([lo + (hi - lo) * draws, (0.5 * (lo + hi))[None]]), lo, hi))
    max_steps = check_integer(max_steps, "max_steps")
    check_scalar_fn(kill_rate, d, starts.dtype, "kill_rate")
    solver = default_solver(starts.dtype)
    result, ends = search(kill_rate, solver, max_steps, starts, lower, upper)

    # The rate must be finite at every point of the box that was evaluated; an end
    # point that is itself non-finite is an optimiser failure, not a property of the rate.
    values = np.concatenate([np.asarray(result.start_values), np.asarray(result.end_values)])
    points = np.concatenate([np.asarray(starts), ends])
    bad = ~np.isfinite(values) & np.all(np.isfinite(points), axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise ValueError(
            f"the kill rate is {values[i]} at y = {points[i].tolist()} inside the box "
            f"[{np.asarray(lower).tolist()}, {np.asarray(upper).tolist()}]: it has no finite "
            "bound there (e.g. the target density vanishes). Choose a smaller region."
        )
    sup = result.value
    if not math.isfinite(sup):
        raise ValueError("no finite kill rate was found in the box; choose a smaller region.")
    if sup < 0:
        raise ValueError(
            f"the kill rate is negative everywhere searched (largest {sup}); a kill rate must be "
            ">= 0 (raise c_tilde, see `minimal_log_rate`)."
        )
    return RateBound(bound=safety * sup, argmax=result.argmax, sup_found=sup)
