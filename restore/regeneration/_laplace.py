"""Laplace-approximation mixtures: regeneration distributions built from the
modes of the target found by multi-start optimisation."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Literal, final

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, ArrayLike, Float, Int

from .._compile import jit
from .._multistart import check_solver, check_starts, solve
from .._validation import check_integer, check_scalar_fn
from ._gaussian import Gaussian
from ._mixture import Mixture
from ._student_t import StudentT

# A converged optimum must satisfy sqrt(g^T Sigma g) < this, i.e. the remaining
# Newton step is below this many posterior standard deviations.
_NEWTON_DECREMENT_TOL = 0.1
_DEFAULT_MERGE_TOL = 1.0


@final
class LaplaceModes(eqx.Module):
    """The distinct local maxima of a log density and their Laplace approximations.

    Modes are sorted by decreasing log density.

    Attributes:
        locations: the modes `m_k`, shape `(k, d)`.
        covariances: `(-Hessian of logdensity at m_k)^{-1}`, symmetrised, shape
            `(k, d, d)` (not multiplied by any proposal `scale`).
        log_densities: `logdensity(m_k)`, shape `(k,)`.
        counts: how many starts converged to each mode, shape `(k,)`.
        num_failed: how many starts were discarded (failed or non-finite
            optimisation, or a Hessian that is not negative definite).
    """

    locations: Float[Array, "k d"]
    covariances: Float[Array, "k d d"]
    log_densities: Float[Array, " k"]
    counts: Int[Array, " k"]
    num_failed: int = eqx.field(static=True)

    @property
    def num_modes(self) -> int:
        """The number `k` of distinct modes."""
        return self.locations.shape[0]

    @property
    def log_evidences(self) -> Float[Array, " k"]:
        """Laplace evidence of each mode, `log p(m_k) + 0.5 log det(2 pi Sigma_k)`."""
        d = self.locations.shape[1]
        _, logdet = jnp.linalg.slogdet(self.covariances)
        return self.log_densities + 0.5 * (logdet + d * math.log(2 * math.pi))

    def _log_evidences_np(self) -> np.ndarray:
        d = self.locations.shape[1]
        _, logdet = np.linalg.slogdet(np.asarray(self.covariances, dtype=np.float64))
        logp = np.asarray(self.log_densities, dtype=np.float64)
        return logp + 0.5 * (logdet + d * math.log(2 * math.pi))


@jit(filtered=True, once=True)
def _local_expansion(logdensity, ys):
    """Log density, gradient and Hessian at every row of `ys`."""

    def one(y):
        return logdensity(y), jax.grad(logdensity)(y), jax.hessian(logdensity)(y)

    return jax.vmap(one)(ys)


def _verify(ys, logps, grads, hessians):
    """Second-order check of candidate optima (host-side, float64).

    Returns `(ok, logps, covs, prec_chols, newton_steps)`: `ok[i]` is True when
    everything is finite, `-H` is positive definite (Cholesky succeeds) and the
    Newton decrement `sqrt(g^T Sigma g)` is below `_NEWTON_DECREMENT_TOL`.
    `prec_chols[i]` is the Cholesky factor of `-H`, `covs[i] = (-H)^{-1}`, and
    `newton_steps[i] = Sigma g` (the step to the maximum of the local quadratic).
    """
    logps = np.array(logps, dtype=np.float64)
    grads = np.asarray(grads, dtype=np.float64)
    hessians = np.asarray(hessians, dtype=np.float64)
    n, d = ys.shape
    ok = np.all(np.isfinite(ys), axis=1) & np.isfinite(logps)
    ok &= np.all(np.isfinite(grads), axis=1)
    ok &= np.all(np.isfinite(hessians), axis=(1, 2))
    covs = np.full((n, d, d), np.nan)
    prec_chols = np.full((n, d, d), np.nan)
    steps = np.zeros((n, d))
    for i in np.nonzero(ok)[0]:
        try:
            chol = np.linalg.cholesky(-0.5 * (hessians[i] + hessians[i].T))
        except np.linalg.LinAlgError:
            ok[i] = False
            continue
        inv_chol = np.linalg.inv(chol)
        cov = inv_chol.T @ inv_chol
        cov = 0.5 * (cov + cov.T)
        z = inv_chol @ grads[i]
        if not (np.all(np.isfinite(cov)) and math.sqrt(float(z @ z)) < _NEWTON_DECREMENT_TOL):
            ok[i] = False
            continue
        covs[i], prec_chols[i], steps[i] = cov, chol, cov @ grads[i]
    return ok, logps, covs, prec_chols, steps


def find_modes(
    logdensity: Callable[[Float[Array, " d"]], Float[Array, ""]],
    starts: ArrayLike,
    *,
    merge_tol: float | None = None,
    solver: optx.AbstractMinimiser | None = None,
    max_steps: int = 256,
) -> LaplaceModes:
    """Locate the local maxima of `logdensity` by multi-start optimisation.

    From every start, `-logdensity` is minimised with optimistix (all starts in
    one `vmap`ped, jitted solve, `throw=False`). Every end point is then
    verified on the host rather than trusting the solver status alone
    (optimistix's backtracking line search can stall exactly at an optimum,
    e.g. of a locally quadratic target, and report `max_steps` reached): a start
    is discarded when the end point, its log density, gradient or Hessian is
    non-finite, when the negative Hessian is not positive definite (Cholesky
    fails: a saddle, a minimum or a flat direction), or when the remaining
    Newton step `sqrt(g^T Sigma g)` exceeds 0.1 standard deviations (the solver
    did not get close to a maximum). Surviving points are polished with one
    Newton step, kept only if it does not decrease the log density and passes
    the same check. The covariance of each optimum is `Sigma = (-H)^{-1}`, with
    `H` the symmetrised `jax.hessian` of `logdensity`.

    Duplicates are merged on the host: optima are visited by decreasing log
    density and one is dropped (counted towards the earlier mode) if its
    Mahalanobis distance `sqrt(r^T Sigma_k^{-1} r)` to an already kept mode `k`
    is below `merge_tol`.

    Arguments:
        logdensity: the (unnormalised) log target; maps one point `(d,)` to a
            scalar. Must be differentiable twice with JAX.
        starts: starting points, shape `(n, d)`; spread them widely (e.g. over
            a box containing the typical set) so that every mode attracts some.
        merge_tol: Mahalanobis radius under which two optima are the same mode.
            Defaults to 1.0; 0 disables merging.
        solver: an optimistix minimiser; defaults to
            `optx.BFGS(rtol=tol, atol=tol)` with `tol = sqrt(machine epsilon)`
            of the dtype of `starts`.
        max_steps: maximum number of solver steps per start.

    Returns:
        A `LaplaceModes`.

    Raises:
        ValueError: if `starts` is not a non-empty `(n, d)` array, `logdensity`
            does not return a real scalar, the options are invalid, or no
            optimisation succeeded.
        TypeError: if `logdensity` is not callable, `solver` is not an optimistix
            minimiser or `max_steps` is not a number.
    """
    # Non-finite starts are allowed: their searches fail and count in `num_failed`.
    starts = check_starts(starts, finite=False)
    n, d = starts.shape
    check_scalar_fn(logdensity, d, starts.dtype, "logdensity")
    merge_tol = _DEFAULT_MERGE_TOL if merge_tol is None else float(merge_tol)
    if not (merge_tol >= 0 and math.isfinite(merge_tol)):
        raise ValueError(f"`merge_tol` must be finite and >= 0, got {merge_tol}.")
    max_steps = check_integer(max_steps, "max_steps")
    solver = check_solver(solver, starts.dtype)

    # Optimise, then verify (and polish with one Newton step) on the host.
    _, ends, _ = solve(logdensity, solver, max_steps, starts)
    ys = np.array(jax.device_get(ends))
    ys = ys.astype(np.float64)
    expansion = _local_expansion(logdensity, jnp.asarray(ys, starts.dtype))
    ok, logps, covs, prec_chols, steps = _verify(ys, *expansion)
    ys_new = np.where(ok[:, None], ys + steps, ys)
    expansion = _local_expansion(logdensity, jnp.asarray(ys_new, starts.dtype))
    ok_new, logps_new, covs_new, chols_new, _ = _verify(ys_new, *expansion)
    better = ok & ok_new & (logps_new >= logps)
    ys[better], logps[better] = ys_new[better], logps_new[better]
    covs[better], prec_chols[better] = covs_new[better], chols_new[better]

    good = np.nonzero(ok)[0]
    if good.size == 0:
        raise ValueError(
            f"No optimisation out of {n} starts reached a local maximum with a "
            "finite, negative-definite Hessian. Widen the spread of `starts`, use "
            "more of them, or increase `max_steps`."
        )

    # Merge duplicates, best first, in the metric of the kept mode.
    order = good[np.argsort(-logps[good], kind="stable")]
    kept: list[int] = []
    counts: list[int] = []
    for i in order:
        for j, k in enumerate(kept):
            z = prec_chols[k].T @ (ys[i] - ys[k])
            if math.sqrt(float(z @ z)) < merge_tol:
                counts[j] += 1
                break
        else:
            kept.append(int(i))
            counts.append(1)

    dtype = starts.dtype
    kept_idx = np.asarray(kept)
    return LaplaceModes(
        locations=jnp.asarray(ys[kept_idx], dtype=dtype),
        covariances=jnp.asarray(covs[kept_idx], dtype=dtype),
        log_densities=jnp.asarray(logps[kept_idx], dtype=dtype),
        counts=jnp.asarray(counts, dtype=int),
        num_failed=int(n - good.size),
    )


def _check_mixture_options(tails, df, scale, weights, defensive):
    """Validate the options of `mixture_from_modes`; return `(df, scale, defensive)`."""
    if tails not in ("gaussian", "student_t"):
        raise ValueError(f"`tails` must be 'gaussian' or 'student_t', got {tails!r}.")
    if weights not in ("equal", "laplace"):
        raise ValueError(f"`weights` must be 'equal' or 'laplace', got {weights!r}.")
    scale = float(scale)
    if not (math.isfinite(scale) and scale > 0):
        raise ValueError(f"`scale` must be finite and strictly positive, got {scale}.")
    df = float(df)
    if not (math.isfinite(df) and df > 0):
        raise ValueError(f"`df` must be finite and strictly positive, got {df}.")
    if defensive is not None:
        defensive = float(defensive)
        if not 0 < defensive < 1:
            raise ValueError(f"`defensive` must lie in (0, 1), got {defensive}.")
    return df, scale, defensive


def mixture_from_modes(
    modes: LaplaceModes,
    *,
    tails: Literal["gaussian", "student_t"] = "gaussian",
    df: float = 4.0,
    scale: float = 1.0,
    weights: Literal["equal", "laplace"] = "equal",
    defensive: float | None = None,
) -> Mixture:
    """Build the Laplace mixture regeneration distribution from found modes.

    See `laplace_mixture` for the meaning of the arguments.

    Arguments:
        modes: the output of `find_modes`.
        tails: `"gaussian"` or `"student_t"` components.
        df: degrees of freedom of Student-t components.
        scale: factor multiplying the Laplace standard deviations.
        weights: `"equal"` or `"laplace"` (Laplace evidence) weights.
        defensive: optional weight in (0, 1) of an extra broad component.

    Raises:
        TypeError: if `modes` is not a `LaplaceModes`.
        ValueError: for invalid options.
    """
    if not isinstance(modes, LaplaceModes):
        raise TypeError(
            f"`modes` must be a LaplaceModes (from find_modes), got {type(modes).__name__}."
        )
    df, scale, defensive = _check_mixture_options(tails, df, scale, weights, defensive)

    locs = np.asarray(modes.locations, dtype=np.float64)
    covs = np.asarray(modes.covariances, dtype=np.float64) * scale**2
    k = locs.shape[0]
    if weights == "equal":
        w = np.full(k, 1.0 / k)
    else:
        log_ev = modes._log_evidences_np()
        w = np.exp(log_ev - log_ev.max())
        w = w / w.sum()

    def make(loc, cov):
        if tails == "gaussian":
            return Gaussian(loc, cov)
        return StudentT(loc, cov, df)

    dtype = modes.locations.dtype
    components = [
        make(jnp.asarray(m, dtype), jnp.asarray(c, dtype)) for m, c in zip(locs, covs)
    ]
    if defensive is not None:
        mean = w @ locs
        r = locs - mean
        cov = np.einsum("k,ki,kj->ij", w, r, r) + np.einsum("k,kij->ij", w, covs)
        cov = 0.5 * (cov + cov.T)
        components.append(make(jnp.asarray(mean, dtype), jnp.asarray(cov, dtype)))
        w = np.append((1.0 - defensive) * w, defensive)
    # Keep the weights strictly positive even if some evidence underflows.
    w = np.maximum(w, np.finfo(np.float64).tiny)
    return Mixture(components, jnp.asarray(w, dtype))


def laplace_mixture(
    logdensity: Callable[[Float[Array, " d"]], Float[Array, ""]],
    starts: ArrayLike,
    *,
    tails: Literal["gaussian", "student_t"] = "gaussian",
    df: float = 4.0,
    scale: float = 1.0,
    weights: Literal["equal", "laplace"] = "equal",
    merge_tol: float | None = None,
    solver: optx.AbstractMinimiser | None = None,
    max_steps: int = 256,
    defensive: float | None = None,
) -> Mixture:
    """A mixture of Laplace approximations at the modes of `logdensity`.

    Runs `find_modes` (multi-start optimisation, Hessian check, merging of
    duplicates) and places one component at every distinct mode `m_k`, with
    location `m_k` and covariance / scale matrix `scale**2 * Sigma_k`, where
    `Sigma_k` is the inverse negative Hessian at `m_k`. Use `find_modes` and
    `mixture_from_modes` directly to inspect the modes before building.

    Arguments:
        logdensity: the (unnormalised) log target, one point `(d,)` -> scalar.
        starts: starting points for the optimiser, shape `(n, d)`.
        tails: `"gaussian"` for Gaussian components, `"student_t"` for
            multivariate t components with the same location and scale matrix
            and `df` degrees of freedom (heavier tails keep the Restore kill
            rate `u / p` bounded for more targets; safer).
        df: degrees of freedom of the Student-t components (and of the
            defensive component when `tails="student_t"`).
        scale: multiplies every Laplace standard deviation; `scale > 1` gives
            wider, safer proposals.
        weights: `"equal"` (1/k each) or `"laplace"`, proportional to the
            Laplace evidence `p(m_k) sqrt(det(2 pi Sigma_k))` (computed in log
            space; estimates the probability mass of each mode).
        merge_tol: Mahalanobis radius under which two optima count as the same
            mode (default 1.0).
        solver: an optimistix minimiser (default BFGS, see `find_modes`).
        max_steps: maximum optimiser steps per start.
        defensive: optional weight in (0, 1) of one extra broad component that
            guards against missed modes. It has the same family as `tails`,
            location `mbar = sum_k w_k m_k` and covariance / scale matrix
            `sum_k w_k (m_k - mbar)(m_k - mbar)^T + sum_k w_k scale**2 Sigma_k`
            (the covariance of the Gaussian mode mixture); the other weights are
            multiplied by `1 - defensive`.

    Returns:
        A `Mixture` of `Gaussian` or `StudentT` components.

    Raises:
        ValueError: for bad inputs, or if no optimisation succeeded.
    """
    # Check the cheap options before the (expensive) optimisation.
    _check_mixture_options(tails, df, scale, weights, defensive)
    modes = find_modes(
        logdensity, starts, merge_tol=merge_tol, solver=solver, max_steps=max_steps
    )
    return mixture_from_modes(
        modes, tails=tails, df=df, scale=scale, weights=weights, defensive=defensive
    )
