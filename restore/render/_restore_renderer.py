"""Metropolis and MALA Restore: the core's `JumpRestore` on the PSS torus, with a film.

The sampler is `restore.JumpRestore` itself, one per target: local dynamics a
luminance-invariant kernel of `restore.local` (`TorusMetropolis`, `TorusMALA`) embedded
in continuous time at rate 1, regeneration `UniformTorus` (`q = 1`), so the kill rate is
`gamma(u) = c q(u) / p(u) = c / lum(u)`, infinite where `lum = 0` (such a start is killed
at once and splats nothing). The log density is `pss_logdensity(target)`, whose aux is
the contribution `rgb / lum`. Each step is one event of every lane (`vmap` of the core
step; competing exponentials, Algorithm 7.1 of the paper): the lane splats its current
state with the Rao-Blackwellised holding time `1 / (1 + gamma)` (`StepInfo`'s expected
holding time and aux), is killed with probability `kappa = gamma / (1 + gamma)`, and then
either regenerates at a uniform draw or makes a local move. Fresh draws and proposals of
all lanes are evaluated in one batch call, so a step costs exactly one evaluation per lane.

**Tour length and `c`.** A tour started at `nu = U[0, 1)^D` visits the embedded jump
chain's states with expected occupation density `(p + c) / c` (it solves
`occ = nu + occ (1 - kappa) K` because the kernel `K` leaves `p` invariant and
`(p + c)(1 - kappa) = p`). So a tour makes on average `∫ occ (1 - kappa) = Z / c` local
moves, its mean duration is also `∫ occ / (1 + gamma) = Z / c`, and it costs `Z / c + 1`
evaluations (one fresh draw). A mean tour length of `L` local moves therefore needs
`c = Z / L`; `init` sets `c = Z_hat / L` from a bootstrap mean of `lum` at uniform draws.
Any `c > 0` gives an exact process: an error in `Z_hat` only changes the tour length.

**Estimator.** With `h = rgb / lum 1{pixel = j}`, each tour's expected splat sum is
`∫ occ h / (1 + gamma) = (1 / c) ∫ p h = (Z / c) E_p[h]`, and its expected number of
kills is `∫ occ kappa = ∫ q = 1`. So with `S_j` the film sum and
`K = sum over steps of kappa` (the Rao-Blackwellised number of finished tours),
`I_j = W H c S_j / K` is a ratio of regenerative sums and converges to
`W H Z E_p[h] = I_j`. Equivalently `c rgb/lum / (1 + gamma) = kappa rgb`: each step splats
the expected colour of the point where the tour will be killed, and a tour's kill point
is exactly uniform (the exit law of Restore is its regeneration law): every tour is a
Rao-Blackwellised path-tracing sample.

**Complete tours (the default).** Lanes start at uniform draws (tour starts) and the
render counts whole tours: when the budget is spent no new tour starts, every open tour
runs on until it is killed, and the image is `I_j = W H c S_j / N` with `N` the number of
tours (all of them finished). Tours are i.i.d. and each has expected splat sum
`(Z / c) E_p[h]`, so this needs no stationary start and has no unfinished-tour bias, as
in the paper's authors' renderer. Finishing costs extra steps, reported as
`finishing_steps`: with `L` about 1 most tours end within a few steps, but a tour in a
region much brighter than `Z` lasts about `lum / c` steps.

**Is the image dominated by a few tours?** A tour's splats carry in all its
(Rao-Blackwellised) duration `T` in luminance (when the density is the luminance of the
colour, each splat's contribution `rgb / lum` has luminance 1): the image's total light
is `c sum T / N`. Its noise averages out like a mean of `N` i.i.d. tours only if `T` has
a finite variance, and as fast only if no few tours hold most of `sum T`. Two
diagnostics say so: the effective number of tours `(sum T)^2 / sum T^2` (Kish's, as for
importance weights), and the Pareto shape `k_hat` of the durations, fitted to the longest
tours of the render, which a run-wide buffer on the device keeps exactly
(`restore._exceedances`, the same buffer as the core's tail diagnostics; `restore._pareto`,
as for the core's estimates). `render` warns when `k_hat > TAIL_WARNING`: a few long tours in bright
regions (the fireflies of path tracing; the caustic of the pool scene) then carry much
of the light, and another render can differ by more than this one's noise suggests.

**Start (open tours).** With `finish_tours=False` the run stops at the budget and
the image uses `K` as above. The embedded jump chain (kill with probability `kappa`, else a local move) has
the stationary law `pi_J ∝ lum + c`: `(p + c) kappa = c` regenerates uniformly and
`(p + c)(1 - kappa) = p` is left invariant by `K`. Started in `pi_J`, every step's splat
and `kappa` have their stationary means, so `E[c S_j] / E[K] = c pi_J(h / (1 + gamma)) /
pi_J(kappa) = Z E_p[h]` for any run length: the ratio is then exact up to the ratio-estimator
bias `O(1 / (lanes x steps))`. `start="stationary"` (the default) draws the lanes from the
bootstrap resampled with weights `lum + c` (sampling-importance-resampling: exact as
`n_bootstrap` grows; the sampler's `init` evaluates the chosen starts once more, `lanes`
evaluations). `start="uniform"` starts every lane at a
uniform draw (a tour start, as in the paper): also consistent, but a finite run ends
with the lanes' long tours (those in bright regions) unfinished, a bias of order
(bright-region sojourn) / (steps per lane) that is large for short runs: 25% low on
`AnalyticImage.default(3, (8, 8))` after 640 steps per lane, where the stationary start is
within 1%. Counting tours by `K` (not by tours started) already removes the bias for
memoryless tours; the start removes the rest.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from .._chunk import run_open_lanes
from .._exceedances import Exceedances, init_exceedances, largest, offer
from .._jump_restore import JumpRestore
from .._pareto import pareto_k
from .._rate import kill_log_probability
from .._restore import RestoreState
from .._speculation import speculative_steps
from ..local import AbstractLocalKernel
from ..regeneration import AbstractRegeneration, UniformTorus
from ._film import empty_film, splat
from ._learned_regeneration import LearnedRegeneration
from ._pss import check_target, contributions, frozen_coordinates, luminance, pixels, pss_logdensity
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

#: The buffer of the longest tours holds this many durations per lane (at least `MIN_TAIL_ROWS`).
TAIL_ROWS_PER_LANE = 8
MIN_TAIL_ROWS = 2**13


def tail_rows(lanes: int) -> int:
    """Rows of the buffer of the longest tour durations: a power of two (room for an offer of every lane)."""
    return 1 << max(int(max(MIN_TAIL_ROWS, TAIL_ROWS_PER_LANE * lanes, 4 * lanes + 64) - 1).bit_length(), 1)


class RestoreParams(NamedTuple):
    """Constants of a Restore render.

    Attributes:
        rate: `c`, the kill-rate constant (`gamma = c / lum`).
        log_rate: `log c`.
        z_bootstrap: the bootstrap mean luminance `Z_hat` that set `c` (NaN if `c` was given).
        z_bootstrap_error: relative standard error of `Z_hat`.
        lanes: number of lanes.
        centres: `(K, D)` centres of the learned regeneration's kernels (`K = 0`: uniform regeneration).
    """

    rate: Float[Array, ""]
    log_rate: Float[Array, ""]
    z_bootstrap: Float[Array, ""]
    z_bootstrap_error: Float[Array, ""]
    lanes: Float[Array, ""]
    centres: Float[Array, "K D"]


class RestoreTally(NamedTuple):
    """Additive sums of a Restore render (with complete tours, only lanes in a counted tour add).

    Attributes:
        film: `sum (1 / (1 + gamma)) rgb / lum` per pixel, `(P, 3)`.
        kill_probability: `K = sum kappa`, the Rao-Blackwellised number of finished tours.
        kills: tours finished (regenerations).
        duration: the total (Rao-Blackwellised) duration `sum T` of the finished counted tours.
        duration_sq: their `sum T^2`.
        restarts: tours started by a kill (the lanes' first tours not included).
        local_moves: local moves proposed.
        accepted: local moves accepted.
        completed_moves: local moves made by finished tours.
        completed_moves_sq: sum over finished tours of (local moves)^2.
        lane_steps: events simulated (lanes x steps).
    """

    film: Float[Array, "P 3"]
    kill_probability: Float[Array, ""]
    kills: Int[Array, ""]
    duration: Float[Array, ""]
    duration_sq: Float[Array, ""]
    restarts: Int[Array, ""]
    local_moves: Int[Array, ""]
    accepted: Int[Array, ""]
    completed_moves: Int[Array, ""]
    completed_moves_sq: Float[Array, ""]
    lane_steps: Int[Array, ""]


class RestoreRenderState(NamedTuple):
    """State of a Restore render: the core sampler's lane states, each lane's local moves in its
    current tour and how many were accepted (the acceptance guess of speculative finishing),
    its tour's duration so far, the longest finished tours of the render (`tails`), which
    lanes are in a counted tour (`in_tour`), whether new tours still start (`starting`; false once
    a complete-tours render finishes its open tours), constants and sums."""

    lanes: RestoreState
    tour_moves: Int[Array, " N"]
    tour_accepted: Int[Array, " N"]
    tour_duration: Float[Array, " N"]
    tails: Exceedances
    in_tour: Bool[Array, " N"]
    starting: Bool[Array, ""]
    params: RestoreParams
    tally: RestoreTally


def _zero_tally(num_pixels: int) -> RestoreTally:
    i0, f0 = jnp.zeros((), jnp.int32), jnp.zeros((), jnp.float32)
    return RestoreTally(empty_film(num_pixels), f0, i0, f0, f0, i0, i0, i0, i0, f0, i0)


def _add_events(tally, target, info, counted, log_kill_rate, moves, starting, events) -> RestoreTally:
    """The tally plus a batch of events (`info`, one per lane or slot; `counted` ones add):
    `log_kill_rate` and `moves` of the state held before each event, `events` simulated."""
    kill = jnp.exp(kill_log_probability(log_kill_rate, jnp.zeros((), jnp.float32)))  # local rate 1
    killed = info.regenerated & counted
    return RestoreTally(
        film=splat(
            tally.film, pixels(target, info.position, info.aux), jnp.where(counted, info.expected_holding_time, 0.0),
            contributions(info.aux),
        ),
        kill_probability=tally.kill_probability + jnp.sum(jnp.where(counted, kill, 0.0)),
        kills=tally.kills + jnp.sum(killed, dtype=jnp.int32),
        duration=tally.duration,  # added by `_end_tours` when they end
        duration_sq=tally.duration_sq,
        restarts=tally.restarts + jnp.sum(killed & starting, dtype=jnp.int32),
        local_moves=tally.local_moves + jnp.sum(counted & ~info.regenerated, dtype=jnp.int32),
        accepted=tally.accepted + jnp.sum(counted & info.accepted, dtype=jnp.int32),
        completed_moves=tally.completed_moves + jnp.sum(jnp.where(killed, moves, 0), dtype=jnp.int32),
        completed_moves_sq=tally.completed_moves_sq + jnp.sum(jnp.where(killed, moves.astype(jnp.float32) ** 2, 0.0)),
        lane_steps=tally.lane_steps + events,
    )


def _end_tours(state, duration: Float[Array, " N"], ended: Bool[Array, " N"], lane: Int[Array, " N"] | None = None) -> dict[str, Any]:
    """The fields of `state` after the counted tours that `ended` (of `duration`, their
    events up to the last one included) are offered to the buffer of the longest tours
    and added to the duration sums; their lanes' running durations restart at 0. `lane`:
    the lanes' indices in the render (default: `0, ..., N - 1`)."""
    if lane is None:
        lane = jnp.arange(duration.shape[0], dtype=jnp.int32)
    batch = max(32, duration.shape[0] // 4)
    tails = offer(state.tails, duration[:, None], lane, ended, 0, batch)
    finished = jnp.where(ended, duration, 0.0)
    tally = state.tally._replace(
        duration=state.tally.duration + jnp.sum(finished), duration_sq=state.tally.duration_sq + jnp.sum(finished**2)
    )
    return dict(tails=tails, tour_duration=jnp.where(ended, 0.0, duration), tally=tally)


class _OpenTours(NamedTuple):
    """The per-lane part of a `RestoreRenderState` that finishing moves between lanes and slots."""

    lanes: RestoreState
    tour_moves: Int[Array, " N"]
    tour_accepted: Int[Array, " N"]
    tour_duration: Float[Array, " N"]
    in_tour: Bool[Array, " N"]


class _Ending(NamedTuple):
    """What `_end_tours` reads and writes besides the durations: the shared part."""

    tails: Exceedances
    tally: RestoreTally


@dataclasses.dataclass(frozen=True)
class RestoreStatistics(RenderStatistics):
    """The diagnostics of a Restore render (`MetropolisRestore`, `MALARestore`); luminances
    are in the target's units, durations in the continuous time of the tours.

    Attributes:
        rate: `c`, the kill-rate constant (`gamma = c / lum`), in luminance.
        tour_length_target: `L`, the mean local moves per tour asked for (NaN with `rate` given).
        z_bootstrap: the bootstrap's mean luminance `Z_hat` that set `c` (NaN if `c` was given).
        z_bootstrap_relative_error: its relative standard error.
        mean_tour_length: local moves per tour, whose theoretical value is `Z / c` (complete
            tours: counted moves over counted tours; open tours: Rao-Blackwellised,
            `(lane_steps - K) / K`).
        z_estimate: `c x mean_tour_length`, an estimate of `Z` in luminance.
        tours_started: tours started (the lanes' first ones included).
        tours_completed: tours finished (regenerations).
        tours_per_lane: the Rao-Blackwellised number of finished tours `K` per lane.
        completed_tour_mean: local moves per finished tour (finished tours only: biased towards
            short tours in short runs).
        completed_tour_cv: their coefficient of variation (standard deviation over mean).
        acceptance_rate: the fraction of local moves accepted.
        tour_k_hat: the Pareto shape of the finished tours' durations `T` (NaN with too few
            tours, or before the render's end); above `TAIL_WARNING` a few long tours dominate
            the image.
        effective_tours: Kish's effective number of tours `(sum T)^2 / sum T^2` (NaN before the
            render's end).
        tour_duration_mean: `sum T / N`, the mean tour duration (expected: `Z / c`; NaN before
            the render's end).
    """

    rate: float
    tour_length_target: float
    z_bootstrap: float
    z_bootstrap_relative_error: float
    mean_tour_length: float
    z_estimate: float
    tours_started: int
    tours_completed: int
    tours_per_lane: float
    completed_tour_mean: float
    completed_tour_cv: float
    acceptance_rate: float
    tour_k_hat: float = math.nan
    effective_tours: float = math.nan
    tour_duration_mean: float = math.nan

    def tail_warning(self) -> str | None:
        if not self.tour_k_hat > TAIL_WARNING:
            return None
        return (
            "a few long tours dominate this image: the tail shape of the tour durations is k_hat = "
            f"{self.tour_k_hat:.2f} > {TAIL_WARNING}, and the light rests on about "
            f"{self.effective_tours:,.0f} effective tours; its noise does not average out like a mean of "
            "many tours, and another render can differ by more than this one's noise suggests: render longer, and "
            "compare realisations"
        )


class AbstractPSSRestore(AbstractRenderer):
    """Jump Restore on the PSS torus with uniform regeneration (see the module docstring).

    Concrete renderers (`MetropolisRestore`, `MALARestore`) choose the local kernel.

    Attributes:
        kernel: the luminance-invariant local kernel (a `restore.local` kernel).
        tour_length: `L`, the mean number of local moves per tour; `c = Z_hat / L`.
        rate: `c` given directly, or `None`.
        n_bootstrap: uniform draws in the bootstrap (the estimate of `Z` and the
            stationary start); none are made with `rate` given and `start="uniform"`.
        start: `"uniform"` (tour starts) or `"stationary"`, see the module docstring.
        finish_tours: finish every tour started before the budget ends and divide by
            the number of tours (default); else stop at the budget and divide by `K`.
        learned: regenerate from a density learned from the bootstrap paths
            (`LearnedRegeneration`), or uniformly (`None`, as the paper's authors do).
    """

    tail_statistic: ClassVar[str | None] = "tour_k_hat"

    kernel: AbstractLocalKernel
    tour_length: float
    rate: float | None
    n_bootstrap: int
    start: str
    finish_tours: bool
    learned: LearnedRegeneration | None

    def _setup(self, kernel, tour_length, rate, n_bootstrap, start, finish_tours, learned=None):
        tour_length = float(tour_length)
        if not (math.isfinite(tour_length) and tour_length > 0):
            raise ValueError(f"tour_length must be positive and finite, got {tour_length!r}")
        if rate is not None:
            rate = float(rate)
            if not (math.isfinite(rate) and rate > 0):
                raise ValueError(f"rate must be positive and finite, got {rate!r}")
        self.kernel = kernel
        self.tour_length = tour_length
        self.rate = rate
        self.n_bootstrap = check_count(n_bootstrap, "n_bootstrap", 2)
        if not isinstance(finish_tours, bool):
            raise TypeError(f"finish_tours must be True or False, got {finish_tours!r}")
        if start is None:
            start = "uniform" if finish_tours else "stationary"
        if start not in ("stationary", "uniform"):
            raise ValueError(f"start must be 'stationary' or 'uniform', got {start!r}")
        if finish_tours and start != "uniform":
            raise ValueError("complete tours begin at regeneration draws: use start='uniform' (or finish_tours=False)")
        self.start = start
        self.finish_tours = finish_tours
        if learned is not None and not isinstance(learned, LearnedRegeneration):
            raise TypeError(f"learned must be a restore.render.LearnedRegeneration or None, got {learned!r}")
        self.learned = learned

    @property
    def _bootstraps(self) -> bool:
        return self.rate is None or self.start == "stationary" or self.learned is not None

    @property
    def finishes(self) -> bool:  # type: ignore[override]  # the ClassVar is never set, so a property may replace it
        return self.finish_tours

    @property
    def uses_gradient(self) -> bool:  # type: ignore[override]  # the ClassVar is never set, so a property may replace it
        return self.kernel.uses_gradient

    def init_cost(self, lanes: int) -> int:
        boot = bootstrap_size(self.n_bootstrap, lanes) if self._bootstraps else 0
        return boot + lanes  # the lanes' starts are evaluated by the sampler's init

    def step_cost(self, lanes: int) -> int:
        return lanes

    def regeneration(self, target, params: RestoreParams) -> AbstractRegeneration:
        """The regeneration distribution: uniform on the torus, in float32, or the one
        `learned` from the bootstrap (its kernels' centres are `params.centres`)."""
        if self.learned is None:
            return UniformTorus(target.dim, jnp.float32)
        return self.learned.distribution(params.centres)

    def local_kernel(self, target) -> AbstractLocalKernel:
        """The local kernel on `target`: `kernel`, which must keep the target's frozen
        coordinates (a concrete renderer that can freeze them overrides this)."""
        if frozen_coordinates(target):
            raise ValueError(
                f"{type(self).__name__} moves every coordinate, but {type(target).__name__} declares "
                f"frozen_coordinates = {frozen_coordinates(target)} that local moves must keep"
            )
        return self.kernel

    def sampler(self, target, params: RestoreParams) -> JumpRestore:
        """The core sampler this renderer runs on `target`, with `c = params.rate`.

        With `c = Z_hat / L` the sampler is made from its tour length `L` and calibrated to
        `Z_hat` (the same `log c`, bit for bit), so it knows that about `1 / (1 + L)` of its
        events are kills: at `L = 1` it draws the next tours' starts for all lanes at once,
        which costs less than gathering the killed lanes (`JumpRestore.step_lanes`).
        """
        logdensity, kernel, regeneration = pss_logdensity(target), self.local_kernel(target), self.regeneration(target, params)
        if self.rate is None:
            sampler = JumpRestore(logdensity, kernel, regeneration, tour_length=self.tour_length, has_aux=True)
            return sampler.calibrated_to(jnp.log(params.z_bootstrap))
        return JumpRestore(logdensity, kernel, regeneration, log_rate=params.log_rate, has_aux=True)

    def init(self, target, key: PRNGKeyArray, lanes: int) -> RestoreRenderState:
        check_target(target, needs_gradient=self.uses_gradient)
        self.local_kernel(target)  # refuses a target whose frozen coordinates the kernel would move
        lanes = check_lanes(lanes)
        k_boot, k_pick, k_start = jax.random.split(key, 3)
        z = z_err = jnp.asarray(jnp.nan, jnp.float32)
        if self._bootstraps:
            boot = bootstrap_points(target, k_boot, self.n_bootstrap, lanes)  # values alone: init evaluates the starts
            lum = luminance(boot)
            z = jnp.mean(lum)
            z_err = jnp.std(lum) / (z * math.sqrt(lum.shape[0]))
        if self.rate is None:
            log_rate = jnp.log(z) - math.log(self.tour_length)
        else:
            log_rate = jnp.asarray(math.log(self.rate), jnp.float32)
        centres = jnp.zeros((0, target.dim), jnp.float32)
        if self.learned is not None:  # its own key: the other draws stay those of a uniform regeneration
            centres = self.learned.fit(jax.random.fold_in(k_boot, 1), boot.position, lum)
        params = RestoreParams(jnp.exp(log_rate), log_rate, z, z_err, jnp.asarray(lanes, jnp.float32), centres)
        sampler = self.sampler(target, params)
        keys = jax.random.split(k_start, lanes)
        if self.start == "uniform":  # tour starts, drawn by the sampler
            states = jax.vmap(sampler.init)(keys)
        else:  # resample the bootstrap with weights lum + c q: the jump chain's stationary law
            q = jnp.exp(jax.vmap(sampler.regeneration.log_prob)(boot.position))  # 1 for the uniform regeneration
            index = resample(k_pick, lum + params.rate * q, lanes)
            states = jax.vmap(sampler.init)(keys, boot.position[index])
        zeros, ones = jnp.zeros(lanes, jnp.int32), jnp.ones(lanes, bool)
        return RestoreRenderState(
            states, zeros, zeros, jnp.zeros(lanes, jnp.float32),
            init_exceedances(tail_rows(lanes), 1, jnp.float32), ones, jnp.asarray(True), params,
            _zero_tally(target.num_pixels),
        )

    def check(self, params: RestoreParams) -> None:
        if self.rate is None and not float(params.z_bootstrap) > 0:
            raise ValueError(
                f"all {self.n_bootstrap} bootstrap draws have zero luminance, so the kill-rate constant "
                "c = Z_hat / tour_length is zero: the image is black or its light is too hard to find "
                "(raise n_bootstrap, or pass rate=c)"
            )

    def step(self, target, key: PRNGKeyArray, state: RestoreRenderState) -> RestoreRenderState:
        """One step of every lane of `state`."""
        sampler = self.sampler(target, state.params)
        n, moves, counted = state.tour_moves.shape[0], state.tour_moves, state.in_tour
        lanes, info = sampler.step_lanes(lane_keys(key, n), state.lanes)
        tally = _add_events(
            state.tally, target, info, counted, state.lanes.log_kill_rate, moves, state.starting, jnp.int32(n)
        )
        killed = info.regenerated & counted
        in_tour = jnp.where(killed, state.starting, counted)  # a killed lane starts a counted tour only while starting
        tour_moves = jnp.where(info.regenerated, 0, moves + 1)
        tour_accepted = jnp.where(info.regenerated, 0, state.tour_accepted + info.accepted)
        duration = state.tour_duration + jnp.where(counted, info.expected_holding_time, 0.0)
        state = state._replace(
            lanes=lanes, tour_moves=tour_moves, tour_accepted=tour_accepted, in_tour=in_tour, tally=tally
        )
        return state._replace(**_end_tours(state, duration, killed))

    def smallest_finishing_batch(self) -> int:
        """256 where trees fill a batch however few tours are open (Metropolis moves); 8 where
        a lane speculates along the reject path alone (MALA, H2MC), whose events per call
        are about one over the acceptance rate, however long the chain."""
        return 256 if self.kernel.proposes_from_position else 8

    def finishing_step(
        self, target, key: PRNGKeyArray, params: RestoreParams, tours: _OpenTours, shared: _Ending, lane: Int[Array, " S"],
        live: Bool[Array, " S"],
    ) -> tuple[_OpenTours, _Ending, Bool[Array, " S"]]:
        """Advance the `live` open tours of a batch of `S` lanes (`lane`: their indices in the
        render) by speculative steps (`restore.speculative_steps`): one batched evaluation of
        `S` candidate events, each open lane a tree of `S // open` of them, shaped by its tour's
        acceptance so far where the local kernel proposes from the position alone, the reject
        path where its candidate needs the gradient (MALA, H2MC). The other lanes keep their
        part as it is. Returns the batch's part, the shared tally and tail buffer, and the
        lanes whose tour ended."""
        sampler = self.sampler(target, params)
        guess = (tours.tour_accepted + 1.0) / (tours.tour_moves + 2.0)  # this tour's acceptance so far
        slots = live.shape[0]
        run = speculative_steps(sampler, key, tours.lanes, live, slots, guess)
        moves = tours.tour_moves[run.lane] + run.level
        tally = _add_events(
            shared.tally, target, run.info, run.valid, run.log_kill_rate, moves, jnp.zeros((), bool),
            jnp.sum(run.valid, dtype=jnp.int32),
        )
        at_last = jnp.where(run.last, run.lane, slots)
        tour_moves = tours.tour_moves.at[at_last].set(jnp.where(run.info.regenerated, 0, moves + 1), mode="drop")
        accepted = run.info.accepted.astype(jnp.int32)
        tour_accepted = tours.tour_accepted.at[jnp.where(run.valid, run.lane, slots)].add(accepted, mode="drop")
        tour_accepted = tour_accepted.at[jnp.where(run.last & run.info.regenerated, run.lane, slots)].set(0, mode="drop")
        held = jnp.where(run.valid, run.info.expected_holding_time, 0.0)
        duration = tours.tour_duration.at[jnp.where(run.valid, run.lane, slots)].add(held, mode="drop")
        ended = live & ~run.active
        fields = _end_tours(_Ending(shared.tails, tally), duration, ended, lane)
        tours = _OpenTours(run.states, tour_moves, tour_accepted, fields["tour_duration"], tours.in_tour & ~ended)
        return tours, _Ending(fields["tails"], fields["tally"]), ended

    def open_tours(self, state: RestoreRenderState) -> int:
        """Lanes whose counted tour is still running (host-side): `finish` runs them to their end."""
        return int(jnp.sum(state.in_tour)) if self.finish_tours else 0

    def stop_starting(self, state: RestoreRenderState) -> RestoreRenderState:
        """No new counted tours from now on: the open ones run to their end."""
        return state._replace(starting=jnp.zeros_like(state.starting))

    def finish(self, target, key: PRNGKeyArray, state: RestoreRenderState, max_steps=None, slots=None):
        """With complete tours: start no new tour and run every open tour to its end in the
        core's narrow batch (`restore._chunk.run_open_lanes`, which `restore.sample` finishes
        its tours with): `slots` slots (default: the lanes), each holding an open lane, and
        every step one batched evaluation of `slots` points shared among the open lanes held
        (`finishing_step`: speculative steps). At most `max_steps` steps if given. Returns the
        state and the steps taken."""
        if not self.finish_tours:
            return state, jnp.zeros((), jnp.int32)
        lanes = state.tour_moves.shape[0]
        slots = lanes if slots is None else min(int(slots), lanes)
        forever = jnp.iinfo(jnp.int32).max
        iterations = forever if max_steps is None else max_steps  # steps of the batch
        state = self.stop_starting(state)

        def step(tours, shared, lane, _, live, i):
            return self.finishing_step(target, jax.random.fold_in(key, i), state.params, tours, shared, lane, live)

        tours = _OpenTours(state.lanes, state.tour_moves, state.tour_accepted, state.tour_duration, state.in_tour)
        shared = _Ending(state.tails, state.tally)
        # a lane steps until its tour ends (no cap of its own); the call stops after `iterations`
        tours, shared, _, steps = run_open_lanes(
            step, tours, shared, state.in_tour, jnp.zeros(lanes, jnp.int32), forever, iterations, slots
        )
        return state._replace(**tours._asdict(), tails=shared.tails, tally=shared.tally), steps

    def scale(self, target, params: RestoreParams, tally: RestoreTally):
        """`W H c / N` (complete tours; `N` = tours started = lanes + kills while starting)
        or `W H c / K` (open tours): the image is `scale x S_j` (module docstring)."""
        if self.finish_tours:
            return ratio(target.num_pixels * params.rate, tally.kills)
        return ratio(target.num_pixels * params.rate, tally.kill_probability)

    def statistics(
        self, params: RestoreParams, tally: RestoreTally, state: RestoreRenderState | None = None
    ) -> RestoreStatistics:
        """Tour and move statistics (`RestoreStatistics`); with the final `state`, those of the
        finished tours' durations `T` too (module docstring): `tour_k_hat`, their Pareto shape,
        fitted to the buffer of the longest tours; `effective_tours`; `tour_duration_mean`."""
        k = tally.kill_probability
        if self.finish_tours:  # counted tours only: their local moves per tour
            mean_length = ratio(tally.local_moves, tally.kills)
        else:
            mean_length = ratio(tally.lane_steps - k, k)
        completed_mean = ratio(tally.completed_moves, tally.kills)
        second = ratio(tally.completed_moves_sq, tally.kills)
        k_hat = effective = duration_mean = math.nan
        if state is not None:
            tours, total, squares = int(tally.kills), float(tally.duration), float(tally.duration_sq)
            longest = largest(jax.tree.map(np.asarray, state.tails), 0).column(0, 0)
            k_hat = pareto_k(longest, tours) if tours else math.nan
            effective = total**2 / squares if squares > 0 else math.nan
            duration_mean = total / tours if tours else math.nan
        return RestoreStatistics(
            rate=float(params.rate),
            tour_length_target=self.tour_length if self.rate is None else math.nan,
            z_bootstrap=float(params.z_bootstrap),
            z_bootstrap_relative_error=float(params.z_bootstrap_error),
            mean_tour_length=float(mean_length),
            z_estimate=float(params.rate * mean_length),
            tours_started=int(params.lanes + tally.restarts),
            tours_completed=int(tally.kills),
            tours_per_lane=float(ratio(k, params.lanes)),
            completed_tour_mean=float(completed_mean),
            completed_tour_cv=float(ratio(np.sqrt(np.maximum(second - completed_mean**2, 0.0)), completed_mean)),
            acceptance_rate=float(ratio(tally.accepted, tally.local_moves)),
            tour_k_hat=k_hat,
            effective_tours=effective,
            tour_duration_mean=duration_mean,
        )
