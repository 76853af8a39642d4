"""PSSMLT (Kelemen et al. 2002): parallel Metropolis chains on luminance with small and large steps."""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int, PRNGKeyArray

from .._pareto import pareto_k, tail_length
from .._point import Point
from ..local import AbstractLocalKernel, AbstractTorusMutation, KelemenMutation, TorusMetropolis, metropolis_accept
from ._film import empty_film, splat
from ._pss import (
    check_target,
    contributions,
    evaluate_points,
    frozen_coordinates,
    luminance,
    pixels,
    pss_logdensity,
    small_step,
)
from ._renderer import (
    TAIL_WARNING,
    AbstractRenderer,
    RenderStatistics,
    bootstrap_points,
    bootstrap_size,
    check_count,
    check_lanes,
    lane_keys,
    ratio,
    resample,
)


class PSSMLTParams(NamedTuple):
    """Constants: the bootstrap estimate `z_hat` of `Z`, its relative standard error, the
    number of bootstrap draws, and the bootstrap's largest luminances (for the tail shape)."""

    z_hat: Float[Array, ""]
    z_hat_error: Float[Array, ""]
    n_bootstrap: Float[Array, ""]
    largest_luminance: Float[Array, " M"]


class PSSMLTTally(NamedTuple):
    """Sums: film of expected-value splats, lane steps, acceptances (all and large steps), and
    the luminance of the large-step proposals (uniform draws: each is an unbiased `Z` sample)."""

    film: Float[Array, "P 3"]
    lane_steps: Int[Array, ""]
    accepted: Int[Array, ""]
    large_steps: Int[Array, ""]
    large_accepted: Int[Array, ""]
    large_luminance: Float[Array, ""]


class PSSMLTState(NamedTuple):
    """Each chain's current point (with its contribution `rgb / lum` as aux), constants and sums."""

    point: Point
    params: PSSMLTParams
    tally: PSSMLTTally


@dataclasses.dataclass(frozen=True)
class PSSMLTStatistics(RenderStatistics):
    """`PSSMLT`'s diagnostics (luminances in the target's units).

    Attributes:
        z_hat: `Z_hat`, the mean luminance of every uniform draw (the bootstrap's and the
            large-step proposals'), which sets the image's brightness.
        z_hat_relative_error: its relative standard error (trusted only where the luminance
            has a finite variance: see `z_k_hat`).
        z_bootstrap: the bootstrap's mean luminance alone.
        z_bootstrap_relative_error: its relative standard error.
        acceptance_rate: the fraction of all proposals accepted.
        large_step_acceptance: the fraction of large steps (uniform draws) accepted.
        small_step_acceptance: the fraction of small steps accepted.
        p_large: the probability of a large step.
        z_k_hat: the Pareto shape of the bootstrap's luminance tail (NaN with too few bright
            draws, or before the render's end); above `TAIL_WARNING` a few very bright paths
            decide `Z_hat`.
    """

    z_hat: float
    z_hat_relative_error: float
    z_bootstrap: float
    z_bootstrap_relative_error: float
    acceptance_rate: float
    large_step_acceptance: float
    small_step_acceptance: float
    p_large: float
    z_k_hat: float = math.nan

    def tail_warning(self) -> str | None:
        if not self.z_k_hat > TAIL_WARNING:
            return None
        return (
            "PSSMLT's estimate of the image's brightness Z_hat rests on a heavy-tailed luminance (tail shape "
            f"k_hat = {self.z_k_hat:.2f} > {TAIL_WARNING} over the bootstrap): a few very bright paths decide "
            f"it, and its relative error {self.z_hat_relative_error:.2g} is not to be trusted; raise "
            "n_bootstrap, or compare realisations"
        )


class PSSMLT(AbstractRenderer):
    """Primary-sample-space Metropolis light transport, one Metropolis chain per lane.

    Proposal: with probability `p_large` a uniform draw (large step), else the small step
    (which keeps the target's `frozen_coordinates`: on `MultiplexedBDPT` this is MMLT);
    both are symmetric, so the acceptance is `a = min(1, lum' / lum)`: the core's
    `restore.local.TorusMetropolis` kernel decides both. The small step may instead be a
    local kernel with its own Hastings test (`restore.local.TorusMALA`, Luan et al.'s
    MALA; `restore.local.TorusH2MC`, Li et al.'s H2MC), which then decides the small
    steps while the large steps keep `min(1, lum' / lum)`: each of the two is invariant,
    so their mixture is. Each step
    evaluates the target once per lane and splats the current state with weight `1 - a`
    and the proposal with weight `a` (expected-value splatting: the weights are the
    expectation of the next state's indicator, so `E[splat] = E[h(u_next)]`).

    `init` draws `n_bootstrap` uniform points: their mean luminance estimates `Z`, and the
    chains start at bootstrap points resampled in proportion to luminance (sampling
    importance resampling), so they start (approximately, to `O(1 / n_bootstrap)`) in
    the stationary law and need no burn-in (no start-up bias).

    Estimator: `I_j = W H Z_hat F_j / (lanes x steps)` with `F_j` the film of weighted
    `rgb / lum`. Each step's splat has expectation `E_p[rgb / lum 1{pixel = j}]` in
    stationarity, and `W H Z E_p[...] = I_j`. `Z_hat` is the mean luminance of the
    bootstrap and of every large-step proposal (all uniform draws), so its error keeps
    falling during the run instead of staying at the bootstrap's (`z_hat` in the
    statistics; `z_bootstrap` is the bootstrap's alone). Its relative error assumes a
    luminance of finite variance; `render` reports the Pareto shape `z_k_hat` of the
    bootstrap's luminance tail and warns above `TAIL_WARNING` (0.7), where a few very bright
    paths (caustics) decide `Z_hat`, and so the brightness of the whole image.

    The default `p_large = 0.3` is Kelemen et al.'s, the value PSSMLT is usually run with.

    Arguments:
        mutation: the small step: a symmetric torus mutation (default `KelemenMutation()`)
            or a local kernel on the torus (`TorusMALA`, `TorusH2MC`; not on targets with
            frozen coordinates).
        p_large: probability of a large step, in `(0, 1]`.
        n_bootstrap: uniform draws for `Z_hat` and the chains' starts.
    """

    tail_statistic: ClassVar[str | None] = "z_k_hat"

    mutation: AbstractTorusMutation | AbstractLocalKernel
    p_large: float
    n_bootstrap: int

    def __init__(
        self,
        mutation: AbstractTorusMutation | AbstractLocalKernel | None = None,
        *,
        p_large: float = 0.3,
        n_bootstrap: int = 65536,
    ):
        mutation = KelemenMutation() if mutation is None else mutation
        if not isinstance(mutation, (AbstractTorusMutation, AbstractLocalKernel)):
            raise TypeError(
                "mutation must be a torus mutation (e.g. KelemenMutation()) or a local kernel on the torus "
                f"(e.g. TorusMALA()), got {type(mutation).__name__}"
            )
        p_large = float(p_large)
        if not (math.isfinite(p_large) and 0 < p_large <= 1):
            raise ValueError(f"p_large must lie in (0, 1], got {p_large!r}")
        self.mutation = mutation
        self.p_large = p_large
        self.n_bootstrap = check_count(n_bootstrap, "n_bootstrap", 2)

    @property
    def uses_gradient(self) -> bool:  # type: ignore[override]  # the ClassVar is never set, so a property may replace it
        return isinstance(self.mutation, AbstractLocalKernel) and self.mutation.uses_gradient

    def small_step_kernel(self, target) -> AbstractLocalKernel:
        """The small step's kernel on `target`: Metropolis with the mutation (keeping the
        target's frozen coordinates), or the local kernel given, which moves every coordinate."""
        if isinstance(self.mutation, AbstractTorusMutation):
            return small_step(self.mutation, target)
        if frozen_coordinates(target):
            raise ValueError(
                f"{type(self.mutation).__name__} moves every coordinate, but {type(target).__name__} declares "
                f"frozen_coordinates = {frozen_coordinates(target)} that small steps must keep"
            )
        return self.mutation

    def init_cost(self, lanes: int) -> int:
        keeps = isinstance(self.mutation, AbstractLocalKernel) and self.mutation.keeps_geometry
        return bootstrap_size(self.n_bootstrap, lanes) + (lanes if keeps else 0)  # `init` evaluates such starts again

    def step_cost(self, lanes: int) -> int:
        return lanes

    def init(self, target, key: PRNGKeyArray, lanes: int) -> PSSMLTState:
        check_target(target, needs_gradient=self.uses_gradient)
        kernel = self.small_step_kernel(target)  # refuses a target whose frozen coordinates the kernel would move
        lanes = check_lanes(lanes)
        k_boot, k_pick = jax.random.split(key)
        keeps = kernel.keeps_geometry  # then the chosen starts are evaluated again, with their geometry
        boot = bootstrap_points(target, k_boot, self.n_bootstrap, lanes, self.uses_gradient and not keeps)
        lum = luminance(boot)
        z = jnp.mean(lum)
        z_err = jnp.std(lum) / (z * math.sqrt(lum.shape[0]))
        index = resample(k_pick, lum, lanes)
        point = jax.tree.map(lambda x: x[index], boot)
        if keeps:
            point = evaluate_points(target, point.position, kernel=kernel)
        i0 = jnp.zeros((), jnp.int32)
        tally = PSSMLTTally(empty_film(target.num_pixels), i0, i0, i0, i0, jnp.zeros((), jnp.float32))
        largest = jax.lax.top_k(lum, min(lum.shape[0], tail_length(lum.shape[0]) + 1))[0]
        params = PSSMLTParams(z, z_err, jnp.asarray(lum.shape[0], jnp.float32), largest)
        return PSSMLTState(point, params, tally)

    def check(self, params: PSSMLTParams) -> None:
        if not float(params.z_hat) > 0:
            raise ValueError(
                f"all {self.n_bootstrap} bootstrap draws have zero luminance: PSSMLT cannot start its chains "
                "(the image is black or its light is too hard to find; raise n_bootstrap)"
            )

    def step(self, target, key: PRNGKeyArray, state: PSSMLTState) -> PSSMLTState:
        k_small, k_large, k_kind, k_accept = jax.random.split(key, 4)
        x, tally = state.point, state.tally
        n, d = x.position.shape
        kernel = self.small_step_kernel(target)
        logdensity = lambda u: pss_logdensity(target)(u)[0]  # noqa: E731
        small, aux = jax.vmap(lambda k, p: kernel.propose(k, p, logdensity))(lane_keys(k_small, n), x)
        fresh = jax.random.uniform(k_large, (n * d,), jnp.float32).reshape(n, d)
        large = jax.random.uniform(k_kind, (n,), jnp.float32) < self.p_large
        y = evaluate_points(target, jnp.where(large[:, None], fresh, small), kernel=kernel)
        accept_keys = lane_keys(k_accept, n)
        moved, info = jax.vmap(kernel.accept)(accept_keys, x, y, aux)
        if not isinstance(kernel, TorusMetropolis):  # large steps: Metropolis on the luminance
            symmetric = lambda k, p, q: metropolis_accept(k, p, q, q.logdensity - p.logdensity)  # noqa: E731
            jumped, jump_info = jax.vmap(symmetric)(accept_keys, x, y)
            pick = lambda a, b: jnp.where(large.reshape((-1,) + (1,) * (a.ndim - 1)), a, b)  # noqa: E731
            moved, info = jax.tree.map(pick, jumped, moved), jax.tree.map(pick, jump_info, info)
        a, accept = info.acceptance_probability, info.accepted
        both = lambda p, q: jnp.concatenate([p, q])  # noqa: E731
        film = splat(
            tally.film,
            both(pixels(target, x.position, x.aux), pixels(target, y.position, y.aux)),
            both(1.0 - a, a),
            both(contributions(x.aux), contributions(y.aux)),
        )
        tally = PSSMLTTally(
            film=film,
            lane_steps=tally.lane_steps + jnp.int32(n),
            accepted=tally.accepted + jnp.sum(accept, dtype=jnp.int32),
            large_steps=tally.large_steps + jnp.sum(large, dtype=jnp.int32),
            large_accepted=tally.large_accepted + jnp.sum(accept & large, dtype=jnp.int32),
            large_luminance=tally.large_luminance + jnp.sum(jnp.where(large, jnp.exp(y.logdensity), 0.0)),
        )
        return PSSMLTState(moved, state.params, tally)

    @staticmethod
    def z_hat(params: PSSMLTParams, tally: PSSMLTTally):
        """Mean luminance of all uniform draws: the bootstrap's and the large-step proposals'."""
        draws = params.n_bootstrap + tally.large_steps
        return (params.z_hat * params.n_bootstrap + tally.large_luminance) / draws

    def scale(self, target, params: PSSMLTParams, tally: PSSMLTTally):
        """`W H Z_hat / (lanes x steps)`."""
        return ratio(target.num_pixels * self.z_hat(params, tally), tally.lane_steps)

    def statistics(self, params: PSSMLTParams, tally: PSSMLTTally, state: PSSMLTState | None = None) -> PSSMLTStatistics:
        """The acceptances and `Z_hat`; with the final `state`, `z_k_hat`: the Pareto shape of the
        bootstrap's luminance tail, fitted to its largest positive values (NaN with too few
        draws or fewer than 6 bright ones)."""
        draws = params.n_bootstrap + tally.large_steps
        z_k_hat = math.nan
        if state is not None:
            largest = np.asarray(state.params.largest_luminance, np.float64)
            z_k_hat = pareto_k(largest[np.isfinite(largest) & (largest > 0)], int(state.params.n_bootstrap))
        return PSSMLTStatistics(
            z_hat=float(self.z_hat(params, tally)),
            z_hat_relative_error=float(params.z_hat_error * np.sqrt(params.n_bootstrap / draws)),
            z_bootstrap=float(params.z_hat),
            z_bootstrap_relative_error=float(params.z_hat_error),
            acceptance_rate=float(ratio(tally.accepted, tally.lane_steps)),
            large_step_acceptance=float(ratio(tally.large_accepted, tally.large_steps)),
            small_step_acceptance=float(ratio(tally.accepted - tally.large_accepted, tally.lane_steps - tally.large_steps)),
            p_large=self.p_large,
            z_k_hat=z_k_hat,
        )
