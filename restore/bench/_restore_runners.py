"""Runners built on `restore.sample`: jump Restore, the MH mixture baseline, parallel random-walk chains."""

from __future__ import annotations

import math
import warnings

import jax
import numpy as np
from jaxtyping import PRNGKeyArray

from .._jump_restore import JumpRestore
from .._mixture_mh import MixtureMH
from .._options import SaveDraws
from .._sample import sample
from ..local import HMC, MALA, RandomWalk
from ._runner import Budget, Runner, RunOutput
from ._timing import Stopwatch

KERNELS = ("rw", "mala", "hmc")


def local_kernel(problem, kernel: str):
    """The problem's local kernel `kernel` and its evaluations per step (HMC: its leapfrog steps)."""
    if kernel == "rw":
        return RandomWalk(problem.rw_scale), 1
    if kernel == "mala":
        return MALA(problem.mala_step), 1
    if kernel == "hmc":
        return HMC(problem.hmc_step, problem.hmc_steps), problem.hmc_steps
    raise ValueError(f"kernel must be one of {KERNELS}, got {kernel!r}")


def short_notes(caught) -> str:
    """A few words for each distinct warning raised during a run."""
    notes = []
    for w in caught:
        text = str(w.message)
        if "heavy-tailed" in text:
            text = "heavy-tailed tours"
        elif "cannot be trusted" in text:
            text = "unreliable error bars (k_hat)"
        elif "open tour" in text:
            text = "unfinished tours"
        elif "NaN or +inf" in text:
            text = "invalid evaluations"
        else:
            text = text.split(";")[0].split(":")[0][:60]
        if text not in notes:
            notes.append(text)
    return "; ".join(notes)


class _SampleRunner(Runner):
    """Shared machinery: build a sampler, run `restore.sample`, read its estimates and draws.

    Draws for the distributional distance are `draws_per_lane` thinned states per lane
    (the starting state dropped). The thinning is fixed per problem from the smallest
    budget the runner sees (`span_evaluations`) so that every budget point reuses one
    compiled program; the draws then cover the first `span_evaluations` of each lane.
    """

    def __init__(self, kernel: str, lanes: int, span_evaluations: float, draws_per_lane: int = 9, pilot_size: int = 4096):
        super().__init__()
        if kernel not in KERNELS:
            raise ValueError(f"kernel must be one of {KERNELS}, got {kernel!r}")
        if lanes < 2 or draws_per_lane < 2:
            raise ValueError(f"need lanes >= 2 and draws_per_lane >= 2, got {lanes} and {draws_per_lane}")
        self.kernel, self.lanes, self.span, self.draws_per_lane, self.pilot_size = kernel, int(lanes), float(span_evaluations), int(draws_per_lane), int(pilot_size)
        self._built: tuple | None = None

    def _build(self, problem, start, local):
        raise NotImplementedError

    def _sampler(self, problem, start):
        """Build once per (problem, starting information), so compiled programs are reused."""
        tag = (problem.name, id(start.regeneration))
        if self._built is None or self._built[0] != tag:
            local, per_step = local_kernel(problem, self.kernel)
            self._built = (tag, self._build(problem, start, local), per_step)
        return self._built[1], self._built[2]

    def _extra_evaluations(self, result) -> int:
        return 0

    def _prepare(self, sampler, key: PRNGKeyArray):
        """Anything a run does before `restore.sample` (inside the timed block)."""
        return sampler

    def run(self, problem, start, key: PRNGKeyArray, budget: Budget) -> RunOutput:
        sampler, per_step = self._sampler(problem, start)
        steps = max(2, round(self.evaluations_for(problem, budget) / (self.lanes * per_step)))
        min_steps = max(2, round(self.span / (self.lanes * per_step)))
        thin = max(1, (min_steps - 1) // (self.draws_per_lane - 1))
        k_pilot, k_run = jax.random.split(key)
        with warnings.catch_warnings(record=True) as caught, Stopwatch() as clock:
            warnings.simplefilter("always")
            result = sample(
                self._prepare(sampler, k_pilot), k_run, num_lanes=self.lanes, num_steps=steps, observables=problem.observables,
                save=SaveDraws(self.lanes * self.draws_per_lane, thin=thin), progress=False,
            )
        evaluations = self.lanes * per_step * (result.num_steps + result.finishing_steps) + self._extra_evaluations(result)
        draws = result.draws[1:]
        d = draws.shape[-1]

        def value(name):
            try:
                return np.asarray(result.estimate(name).value, np.float64)
            except ValueError:  # e.g. fewer than 2 complete tours
                return None

        mean, m2 = value("x"), value("x**2")
        try:
            ess = float(np.median(result.ess("x")))
        except ValueError:
            ess = math.nan
        output = RunOutput(
            evaluations=int(evaluations),
            wall_time=clock.wall,
            compile_time=clock.compile,
            mode_weights=value("modes") if "modes" in problem.observables else None,
            mean=mean if mean is not None else np.full(d, np.nan),
            second_moment=m2 if m2 is not None else np.full(d, np.nan),
            draws=draws.reshape(-1, d),
            draw_weights=result.draw_weights[1:].reshape(-1),
            ess=ess,
            notes=short_notes(caught),
        )
        if budget.kind == "evaluations":
            self._record_rate(problem, output)
        return output


class JumpRestoreRunner(_SampleRunner):
    """Jump Restore with a RandomWalk, MALA or HMC local kernel; tour length `problem.tour_length`.

    Its evaluations include the pilot that turns the tour length into `c_tilde` and the
    steps that finish the tours still open at the end of the budget.
    """

    family, matches, time_budget = "restore", None, False

    def __init__(self, kernel: str, lanes: int, span_evaluations: float, **kwargs):
        super().__init__(kernel, lanes, span_evaluations, **kwargs)
        self.name = f"restore-{kernel}"

    def _build(self, problem, start, local):
        return JumpRestore(problem.logdensity, local, start.regeneration, tour_length=problem.tour_length, pilot_size=self.pilot_size)

    def _prepare(self, sampler, key: PRNGKeyArray):
        # The pilot estimate is a static field of the calibrated sampler: a fresh one per
        # run would recompile `restore.sample`'s loop every time. It is dropped once
        # `log_rate` is set, so every run reuses one compiled program.
        return sampler.calibrate(key)[0]

    def _extra_evaluations(self, result) -> int:
        return self.pilot_size


class MixtureMHRunner(_SampleRunner):
    """`restore.MixtureMH` with the same kernel and large-step distribution as jump Restore.

    The large-step probability is `factor / T`, with `T` jump Restore's mean tour length
    (`factor = 1` is the matched baseline; 0 gives independent local-kernel chains).
    """

    def __init__(self, kernel: str, lanes: int, span_evaluations: float, factor: float = 1.0, **kwargs):
        super().__init__(kernel, lanes, span_evaluations, **kwargs)
        if not 0 <= factor:
            raise ValueError(f"factor must be >= 0, got {factor!r}")
        self.factor = float(factor)
        self.matches = f"restore-{kernel}"
        if factor == 0:
            self.name, self.family = f"{kernel}-chains", "chains"
        else:
            self.name, self.family = f"mh-{kernel}" + ("" if factor == 1 else f"-q{factor:g}x"), "mh"

    def _build(self, problem, start, local):
        q = min(self.factor / problem.tour_length, 1.0)
        return MixtureMH(problem.logdensity, local, start.regeneration, large_step_probability=q)
