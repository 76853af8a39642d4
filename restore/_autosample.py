"""`autosample`: one call from a log density and what the user knows to a healthy Restore run.

Restore is exact for any regeneration distribution `u` that covers the target, but its
efficiency, and whether its error bars mean anything, depends on how close `u` is to the
target. `autosample` builds `u` in stages, population-Monte-Carlo style:

1. **Seeding.** Short adaptive chains from starts drawn from what the user knows (a box,
   a scale, a prior) find where the mass is (`_seeding`). No mode is needed.
2. **Stages.** Fit a regeneration to the latest draws (the family and size chosen by
   held-out likelihood, `restore.regeneration.choose_regeneration`), mix in a broad
   defensive component built from the user's knowledge (so `u` covers the target), and
   run jump Restore with that `u` frozen. Each stage is an exact Restore run; its
   tour-weighted draws are draws of the target, and the next stage is fitted to them
   (from the families that came close to the best in this choice: `close_families`).
3. **Stop** when a stage's tours are healthy: the Pareto shape `k_hat` of the tour
   durations and of the importance weights is small, no tour outlasted the stage and no
   handful of tours holds most of the time (`TourStatistics.heavy_tailed`), so the tours
   are close to i.i.d. exponential and the error bars can be trusted. When the first stage
   is healthy, its regeneration was still fitted to the seeding chains, which have not
   equilibrated; where its tours are still far from exponential (`REFIT_SHARE`), the same
   family and size are fitted again to that stage's tour draws (`refit_regeneration`), and
   the final run takes that fit where it scores better on held-out lanes (it usually does:
   they are the target's own draws).
4. **Final run.** A fresh run with the chosen `u` frozen before it starts, with the full
   budget and the user's observables. Its estimates are the result; the stages only
   chose `u`. Because `u` is fixed before the final run begins, its tours are i.i.d. given
   `u`, and the regenerative central limit theorem applies exactly as for a hand-built
   regeneration. Pooling the stages would add tours whose regenerations were chosen by
   looking at those same tours, and early stages are heavy-tailed by design, so they are
   not pooled.

5. **Coverage check.** The final regeneration is checked against the draws of the stage
   that chose it, which were made with another regeneration: target mass that lies where
   the final run expects fewer than one tour to start, which no diagnostic of that run can
   see, marks its estimates unreliable (`coverage_caveat`).

If no stage becomes healthy, adapting goes on while the stages keep finding mass (up to
`max_stages`), and the final run takes the stage with the lightest tail among those whose
`log Z` is not clearly below the highest (`restore._stages`); its estimates carry the
diagnostics that say their error bars cannot be trusted. It never raises because the
target has no mode or too many of them.
"""

from __future__ import annotations

import math
import os
import time
import warnings
import weakref
from collections.abc import Callable, Mapping, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, PRNGKeyArray

from ._compile import jit
from ._coordinates import check_coordinates
from ._coverage import unseen_mass
from ._estimates import COVERAGE_REMEDY
from ._jump_restore import JumpRestore
from ._options import DEFAULT_DRAWS, Checkpoint, SaveDraws
from ._pareto import K_HAT_LIMIT
from ._preconditioning import guide_components, typical_scale_tril
from ._progress import console_note
from ._random import distribution_draws
from ._result import SampleResult
from ._sample import sample
from ._seeding import seed_draws
from ._seeding_modes import laplace_candidates
from ._stages import StageReport, final_stage, keep_adapting
from ._validation import check_integer, check_key, check_logdensity
from ._warnings import AUTOSAMPLE_ADVICE, advising
from .local import AbstractLocalKernel, CorrelatedRandomWalk, GuidedRandomWalk, RandomWalk
from .regeneration import (
    AbstractRegeneration,
    ConditionalGaussian,
    DiagonalMixture,
    Mixture,
    ProductMixture,
    RotatedProductMixture,
    StudentT,
    UniformBox,
    choose_regeneration,
)
from .regeneration._choose import FAMILIES, close_families, padded_size, refit_regeneration

#: A stage is healthy when the tail shape of its tour durations is below this...
HEALTHY_DURATION_K = 0.3
#: ...and that of its importance weights below this.
HEALTHY_IMPORTANCE_K = K_HAT_LIMIT
#: A healthy first stage's family is fitted again to its tours when their effective number is below
#: this share of their number (exponential tours have 1/2; `TourStatistics.effective_num_tours`).
REFIT_SHARE = 0.4
#: Degrees of freedom of the defensive component built from a box or a scale.
DEFENSIVE_DF = 3.0
#: Seeding starts on which the log density's coordinates are checked (`check_coordinates`).
PROBE_POINTS = 8
#: The keys of the first this many stages come from one split of the call's key (with the seeding's
#: and the final run's); a later stage folds its number into the last of them.
KEYED_STAGES = 6

#: Per log density and dimension, the number of components each regeneration family was last
#: run with (padded with zero-weight components: `Fit.padded`). A Restore run's programs are
#: compiled for the regeneration's structure and array shapes, so stages (and later calls)
#: whose fits are padded to these sizes run on programs compiled already.
_PROGRAM_SIZES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _program_sizes(logdensity, dim: int, dtype) -> dict[str, int]:
    """The family sizes remembered for this log density (a fresh dict if it cannot be remembered)."""
    try:
        per_target = _PROGRAM_SIZES.setdefault(logdensity, {})
    except TypeError:  # not weakly referable
        return {}
    return per_target.setdefault((dim, jnp.dtype(dtype).name), {})


class _Tried(NamedTuple):
    """A Restore stage as the final run may take it: its report, fit, regeneration (defensive
    component included), trusted `log Z` (or `None`) and the draws its regeneration was chosen by."""

    report: StageReport
    fit: Any
    regeneration: Mixture
    log_z: float | None
    chosen_from: tuple[np.ndarray, np.ndarray]


class AutoResult:
    """What `autosample` returns: the final run's result, the chosen regeneration and the stages.

    `estimate`, `normalising_constant`, `tour_statistics`, `ess`, `estimate_draws`,
    `to_arviz` and `summary` are those of the final run (`result`), whose estimates carry
    the tail diagnostic `k_hat` and say whether their error bars can be trusted.

    Attributes:
        result: the final run's `SampleResult`.
        sampler: the final `JumpRestore` sampler.
        regeneration: the chosen regeneration distribution (defensive component included).
        stages: a `StageReport` per stage, the final run last.
        evaluations: log-density evaluations of all stages together.
        wall_time: seconds for the whole call.
        healthy: whether a stage reached healthy tails before the final run.
    """

    def __init__(self, result, sampler, regeneration, stages, evaluations, wall_time, healthy):
        self.result: SampleResult = result
        self.sampler: JumpRestore = sampler
        self.regeneration: AbstractRegeneration = regeneration
        self.stages: tuple[StageReport, ...] = tuple(stages)
        self.evaluations: int = int(evaluations)
        self.wall_time: float = float(wall_time)
        self.healthy: bool = bool(healthy)

    def estimate(self, name: str, method=None, lanes=None):
        """The final run's estimate of the observable `name` (see `SampleResult.estimate`)."""
        return self.result.estimate(name, method=method, lanes=lanes)

    def normalising_constant(self, method="tours"):
        """The final run's estimate of `log Z` (see `SampleResult.normalising_constant`)."""
        return self.result.normalising_constant(method)

    def tour_statistics(self):
        return self.result.tour_statistics()

    def ess(self, name: str, method=None):
        return self.result.ess(name, method)

    def estimate_draws(self, fn):
        return self.result.estimate_draws(fn)

    def to_arviz(self, resample: bool = True, seed: int = 0, transform=None, chains: int | None = None):
        """The final run's stored draws in ArviZ, lanes grouped into chains (see `SampleResult.to_arviz`)."""
        return self.result.to_arviz(resample=resample, seed=seed, transform=transform, chains=chains)

    def summary(self) -> str:
        """The stages in a table, then the final run's summary."""
        lines = [
            f"autosample: {len(self.stages)} stages, {self.evaluations:,} evaluations in {self.wall_time:.1f} s"
            + ("" if self.healthy else " (no stage reached healthy tails: read the diagnostics)"),
            "  stage kind   regeneration                    evals     k_hat(T)  k_hat(w)  log Z",
        ]
        for s in self.stages:
            z = "" if math.isnan(s.log_z) else f"{s.log_z:.4f} +- {s.log_z_se:.4f}"
            lines.append(
                f"  {s.stage:>5} {s.kind:<6} {s.family + f' x{s.num_components}':<30} {s.evaluations:>10,} "
                f"{s.duration_k_hat:>8.2f} {s.importance_k_hat:>9.2f}  {z}"
            )
        return "\n".join(lines + [self.result.summary()])

    def __repr__(self) -> str:
        final = self.stages[-1]
        return (
            f"<AutoResult: {len(self.stages)} stages, {self.evaluations:,} evaluations, final regeneration "
            f"{final.family} x{final.num_components}, k_hat(T) {final.duration_k_hat:.2f}>"
        )


def _user_knowledge(box, scale, loc, prior, dim, dtype):
    """Where the seeding chains start, and the defensive component of every regeneration."""
    given = [name for name, value in (("box", box), ("scale", scale), ("prior", prior)) if value is not None]
    if len(given) != 1:
        raise ValueError(
            "give exactly one of box=(lower, upper), scale= (with optional loc=) or prior= (a "
            f"restore.regeneration distribution): what you know about where the target's mass is; got {given or 'none'}"
        )
    dim = None if dim is None else check_integer(dim, "dim")
    if prior is not None:
        if not isinstance(prior, AbstractRegeneration):
            raise TypeError(f"prior must be a restore.regeneration distribution, got {type(prior).__name__}")
        _agrees(dim, prior.dim, "prior")
        return prior, prior
    if box is not None:
        try:
            lower, upper = box
        except (TypeError, ValueError):
            raise ValueError(f"box must be a pair (lower, upper), got {box!r}") from None
        lower, upper = np.broadcast_arrays(np.asarray(lower, np.float64), np.asarray(upper, np.float64))
        if lower.ndim == 0:
            if dim is None:
                raise ValueError("box bounds are scalars: give dim= too")
            lower, upper = np.full(dim, float(lower)), np.full(dim, float(upper))
        if lower.ndim == 1:
            _agrees(dim, lower.shape[0], "box")
        if lower.ndim != 1 or not (np.all(np.isfinite(lower)) and np.all(np.isfinite(upper)) and np.all(upper > lower)):
            raise ValueError("box must be (lower, upper) with finite 1-d bounds and upper > lower everywhere")
        centre, half = 0.5 * (lower + upper), 0.5 * (upper - lower)
        starts = UniformBox(jnp.asarray(lower, dtype), jnp.asarray(upper, dtype))
        return starts, _diagonal_t(centre, half, dtype)
    scale = np.asarray(scale, np.float64)
    if scale.ndim > 1:
        raise ValueError(f"scale must be a scalar or a vector (d,), got shape {scale.shape}")
    if scale.ndim == 1:
        _agrees(dim, scale.shape[0], "scale")
    if loc is None:
        if scale.ndim == 0 and dim is None:
            raise ValueError("scale is a scalar and no loc is given: give dim= too")
        loc = np.zeros(dim if scale.ndim == 0 else scale.shape[0])
    loc = np.asarray(loc, np.float64)
    if loc.ndim > 1:
        raise ValueError(f"loc must be a scalar or a vector (d,), got shape {loc.shape}")
    if loc.ndim == 0:  # a scalar centre: one value for every coordinate
        if scale.ndim == 0 and dim is None:
            raise ValueError("scale and loc are scalars: give dim= too")
        loc = np.full(dim if scale.ndim == 0 else scale.shape[0], float(loc))
    _agrees(dim, loc.shape[0], "loc")
    if scale.ndim == 1 and scale.shape != loc.shape:
        raise ValueError(f"scale has {scale.shape[0]} coordinates and loc {loc.shape[0]}: they must agree")
    scale = np.broadcast_to(scale, loc.shape)
    if not (np.all(np.isfinite(scale)) and np.all(scale > 0) and np.all(np.isfinite(loc))):
        raise ValueError("scale must be positive and finite, and loc finite")
    return StudentT(jnp.asarray(loc, dtype), jnp.asarray(scale**2, dtype), DEFENSIVE_DF), _diagonal_t(loc, scale, dtype)


def _agrees(dim: int | None, length: int, what: str) -> None:
    """Refuse a `dim` that disagrees with the length of `box`, `scale`, `loc` or the prior
    (one of them would otherwise be silently ignored)."""
    if dim is not None and int(dim) != int(length):
        raise ValueError(f"dim={dim} disagrees with {what}, which has {length} coordinates: give one dimension")


def _diagonal_t(centre: np.ndarray, scale: np.ndarray, dtype) -> DiagonalMixture:
    """The Student-t with `DEFENSIVE_DF` degrees of freedom and diagonal scales: the defensive
    component, as a one-component diagonal mixture (`O(d)` per evaluation, where the same
    distribution as a `StudentT` would solve with a `(d, d)` factor at every step)."""
    return DiagonalMixture(np.ones(1), jnp.asarray(centre[None], dtype), jnp.asarray(scale[None], dtype), DEFENSIVE_DF)


def typical_scale(regeneration: AbstractRegeneration) -> np.ndarray:
    """Per-coordinate standard deviation within a component: the step scale of local moves.

    For a mixture, the weighted median over components of each coordinate's scale: a few
    broad components (fitted to seeding chains that had not arrived yet) must not set the
    step of local moves in narrow modes, where it would reject nearly every move.
    """
    if isinstance(regeneration, Mixture):
        parts = np.array([typical_scale(c) for c in regeneration.components])
        return _weighted_median(parts, np.asarray(regeneration.weights))
    if isinstance(regeneration, DiagonalMixture):
        return _weighted_median(np.asarray(regeneration.scales), np.exp(np.asarray(regeneration.log_weights)))
    if isinstance(regeneration, ProductMixture):  # (d, K) scales and log weights, one mixture per coordinate
        scales, weights = np.asarray(regeneration.scales), np.exp(np.asarray(regeneration.log_weights))
        return np.array([_weighted_median(s[:, None], w)[0] for s, w in zip(scales, weights, strict=True)])
    if isinstance(regeneration, ConditionalGaussian):  # each coordinate's spread given the others, at a typical draw
        draws = distribution_draws(regeneration, jax.random.key(0), 2048)
        return np.median(np.asarray(regeneration.conditional_scales(draws)), axis=0)
    if isinstance(regeneration, RotatedProductMixture):  # x = centre + A^{-1} y: each axis of x mixes the y's
        within = typical_scale(regeneration.product)
        return np.sqrt(np.asarray(regeneration.inverse, np.float64) ** 2 @ within**2)
    for name in ("scale_tril",):
        tril = getattr(regeneration, name, None)
        if tril is not None:
            return np.sqrt(np.sum(np.asarray(tril) ** 2, axis=1))
    draws = np.asarray(distribution_draws(regeneration, jax.random.key(0), 2048))
    return np.std(draws, axis=0)


def default_kernel(regeneration: AbstractRegeneration, d: int, dtype) -> AbstractLocalKernel:
    """Random-walk Metropolis scaled `2.38 / sqrt(d)` to the regeneration's components: with
    several, each step sized by the components where the walk is (`GuidedRandomWalk`); with
    one, along its correlations when it has a full covariance, else axis by axis."""
    guide = guide_components(regeneration)
    if guide is not None and np.sum(np.isfinite(guide[0])) > 1:
        log_w, means, trils = (jnp.asarray(a, dtype) for a in guide)
        return GuidedRandomWalk(log_w, means, trils, 2.38 / math.sqrt(d))
    scales = typical_scale(regeneration)
    tril = typical_scale_tril(regeneration, scales)
    if tril is not None:
        return CorrelatedRandomWalk(jnp.asarray(2.38 / math.sqrt(d) * tril, dtype))
    return RandomWalk(jnp.asarray(2.38 / math.sqrt(d) * scales, dtype))


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Per column of `values` `(K, d)`, the median under the weights `(K,)`."""
    order = np.argsort(values, axis=0)
    cumulative = np.cumsum(weights[order], axis=0) / np.sum(weights)
    columns = np.arange(values.shape[1])
    return values[order[np.argmax(cumulative >= 0.5, axis=0), columns], columns]


def _evaluations(result: SampleResult, pilot: int) -> int:
    return int(result.num_lanes * (result.num_steps + result.finishing_steps) + pilot)


def _stage_report(stage, kind, fit, result: SampleResult, pilot: int, seconds: float) -> StageReport:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        stats = result.tour_statistics()
        try:
            log_z = result.normalising_constant()
            z, z_se = float(log_z.value), float(log_z.standard_error)
        except ValueError:
            z, z_se = math.nan, math.nan
        try:
            k_w = float(result.normalising_constant("importance").k_hat)
        except ValueError:
            k_w = math.nan
    k_t = float(stats.k_hat)
    share = stats.effective_num_tours / max(stats.num_tours, 1)
    healthy = (
        stats.num_tours >= 100
        and k_t < HEALTHY_DURATION_K
        and not (k_w >= HEALTHY_IMPORTANCE_K)
        and not stats.heavy_tailed  # no tour outlasted the stage, no handful of tours holds the time
        and result.num_uncovered == 0
        and result.num_invalid == 0
    )
    return StageReport(stage, kind, fit.family, fit.num_components, _evaluations(result, pilot), seconds, k_t, k_w, share, z, z_se, bool(healthy))


def autosample(
    logdensity: Callable[[Array], Array],
    key: PRNGKeyArray,
    *,
    box: tuple[ArrayLike, ArrayLike] | None = None,
    scale: ArrayLike | None = None,
    loc: ArrayLike | None = None,
    prior: AbstractRegeneration | None = None,
    dim: int | None = None,
    num_lanes: int = 1024,
    num_steps: int = 1000,
    observables: Mapping[str, Callable[[Array], Array]] | None = None,
    tour_length: float = 5.0,
    local: AbstractLocalKernel | None = None,
    families: Sequence[str] = FAMILIES,
    laplace: bool = True,
    defensive: float = 0.1,
    max_stages: int = 16,
    stage_steps: int | None = None,
    seed_steps: int = 200,
    progress: bool = True,
    save: SaveDraws = DEFAULT_DRAWS,
    checkpoint: Checkpoint | str | os.PathLike | None = None,
) -> AutoResult:
    """Sample `logdensity` with jump Restore, its regeneration built and improved in stages.

    Give one of `box`, `scale` (with `loc`) or `prior`: what you know about where the
    target's mass is. The result's estimates come from a final run whose regeneration was
    fixed before it started; every estimate carries the tail diagnostic `k_hat` and is
    marked unreliable when its error bar cannot be trusted.

    Arguments:
        logdensity: unnormalised log density of one point `(d,)`.
        key: a JAX PRNG key.
        box: `(lower, upper)` bounds (arrays `(d,)`, or scalars with `dim`) that hold most
            of the mass; seeding starts are uniform in it, and a Student-t over it (df 3)
            is the defensive component.
        scale: a rough scale of the target around `loc` (scalar with `dim`, or `(d,)`).
        loc: the centre for `scale` (default 0).
        prior: a `restore.regeneration` distribution that covers the target (e.g. the
            prior of a Bayesian model); starts are drawn from it and it is the defensive
            component.
        dim: the dimension, when `box` or `scale` are scalars.
        num_lanes: lanes of every stage and of the final run.
        num_steps: steps per lane of the final run.
        observables: what the final run streams (default `x` and `x**2`).
        tour_length: mean tour duration `T` of every run.
        local: the local kernel (default: random-walk Metropolis scaled `2.38 / sqrt(d)` to
            each stage's fitted regeneration: with several components, steps sized and
            oriented by the components where the walk is (`restore.local.GuidedRandomWalk`);
            with one, along its correlations when it has a full covariance
            (`typical_scale_tril`), else axis by axis).
        families: the regeneration families to choose from (see
            `restore.regeneration.choose_regeneration`).
        laplace: also offer, at every stage, Laplace approximations (Gaussian and
            Student-t components) at the modes that optimisation from the seeding chains' last states finds (when
            the log density has a gradient and modes are found).
        defensive: weight of the defensive component in every regeneration.
        max_stages: most Restore stages before the final run. Adapting stops at the first
            healthy stage; without one, after 6 stages it goes on only while one of the last 3
            found mass the stages before it missed (a `log Z` 3 standard errors above theirs).
        stage_steps: steps per lane of each stage (default `max(100, num_steps // 4)`).
        seed_steps: steps of each seeding chain.
        progress: show progress bars and one line per stage.
        save: the draws the final run keeps (`restore.SaveDraws`); the stages keep as many
            per lane, thinned over their shorter runs, to fit the next regeneration to.
        checkpoint: the final run's checkpoint (`restore.Checkpoint` or a file name).

    Returns:
        An `AutoResult`.
    """
    started = time.perf_counter()
    check_key(key)
    num_lanes, num_steps = check_integer(num_lanes, "num_lanes", minimum=4), check_integer(num_steps, "num_steps")
    max_stages, seed_steps = check_integer(max_stages, "max_stages"), check_integer(seed_steps, "seed_steps", minimum=4)
    stage_steps = max(100, num_steps // 4) if stage_steps is None else check_integer(stage_steps, "stage_steps")
    if not 0.0 < float(defensive) < 1.0:
        raise ValueError(f"defensive must lie in (0, 1), got {defensive!r}")
    dtype = jnp.result_type(float)
    starts_from, defend = _user_knowledge(box, scale, loc, prior, dim, dtype)
    d = starts_from.dim
    check_logdensity(logdensity, d)
    say = console_note if progress else (lambda message: None)

    key_seed, key_starts, key_final, stage_keys = _keys(key, min(max_stages, KEYED_STAGES))
    clock = time.perf_counter()
    starts = distribution_draws(starts_from, key_starts, num_lanes)
    if starts.dtype != dtype:
        raise ValueError(
            f"the prior draws {starts.dtype} numbers and JAX computes in {dtype} (jax_enable_x64 was switched "
            "after the prior was built?): build the prior, and the target, after jax.config.update('jax_enable_x64', ...)"
        )
    check_coordinates(logdensity, starts[:PROBE_POINTS])
    seeds = seed_draws(logdensity, starts, key_seed, num_steps=seed_steps)
    seed_report = StageReport(
        0, "seed", "chains", num_lanes, seeds.evaluations, time.perf_counter() - clock,
        math.nan, math.nan, math.nan, math.nan, math.nan, False,
    )  # fmt: skip
    stages = [seed_report]
    say(f"autosample: {num_lanes} seeding chains, {'MALA' if seeds.uses_gradient else 'random walk'}, acceptance {seeds.acceptance:.2f}")
    draws, weights, groups = seeds.positions, np.ones(len(seeds.positions)), seeds.chains
    extra, mode_evaluations = laplace_candidates(logdensity, seeds, d) if laplace else ((), 0)
    if mode_evaluations:
        stages[0] = seed_report._replace(evaluations=seeds.evaluations + mode_evaluations, wall_time=time.perf_counter() - clock)
        say(f"autosample: Laplace candidates at the modes found from the seeding chains ({max((f.num_components for f in extra), default=0)} components)")

    sizes = _program_sizes(logdensity, d, dtype)

    def regeneration_from(fit):
        """The fit padded to the size its family last ran with (so that its programs are reused), with the defensive component."""
        size = padded_size(fit.num_components, sizes.get(fit.family))
        sizes[fit.family] = size
        return Mixture([fit.padded(size), defend], jnp.asarray([1.0 - defensive, defensive], dtype))

    def sampler_for(u, log_z):
        kernel = local if local is not None else default_kernel(u.components[0], d, dtype)
        sampler = JumpRestore(logdensity, kernel, u, tour_length=tour_length)
        if log_z is None:
            return sampler, True
        # Calibrated from the stage's log Z, not by a pilot; as a sampler with the same static
        # fields as a piloted one, so that its run reuses the programs compiled for the stage.
        return sampler.calibrated_to(float(log_z)), False

    # Stages store draws in a buffer of the final run's shape, and stream the same observables,
    # so the final run reuses the compiled programs of the stage whose regeneration it takes.
    if not isinstance(save, SaveDraws):
        raise TypeError(f"save must be a restore.SaveDraws, got {type(save).__name__}")
    final = save.plan(num_steps, num_lanes)
    if final.stored > 0:
        stage_save = SaveDraws(final.stored * num_lanes, max(1, stage_steps // final.stored), final.rows)
    else:  # the final run stores no draws; the stages need some to fit to
        stage_save = SaveDraws(min(100_000, num_lanes * 64))

    tried: list[_Tried] = []
    log_z = None
    stage = 0
    while True:
        stage += 1
        clock = time.perf_counter()
        choice = choose_regeneration(draws, weights, groups, families=families, seed=stage, sizes=sizes, extra=extra)
        # the next stage fits again only the families that came close to the best
        families = close_families(families, choice.candidates, d)
        u = regeneration_from(choice.fit)
        sampler, piloted = sampler_for(u, log_z)
        stage_key = stage_keys[stage - 1] if stage <= len(stage_keys) else jax.random.fold_in(stage_keys[-1], stage)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            # a tour that outlasts as many steps again as the stage had is a finding of the stage
            # (the regeneration misses mass), not worth ten times the stage's steps to finish
            result = sample(
                sampler, stage_key, num_lanes=num_lanes, num_steps=stage_steps,
                observables=observables, progress=progress, save=stage_save, finish_tours=stage_steps,
            )  # fmt: skip
        pilot = sampler.pilot_size if piloted else 0
        report = _stage_report(stage, "adapt", choice.fit, result, pilot, time.perf_counter() - clock)
        stages.append(report)
        say(
            f"autosample stage {stage}: {choice.fit.family} x{choice.fit.num_components}, tail shapes "
            f"k_hat(T) {report.duration_k_hat:.2f}, k_hat(w) {report.importance_k_hat:.2f}"
            + (" - healthy" if report.healthy else "")
        )
        # The next stage's rate from this stage's log Z when its error bar can be trusted, else
        # from a pilot: tours that outlast a stage bias its log Z (low, by a nat or more in a
        # first stage), and a rate off by that much makes the next stage's tours that much longer.
        log_z = _trusted_log_z(result)
        # the draws this regeneration was chosen by, drawn with another one: evidence on its coverage
        tried.append(_Tried(report, choice.fit, u, log_z, _coverage_sample(draws, weights)))
        if report.healthy or not keep_adapting([t.report for t in tried], max_stages):
            break
        draws, weights, groups = _stage_draws(result, d)

    index = final_stage([t.report for t in tried])
    report, fit, u, log_z, chosen_from = tried[index]
    clock = time.perf_counter()
    if report.healthy and index == 0 and report.effective_tours < REFIT_SHARE:
        # The seeding chains have not equilibrated, so a healthy first stage still regenerates from a
        # fit to draws that are not the target's: fitted again to that stage's tours where that scores better.
        draws, weights, groups = _stage_draws(result, d)
        refit = refit_regeneration(fit, draws, weights, groups, seed=stage + 1).fit
        if refit is not fit:
            fit, u, chosen_from = refit, regeneration_from(refit), _coverage_sample(draws, weights)
            say(f"autosample: {fit.family} x{fit.num_components} fitted again to stage 1's tours (their effective share {report.effective_tours:.2f})")
    sampler, piloted = sampler_for(u, log_z)
    with advising(AUTOSAMPLE_ADVICE):
        result = sample(
            sampler, key_final, num_lanes=num_lanes, num_steps=num_steps, observables=observables, progress=progress,
            save=save, checkpoint=checkpoint,
        )  # fmt: skip
    checked = coverage_caveat(logdensity, u, result, *chosen_from)
    result.caveat = checked.caveat
    final_report = _stage_report(len(stages), "final", fit, result, sampler.pilot_size if piloted else 0, time.perf_counter() - clock)
    stages.append(final_report._replace(evaluations=final_report.evaluations + checked.evaluations))
    total = sum(s.evaluations for s in stages)
    return AutoResult(result, sampler, u, stages, total, time.perf_counter() - started, report.healthy)


#: At most this many of the draws a regeneration was chosen by are used to check its coverage.
COVERAGE_DRAWS = 16384
#: Unseen mass (`restore._coverage.unseen_mass`) above this many standard errors of `log Z`
#: (and above `COVERAGE_FLOOR`) marks the final run's estimates unreliable.
COVERAGE_SE = 2.0
COVERAGE_FLOOR = 1e-3


class Coverage(NamedTuple):
    """The coverage check of the final regeneration: a caveat (`""` when it passes) and the evaluations it took."""

    caveat: str
    evaluations: int


def coverage_caveat(logdensity, regeneration: AbstractRegeneration, result: SampleResult, draws, weights) -> Coverage:
    """Check the final regeneration against the draws it was chosen by (drawn with another one).

    The final run's estimates miss the mass of any region where the regeneration is so
    thin that the run expects fewer than one tour to start there (`unseen_mass`); its
    diagnostics, computed from the tours it ran, cannot show that. The draws of the stage
    that chose the regeneration (run with the stage before's) can: when they put more than
    `COVERAGE_SE` standard errors of `log Z` of the target's mass there, the estimates are
    marked unreliable.
    """
    x, w = _coverage_sample(draws, weights)
    if w.size == 0 or not result.has_tours:
        return Coverage("", 0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        log_z = result.normalising_constant()
    if not (np.isfinite(float(log_z.value)) and bool(log_z.reliable)):
        return Coverage("", 0)  # marked already
    points = jnp.asarray(x, result.draws.dtype)
    log_p, log_u = _densities(logdensity, regeneration, points)
    tours = float(np.sum(result.sums.num_tours))
    mass = unseen_mass(np.asarray(log_p), np.asarray(log_u), w, float(log_z.value), tours)
    if mass <= max(COVERAGE_SE * float(log_z.standard_error), COVERAGE_FLOOR):
        return Coverage("", int(w.size))
    return Coverage(
        f"about {mass:.1%} of the target's mass, seen in an earlier stage's draws, lies where the regeneration is so "
        f"thin that this run's {tours:,.0f} tours expect fewer than one start there, so the estimates miss it "
        f"(a mode or region the regeneration leaves to its defensive component): {COVERAGE_REMEDY}",
        int(w.size),
    )


def _stage_draws(result: SampleResult, d: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A stage's stored draws `(n, d)`, their weights and their lanes (the groups held out together)."""
    groups = np.broadcast_to(np.arange(result.num_lanes), result.draw_weights.shape).reshape(-1)
    return np.asarray(result.draws).reshape(-1, d), np.asarray(result.draw_weights).reshape(-1), groups


def _coverage_sample(draws, weights) -> tuple[np.ndarray, np.ndarray]:
    """The finite draws of positive weight, at most `COVERAGE_DRAWS` of them (a fixed random subset, in order)."""
    x = np.asarray(draws, np.float64)
    w = np.asarray(weights, np.float64).reshape(-1)
    keep = np.flatnonzero(np.isfinite(w) & (w > 0) & np.all(np.isfinite(x), axis=1))
    if keep.size > COVERAGE_DRAWS:
        keep = np.sort(np.random.default_rng(0).choice(keep, COVERAGE_DRAWS, replace=False))
    return x[keep], w[keep]


@jit(filtered=True, once=True)
def _densities(logdensity, regeneration, points):
    """`log p` and `log u` at `points` `(n, d)`."""
    return jax.vmap(logdensity)(points), jax.vmap(regeneration.log_prob)(points)


@jit(static_argnums=1, once=True)
def _keys(key: PRNGKeyArray, max_stages: int):
    """The keys of the seeding chains, their starts, the final run and the first `max_stages`
    stages, in one compiled program (eager splits and folds would compile one each)."""
    key_seed, key_starts, key_final, *stages = jax.random.split(key, 3 + max_stages)
    return key_seed, key_starts, key_final, tuple(stages)


def _trusted_log_z(result: SampleResult) -> float | None:
    """A run's `log Z` from its tours, or `None` when it is missing or marked unreliable."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            log_z = result.normalising_constant()
        except ValueError:
            return None
    value = float(log_z.value)
    return value if math.isfinite(value) and bool(log_z.reliable) else None
