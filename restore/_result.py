"""The result of a run: estimates with standard errors, the normalising constant, diagnostics."""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Callable, Mapping
from typing import Any, Literal

import jax
import numpy as np

from ._arviz import CHAINS
from ._arviz import to_arviz as arviz_export
from ._diagnostics import TourStatistics, heavy_tail_reasons, tour_statistics
from ._estimates import (
    COVERAGE_REMEDY,
    DROPPED_TOURS_REMEDY,
    FEW_TERMS_REMEDY,
    START_REMEDY,
    Estimate,
    UnreliableEstimateWarning,
    check_total_time,
    halves_z,
    halves_z_from_sums,
    lane_ratio,
    log_mean_exp,
    start_transient,
    tour_ratio,
    unreliable_reason,
    with_tail_excess,
)
from ._estimates_table import estimates_table
from ._observables import Observables
from ._pareto import k_hat_limit
from ._sampler import AbstractSampler
from ._tails import (
    TourTails,
    duration_k,
    duration_square_excess,
    importance_k,
    residual_k,
    residual_square_excess,
    select_lanes,
)
from ._trace import RunTrace
from ._warnings import SAMPLE_ADVICE, advice, warn

Method = Literal["tours", "lanes"]


class LogEstimate(Estimate):
    """An estimate of a logarithm, e.g. `log Z`; `standard_error` is that of the log."""


def _kept(tails: TourTails | None) -> TourTails:
    """The run's tour tails, which every run with tours keeps."""
    if tails is None:
        raise ValueError("this result kept no tour tails")
    return tails


@dataclasses.dataclass(eq=False)
class SampleResult:
    """What `restore.sample` returns: streamed sums, thinned draws and run facts.

    Everything is held in numpy on the host. The main entry points are `estimate`,
    `normalising_constant`, `tour_statistics`, `ess`, `estimate_draws` and `to_arviz`;
    `restore.plot` draws them.

    Attributes:
        sampler_name: the class name of the sampler that ran.
        is_regenerative: tours start independently of the past (tour-based errors hold).
        has_tours: the sampler has tours at all.
        observables: what was streamed, with names and shapes.
        sums: per-lane float64 totals (`LaneSums`, a leading lane axis).
        histogram: `(counts, total time)` of complete tour durations in log10 bins.
        tails: the run's largest tour terms with their lanes, for the Pareto `k_hat` (`None` without tours).
        draws: thinned states `(stored, lanes, d)`; `draw_weights` their weights.
        draw_weights: `(stored, lanes)`.
        final_state: every lane's last state.
        num_lanes: lanes run.
        num_steps: steps per lane within the budget; `finishing_steps` after it.
        finishing_steps: steps spent finishing the tours open at the end of the budget.
        unfinished_tours: lanes whose tour was still open after finishing (or, with
            `tours_dropped`, when the budget ended).
        thin: every `thin`-th step was stored.
        weights: `"rao_blackwell"` or `"time"`.
        wall_time: seconds the run took.
        interrupted: the run was stopped early (Ctrl-C); the result covers what ran.
        draws_note: why the draws were thinned, if they were.
        log_rate: `log c` with the mean tour duration `Z / c` (`None` without tours).
        tour_length: the mean tour duration the rate was calibrated for, if it was.
        pilot: the pilot estimate of `Z` that calibrated the rate (`PilotEstimate`), if one did.
        expected_tour_times: per lane, the complete tours' expected total duration over
            `Z` with several phases (`None` with one).
        trace: the kill rate and acceptance of each chunk (a `restore.RunTrace`), or `None`.
        advice: what the warnings advise when the regeneration is far from the target
            (it depends on how the run was built: by hand or by `restore.autosample`).
        caveat: a reason found outside the run why its tour-based error bars cannot be
            trusted (`restore.autosample`'s check of the regeneration against an earlier
            stage's draws), or `""`.
        tours_dropped: the tours open when the budget ended were not run to their end
            (`finish_tours=False`, or Ctrl-C before they were): the tour-based estimates
            lean towards short tours and are marked unreliable.
    """

    sampler_name: str
    is_regenerative: bool
    has_tours: bool
    observables: Observables
    sums: Any
    histogram: tuple
    tails: TourTails | None
    draws: np.ndarray
    draw_weights: np.ndarray
    final_state: Any
    num_lanes: int
    num_steps: int
    finishing_steps: int
    unfinished_tours: int
    thin: int
    weights: str
    wall_time: float
    interrupted: bool
    draws_note: str | None
    log_rate: float | None
    tour_length: tuple[float, ...] | None
    pilot: Any
    expected_tour_times: np.ndarray | None
    trace: RunTrace | None = None
    advice: str = SAMPLE_ADVICE
    caveat: str = ""
    tours_dropped: bool = False
    _thinning_noted: bool = dataclasses.field(default=False, init=False, repr=False)
    _run_shapes: dict[str, np.ndarray] = dataclasses.field(default_factory=dict, init=False, repr=False)  # `_run_shape`

    @classmethod
    def from_run(
        cls,
        *,
        sampler: AbstractSampler,
        pilot,
        observables: Observables,
        sums,
        histogram,
        tails,
        draws,
        draw_weights,
        final_state,
        num_steps,
        finishing_steps,
        thin,
        weights,
        wall_time,
        interrupted,
        draws_note=None,
        unfinished_tours=0,
        trace=None,
        tours_dropped=False,
    ) -> SampleResult:
        to_np = lambda tree: jax.tree.map(np.asarray, tree)
        facts = sampler.run_facts()
        result = cls(
            sampler_name=type(sampler).__name__,
            is_regenerative=bool(sampler.is_regenerative),
            has_tours=bool(sampler.has_tours),
            observables=observables,
            sums=to_np(sums),
            histogram=to_np(histogram),
            tails=tails,
            draws=np.asarray(draws),
            draw_weights=np.asarray(draw_weights),
            final_state=to_np(final_state),
            num_lanes=int(np.asarray(sums.all_t).shape[0]),
            num_steps=int(num_steps),
            finishing_steps=int(finishing_steps),
            unfinished_tours=int(unfinished_tours),
            thin=int(thin),
            weights=weights,
            wall_time=float(wall_time),
            interrupted=bool(interrupted),
            draws_note=draws_note,
            log_rate=None if facts.log_rate is None else float(facts.log_rate),
            tour_length=facts.tour_length,
            pilot=pilot,
            expected_tour_times=sampler.expected_tour_times(final_state.tour, sums.num_tours) if sampler.has_tours else None,
            trace=trace,
            advice=advice(),
            tours_dropped=bool(tours_dropped),
        )
        result._warn()
        return result

    # ------------------------------------------------------------------ estimates
    @property
    def tour_log_rate(self) -> float | None:
        """`log c` such that the mean duration of the complete tours is `Z / c`: `log c_tilde` with
        one phase; with several, the tours' own constants `c_tilde_{phase(k)}` averaged
        harmonically (whatever the phase rule)."""
        times = self.expected_tour_times
        n = float(np.sum(self.sums.num_tours))
        if times is None or n == 0:
            return self.log_rate
        return math.log(n) - math.log(float(np.sum(times)))

    def _default_method(self, method: Method | None) -> Method:
        method = method or ("tours" if self.is_regenerative else "lanes")
        if method not in ("tours", "lanes"):
            raise ValueError(f"method must be 'tours' or 'lanes', got {method!r}")
        if method == "tours" and not self.is_regenerative:
            if self.has_tours:
                raise ValueError(
                    "tours depend on each other through the exit-dependent transfer, so tour-based standard "
                    "errors would be wrong: use method='lanes' (each lane is an independent replicate)"
                )
            raise ValueError(f"{self.sampler_name} has no regenerations: use method='lanes'")
        return method

    def estimate(self, name: str, method: Method | None = None, lanes=None) -> Estimate:
        """Estimate of `E_pi[f]` for the streamed observable `name`, with its standard error.

        Arguments:
            name: an observable given to `restore.sample` (default ones: `"x"`, `"x**2"`;
                the position `"x"` is streamed with any observables).
            method: `"tours"` (regenerative ratio estimator over complete tours; the
                default for Restore samplers) or `"lanes"` (lanes as independent
                replicates, incomplete tours included; the default for MH: marked
                unreliable when the two halves of the lanes' runs show that the lanes have
                not forgotten their start, `_estimates.halves_z_from_sums`).
            lanes: optional index (slice, integer array or mask) of the lanes to use,
                e.g. to form independent replications from one run. Its `k_hat` is at least
                the whole run's (`_run_shape`).
        """
        slot = self.observables.slot(name)
        cut = slice(slot.start, slot.start + slot.size)
        s = self.sums
        pick = (lambda a: a) if lanes is None else (lambda a: a[lanes])
        if self._default_method(method) == "tours":
            est = tour_ratio(pick(s.sum_f)[:, cut], pick(s.sum_f2)[:, cut], pick(s.sum_ft)[:, cut], pick(s.sum_t), pick(s.sum_t2), pick(s.num_tours))
            n = int(np.sum(pick(s.num_tours)))
            tails = _kept(self.tails) if lanes is None else select_lanes(_kept(self.tails), lanes, self.num_lanes)
            values = list(enumerate(est.value.reshape(-1).tolist()))
            k_hat = np.array([residual_k(tails, slot.start + j, v, n) for j, v in values])
            excess = np.array([residual_square_excess(tails, slot.start + j, v, n) for j, v in values])
            est = with_tail_excess(est, excess, n, float(np.sum(pick(s.sum_t), dtype=np.float64)))
            if lanes is not None:
                k_hat = np.fmax(k_hat, np.ravel(self._run_shape(name, lambda: self.estimate(name, method))))
            est = est._replace(k_hat=k_hat, k_limit=k_hat_limit(n), caveat=self._caveat(lanes))
        else:
            est = lane_ratio(pick(s.all_f)[:, cut], pick(s.all_t))
            f1, t1 = pick(s.half_f)[:, cut], pick(s.half_t)
            halves = halves_z_from_sums(f1, t1, pick(s.all_f)[:, cut] - f1, pick(s.all_t) - t1)
            est = est._replace(caveat=start_transient(halves))
        shape = lambda a: np.reshape(a, slot.shape)  # noqa: E731
        shaped = Estimate(shape(est.value), shape(est.standard_error), shape(est.k_hat), est.k_limit, est.caveat)
        _warn_unreliable(f"the estimate of {name!r}", shaped, self.advice)
        return shaped

    def ess(self, name: str, method: Method | None = None) -> np.ndarray:
        """Effective sample size of each component: `Var_pi(f) / standard_error^2`."""
        slot = self.observables.slot(name)
        cut = slice(slot.start, slot.start + slot.size)
        s = self.sums
        total = float(np.sum(s.all_t, dtype=np.float64))
        mean = np.sum(s.all_f[:, cut], axis=0, dtype=np.float64) / total
        var = np.maximum(np.sum(s.all_f2[:, cut], axis=0, dtype=np.float64) / total - mean**2, 0.0)
        se = self.estimate(name, method).standard_error.reshape(-1)
        return (var / se**2).reshape(slot.shape)

    def normalising_constant(self, method: Literal["tours", "importance"] = "tours", lanes=None) -> LogEstimate:
        """Estimate of `log Z` with the standard error of the log.

        `"tours"`: the mean tour duration is `Z / c_tilde`, so
        `Z_hat = c_tilde * (total time of complete tours) / (number of tours)`. With
        several phases, tour `k` of phase `j` lasts `Z / c_tilde_j` on average whatever
        the phase rule, so `Z_hat = sum_k T_k / sum_k 1 / c_tilde_phase(k)`, with lanes as
        independent replicates for the standard error (see `tour_log_rate`).
        `"importance"`: the mean of `p(y) / q(y)` over every tour start `y` drawn from the
        reference `q` of the run (a by-product: those draws are evaluated anyway).

        With an exit-dependent transfer the tours are dependent (tour starts are still
        `q`-distributed in stationarity, so both estimates stay consistent), and the
        standard error of the `"tours"` estimate is computed over lanes instead.

        `lanes` (an index, slice or mask) restricts the estimate to some lanes, e.g. to
        form independent replications from one run.
        """
        if not self.has_tours or self.log_rate is None:
            raise ValueError("normalising constants come from Restore runs (with a log_rate)")
        s = self.sums if lanes is None else type(self.sums)(*(np.asarray(a)[lanes] for a in self.sums))
        tails = self.tails if lanes is None or self.tails is None else select_lanes(self.tails, lanes, self.num_lanes)
        if method == "tours":
            n = float(np.sum(s.num_tours))
            if n < 2:
                raise ValueError("need at least 2 complete tours to estimate the normalising constant")
            T, T2 = float(np.sum(s.sum_t, dtype=np.float64)), float(np.sum(s.sum_t2, dtype=np.float64))
            check_total_time(T, T2, "tours")
            mean = T / n
            times = self.expected_tour_times
            log_z = np.asarray(self.log_rate + math.log(mean))
            k_hat: float | np.ndarray
            if times is not None:  # several phases: tours of phase j last Z / c_tilde_j on average
                times = np.asarray(times) if lanes is None else np.asarray(times)[lanes]
                ratio = lane_ratio(s.sum_t, times)  # Z_hat = sum T / sum 1 / c_tilde_phase(k), lanes independent
                log_z = np.asarray(math.log(float(ratio.value)))
                rel_se, k_hat, k_limit = float(ratio.standard_error / ratio.value), ratio.k_hat, ratio.k_limit
            elif self.is_regenerative:
                excess = duration_square_excess(_kept(tails), int(n), mean)  # see `tail_square_excess`
                sd = math.sqrt((max(T2 / n - mean**2, 0.0) * n + excess) / (n - 1))
                rel_se = sd / (mean * math.sqrt(n))
                k_hat, k_limit = duration_k(_kept(tails), int(n)), k_hat_limit(n)
                if lanes is not None:
                    k_hat = float(np.fmax(k_hat, self._run_shape("log Z", lambda: self.normalising_constant())))
            else:
                lane_est = lane_ratio(s.sum_t, s.num_tours)
                rel_se, k_hat, k_limit = float(lane_est.standard_error) / mean, lane_est.k_hat, lane_est.k_limit
            est = LogEstimate(log_z, np.asarray(rel_se), np.asarray(k_hat), k_limit, self._caveat(lanes))
        elif method == "importance":
            starts = float(np.sum(s.num_iw))
            log_iw, se = log_mean_exp(s.log_iw_sum, s.log_iw_sum2, starts)
            k_iw = importance_k(_kept(tails), int(starts))
            est = LogEstimate(np.asarray(log_iw), np.asarray(se), np.asarray(k_iw), k_hat_limit(starts))
        else:
            raise ValueError(f"method must be 'tours' or 'importance', got {method!r}")
        _warn_unreliable(f"log Z ({method})", est, self.advice)
        return est

    def _run_shape(self, key: str, whole_run) -> np.ndarray:
        """The `k_hat` of the whole run's estimate `whole_run()`, the floor of the `k_hat` of any group of its lanes.

        The tail shape is a property of the sampler, which every lane shares: the whole run's
        largest tours estimate it far better than one group's, and a group that met none of the
        long tours looks lighter than it is (its estimate is then also the most wrong).
        """
        if key not in self._run_shapes:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UnreliableEstimateWarning)
                self._run_shapes[key] = np.asarray(whole_run().k_hat, np.float64)
        return self._run_shapes[key]

    def _caveat(self, lanes=None) -> str:
        """Why the tour-based error bars cannot be trusted, whatever their tail fit says (`""`: no reason)."""
        return "; ".join(reason for reason in (self._open_tours_caveat(lanes), self.caveat) if reason)

    def _open_tours_caveat(self, lanes=None) -> str:
        """Tours still running at the end were left out: their (long) time is missing from the tours."""
        if not self.unfinished_tours:
            return ""
        s = self.sums
        open_lanes = (np.asarray(s.open_steps) > 0) & ~np.asarray(s.skip_first)
        count = int(np.sum(open_lanes if lanes is None else open_lanes[lanes]))
        if not count:
            return ""
        if self.tours_dropped:
            why = "the run was interrupted" if self.interrupted else "finish_tours=False"
            return (
                f"{count} tour{'s were' if count > 1 else ' was'} still open when the budget ended and "
                f"{'were' if count > 1 else 'was'} dropped ({why}), so the tour-based estimates lean towards short "
                f"tours (the long ones are the likely ones to straddle the end); {DROPPED_TOURS_REMEDY}"
            )
        return (
            f"{count} tour{'s were' if count > 1 else ' was'} still running "
            f"{self.finishing_steps} steps after the budget ended and left out, so tours can outlast the run and the "
            "tour-based estimates miss their time (a region "
            "the regeneration barely covers: a missed mode, a tail heavier than the regeneration's, or a density "
            "with infinite mass)"
        )

    def tour_statistics(self) -> TourStatistics:
        """Tour count, mean duration against `1/c`, and tail diagnostics of tour lengths."""
        if not self.has_tours:
            raise ValueError(f"{self.sampler_name} has no tours")
        try:  # the requested tour length, if any, corrected for the pilot's error in Z
            with warnings.catch_warnings():  # a statistic of the tours, not the user's estimate of Z
                warnings.simplefilter("ignore", UnreliableEstimateWarning)
                log_z = float(self.normalising_constant("importance").value)  # a ValueError without a log_rate
                tour_log_rate = self.tour_log_rate
                if tour_log_rate is None:  # (only without a log_rate, as above)
                    raise ValueError("no log_rate")
                log_expected = log_z - tour_log_rate
            with np.errstate(over="ignore"):  # beyond float64: inf
                expected = float(np.exp(np.float64(log_expected)))
        except ValueError:
            expected = math.nan
        s = self.sums
        n = int(np.sum(s.num_tours))
        k_hat = duration_k(self.tails, n) if self.tails is not None else math.nan
        return tour_statistics(s.sum_t, s.sum_t2, s.num_tours, s.max_tour, s.all_t, self.histogram, expected, k_hat, self.unfinished_tours)

    @property
    def acceptance_rate(self) -> float:
        """Share of budgeted steps that made an accepted move (local moves, or MH large steps)."""
        steps = self.num_steps * self.num_lanes
        return float(np.sum(self.sums.num_accepted)) / max(steps, 1)

    @property
    def num_invalid(self) -> int:
        """Evaluations that returned NaN or `+inf` (treated as zero density)."""
        return int(np.sum(self.sums.num_invalid))

    @property
    def num_negative_rate(self) -> int:
        """States where the kill rate was negative (`c_tilde` too small for the dynamics)."""
        return int(np.sum(self.sums.num_negative_rate))

    @property
    def num_bound_exceeded(self) -> int:
        """Thinning candidates where the kill rate exceeded the bound `Gamma`."""
        return int(np.sum(self.sums.num_bound_exceeded))

    @property
    def max_bound_ratio(self) -> float:
        """Largest `gamma / Gamma` seen at a thinning candidate (above 1: the bound failed)."""
        ratio = self.sums.max_bound_ratio
        return float(np.max(ratio)) if np.size(ratio) else 0.0

    @property
    def num_uncovered(self) -> int:
        """Steps into states of positive target density that the regeneration cannot reach."""
        return int(np.sum(self.sums.num_uncovered))

    # ------------------------------------------------------------------ draws
    def estimate_draws(self, fn: Callable[[np.ndarray], np.ndarray]) -> Estimate:
        """Post-hoc estimate of `E_pi[fn(x)]` from the stored (thinned) draws and weights.

        `fn` maps an array of states `(..., d)` to values `(...)` or `(..., k)` (numpy or
        JAX). The standard error treats lanes as independent replicates; the estimate is
        marked unreliable when the halves of the draws show that the lanes have not
        forgotten their start (as lane-based estimates are).
        """
        if self.draws.shape[0] == 0:
            raise ValueError("no draws were stored: pass save=restore.SaveDraws(max_draws > 0) to restore.sample")
        self.note_thinning()
        values = np.asarray(fn(self.draws), np.float64)
        if values.shape[:2] != self.draws.shape[:2]:
            raise ValueError(f"fn must keep the leading (draw, lane) axes {self.draws.shape[:2]}, got {values.shape}")
        w = self.draw_weights.astype(np.float64)
        wv = np.einsum("sl,sl...->l...", w, values)
        return lane_ratio(wv, w.sum(axis=0))._replace(caveat=start_transient(halves_z(values, w)))

    def to_arviz(self, resample: bool = True, seed: int = 0, transform: Callable[[np.ndarray], Mapping[str, np.ndarray]] | None = None, chains: int | None = None):
        """The stored draws in ArviZ, lanes grouped into chains: an `xarray.DataTree` with ArviZ 1.x, `InferenceData` with 0.x.

        The lanes of a regenerative run are independent sequences of i.i.d. tours, so a few
        consecutive lanes laid end to end are distributed as one longer run: by default each
        of 4 chains holds its lanes' draws one after another, and `az.rhat` / `az.ess` mean
        what they mean for MCMC chains (one chain per lane would make R-hat measure how
        short a lane is; see the docs' page on R-hat and ESS). The lanes of other samplers
        (e.g. `MixtureMH`) start away from the target and are one chain each by default, so
        that R-hat sees whether each has forgotten its start.

        The stored draws are weighted by their holding times. ArviZ expects equally
        weighted draws: with `resample=True` each lane's draws are resampled in proportion
        to their weights (systematic resampling), and `sample_stats` holds `weight` (all
        ones), `source_draw` (the stored draw of its lane each copies) and `source_weight`;
        with `resample=False` the draws are kept as stored and `sample_stats.weight` holds
        their weights. `sample_stats.lane` is each draw's lane. The attributes `restore_draws`
        (`"resampled"` or `"weighted"`) and `restore_chains` of the groups say which.

        Arguments:
            resample: resample the draws to equal weights (default) or keep them weighted.
            seed: seed of the resampling.
            transform: optional map from draws `(lanes, n, d)` to named arrays with leading
                axes `(lanes, n)`, e.g. `targets.numpyro.NumPyroTarget.constrain`; default one
                variable `"x"`.
            chains: how many chains the lanes are grouped into (the largest divisor of the
                number of lanes up to this; `num_lanes` for one chain per lane). Default: 4
                for a regenerative run, one chain per lane otherwise.
        """
        if chains is None:
            chains = CHAINS if self.is_regenerative else self.num_lanes
        self.note_thinning()
        return arviz_export(self.draws, self.draw_weights, resample=resample, seed=seed, transform=transform, attrs={"sampler": self.sampler_name}, chains=chains)

    # ------------------------------------------------------------------ reporting
    def note_thinning(self) -> None:
        """Say once, when the draws are used, that the budget thinned them (`draws_note`): the
        streamed estimates use every step, so only work on the draws is affected."""
        if self.draws_note and not self._thinning_noted:
            self._thinning_noted = True
            warn(f"the stored draws were {self.draws_note}", ThinnedDrawsWarning)

    def _warn(self) -> None:
        if self.num_invalid:
            warn(
                f"the log density returned NaN or +inf at {self.num_invalid} evaluated points; they were "
                "treated as zero density (rejected, or killed at once with weight zero)",
                RuntimeWarning,
            )
        if self.num_uncovered:
            warn(
                f"{self.num_uncovered} steps reached states with positive target density where the "
                "regeneration density is zero: tours there are never killed, so the regeneration "
                "distribution must cover the target's support (widen it or add a defensive component)",
                RuntimeWarning,
            )
        if self.num_negative_rate:
            warn(
                f"the kill rate was negative at {self.num_negative_rate} states: c_tilde is too small for these "
                "dynamics there (the rate used was zero, so the process is not exactly invariant). Raise log_rate "
                "(restore.minimal_log_rate searches for the smallest safe value)",
                RuntimeWarning,
            )
        if self.num_bound_exceeded:
            warn(
                f"the kill rate exceeded the thinning bound at {self.num_bound_exceeded} candidate events (up to "
                f"{self.max_bound_ratio:.3g} times the bound): those kills were too rare, so the process is not "
                "exactly invariant. Raise the bound (restore.rate_bound searches a region for one)",
                RuntimeWarning,
            )
        if self.has_tours and self.log_rate is not None:
            stats = self.tour_statistics()
            if stats.heavy_tailed:
                remedy = f"finish the open tours (finish_tours=True, the default); if this stays, {self.advice}" if self.tours_dropped else self.advice
                warn(
                    f"tour-based estimates and their standard errors cannot be trusted: {heavy_tail_reasons(stats)}; {remedy}",
                    UnreliableEstimateWarning,
                )

    def summary(self) -> str:
        """A short text report of the run, then a table of the estimates:
        each observable's mean, standard error, ESS, `k_hat` and whether its error bar can be trusted."""
        lines = [
            f"{self.sampler_name}: {self.num_lanes} lanes x {self.num_steps} steps in {self.wall_time:.2f} s"
            + (" (interrupted)" if self.interrupted else "")
            + (f", {self.unfinished_tours} open tours dropped" if self.tours_dropped and self.unfinished_tours else ""),
            f"  acceptance rate {self.acceptance_rate:.3f}, invalid evaluations {self.num_invalid}",
            f"  stored draws: {self.draws.shape[0]} per lane, one every {self.thin} steps"
            + (" (thinned to the draws budget: raise SaveDraws(max_draws=...) or set SaveDraws(thin=...) to keep more)" if self.draws_note else ""),
        ]
        if self.has_tours and self.log_rate is not None:
            stats = self.tour_statistics()
            lines.append(
                f"  tours {stats.num_tours}, mean duration {stats.mean_duration:.3f} +- {stats.mean_duration_se:.3f} "
                f"(expected 1/c = {stats.expected_duration:.3f}), longest 1% hold {stats.longest_share:.1%}, "
                f"tail shape k_hat {stats.k_hat:.2f} (limit {stats.k_limit:.2f})"
            )
            if stats.num_tours >= 2:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", UnreliableEstimateWarning)
                    log_z = self.normalising_constant("tours")
                verdict = "" if log_z.reliable else f"; UNRELIABLE: {unreliable_reason(log_z)}"
                lines.append(f"  log Z = {float(log_z.value):.4f} +- {float(log_z.standard_error):.4f} (tours{verdict})")
        return "\n".join(lines + estimates_table(self.observables, self.estimate, self.ess, self._default_method(None)))

    def __repr__(self) -> str:
        return f"<SampleResult {self.sampler_name}: {self.num_lanes} lanes x {self.num_steps} steps>"


class ThinnedDrawsWarning(UserWarning):
    """The draws a user works on were thinned to the draws budget (`SaveDraws(max_draws=...)`)."""


def _warn_unreliable(what: str, estimate: Estimate, advice: str) -> None:
    """Say in plain words when an estimate's error bar cannot be trusted, and what to do."""
    if np.all(estimate.reliable):
        return
    reason = unreliable_reason(estimate)
    remedy = "" if reason.endswith((FEW_TERMS_REMEDY, COVERAGE_REMEDY, DROPPED_TOURS_REMEDY, START_REMEDY)) else f"; {advice}"  # the reason may say what to do itself
    warn(f"{what}: the standard error cannot be trusted: {reason}{remedy}", UnreliableEstimateWarning)
