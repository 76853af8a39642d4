"""The evidence benchmark: `log Z` from Restore, tempered SMC and nested sampling on problems with exact answers."""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._evidence_problems import EVIDENCE_PROBLEMS, EvidenceReference, get_evidence_problem
from ._evidence_restore import AutosampleRunner, LaplaceRestoreRunner
from ._evidence_runner import EvidenceOutput, EvidenceRunner, short_message
from ._nested_runner import DynestyRunner
from ._nuts_runner import NUTSRunner
from ._smc_runner import TemperedSMCRunner
from ._suite import _key, _progress


@dataclass(frozen=True)
class EvidenceConfig:
    """What an evidence run covers and how big each method's setup is.

    Every method runs once per problem and seed, with its own natural budget (the table
    reports what each spent): tempered SMC with `smc_particles` particles and
    `smc_mcmc_steps` HMC moves per temperature; dynesty with `nested_live` live points,
    stopped after `nested_seconds` of sampling at the latest; Restore's hand-built recipe and
    `restore.autosample` with `restore_lanes` lanes of `restore_steps` steps (the recipe
    finds modes from `restore_starts` uniform starts in the box; `autosample` runs at most
    `restore_stages` adaptive stages; `None`: its default); NUTS (moments only) with `nuts_chains`
    chains of `nuts_warmup` adaptation and `nuts_kept` kept steps. `samplers`, when given,
    keeps the methods whose names start with one of its entries.
    """

    name: str
    problems: tuple[str, ...] = tuple(EVIDENCE_PROBLEMS)
    seeds: int = 3
    smc_particles: int = 4096
    smc_mcmc_steps: int = 5
    nested_live: int = 500
    nested_seconds: float = 600.0
    restore_lanes: int = 1024
    restore_steps: int = 1000
    restore_starts: int = 256
    restore_stages: int | None = None
    nuts_chains: int = 4
    nuts_warmup: int = 1000
    nuts_kept: int = 1000
    samplers: tuple[str, ...] | None = None
    reference_draws: int = 65536
    base_seed: int = 0

    def __post_init__(self):
        if not self.problems:
            raise ValueError("choose at least one problem")
        for name in self.problems:
            get_evidence_problem(name)
        if self.seeds < 1:
            raise ValueError(f"need seeds >= 1, got {self.seeds}")

    def replace(self, **changes) -> EvidenceConfig:
        return dataclasses.replace(self, **changes)

    @classmethod
    def full(cls) -> EvidenceConfig:
        """3 seeds; SMC 4096 particles, dynesty 500 live points (10 min cap), Restore 1024 lanes x 1000 steps."""
        return cls("full")

    @classmethod
    def quick(cls) -> EvidenceConfig:
        """2 seeds with small budgets: SMC 1024 particles, dynesty 200 live points (1 min cap), Restore 256 x 250."""
        return cls("quick", seeds=2, smc_particles=1024, nested_live=200, nested_seconds=60.0, restore_lanes=256, restore_steps=250)

    @classmethod
    def tiny(cls) -> EvidenceConfig:
        """Seconds of sampling, for the smoke test: one seed, tiny budgets, the 2-d mixture."""
        return cls(
            "tiny", problems=("gmm40",), seeds=1, smc_particles=64, smc_mcmc_steps=2, nested_live=25,
            nested_seconds=2.0, restore_lanes=32, restore_steps=60, restore_starts=32, restore_stages=1, reference_draws=4096,
            nuts_chains=2, nuts_warmup=20, nuts_kept=20,
        )

    def runners(self) -> list[EvidenceRunner]:
        """The methods of this configuration: Restore (recipe, autosample), tempered SMC, dynesty, NUTS."""
        out: list[EvidenceRunner] = [
            LaplaceRestoreRunner(self.restore_lanes, self.restore_steps, self.restore_starts),
            AutosampleRunner(self.restore_lanes, self.restore_steps, self.restore_stages),
            TemperedSMCRunner(self.smc_particles, self.smc_mcmc_steps),
            TemperedSMCRunner(self.smc_particles, self.smc_mcmc_steps, dense=True, name="smc-hmc-dense"),
            DynestyRunner(self.nested_live, self.nested_seconds),
            NUTSRunner(self.nuts_chains, self.nuts_warmup, self.nuts_kept),
        ]
        if self.samplers is not None:
            out = [r for r in out if any(r.name.startswith(s) for s in self.samplers)]
        return out


@dataclass
class EvidenceResult:
    """Everything an evidence run measured, and where its files went."""

    config: EvidenceConfig
    rows: list[dict]
    references: dict[str, EvidenceReference]
    machine: dict[str, str]
    seconds: float
    files: dict[str, Path] = field(default_factory=dict)
    interrupted: bool = False


def _max_abs_z(estimate, standard_error, truth) -> float:
    if estimate is None or standard_error is None:
        return math.nan
    with np.errstate(divide="ignore", invalid="ignore"):
        z = (np.asarray(estimate) - truth) / np.asarray(standard_error)
    return float(np.max(np.abs(z))) if np.all(np.isfinite(z)) else math.nan


def _rms_error(estimate, truth: np.ndarray, unit: np.ndarray) -> float:
    if estimate is None:
        return math.nan
    return float(np.sqrt(np.mean(((np.asarray(estimate, np.float64) - truth) / unit) ** 2)))


def score_evidence(out: EvidenceOutput, ref: EvidenceReference) -> dict:
    """The metrics of one run against the exact answers.

    `log_z_error` is signed (estimate minus truth); `log_z_z` divides it by the reported
    standard error. `max_z_mean` and `max_z_second` are the largest `|z|` over coordinates
    of the means and second moments, where the method reports standard errors (several
    dozen z-scores: values up to about 3 are expected). `mean_error` and
    `second_moment_error` are root-mean-square errors over coordinates in units of the
    marginal standard deviation (variance for second moments), for every method.
    """
    error = out.log_z - ref.log_z
    positive_error = out.positive - ref.positive_probability if ref.positive_probability is not None else math.nan
    with np.errstate(divide="ignore", invalid="ignore"):
        log_z_z = error / out.log_z_se if out.log_z_se > 0 else math.nan
        positive_z = positive_error / out.positive_se if out.positive_se > 0 else math.nan
    return {
        "log_z": out.log_z, "log_z_true": ref.log_z, "log_z_error": error, "abs_log_z_error": abs(error),
        "log_z_se": out.log_z_se, "log_z_z": log_z_z, "k_hat": out.k_hat, "reliable": "" if out.reliable is None else str(out.reliable),
        "mean_error": _rms_error(out.mean, ref.mean, ref.sd),
        "second_moment_error": _rms_error(out.second_moment, ref.second_moment, ref.sd**2),
        "max_z_mean": _max_abs_z(out.mean, out.mean_se, ref.mean),
        "max_z_second": _max_abs_z(out.second_moment, out.second_moment_se, ref.second_moment),
        "positive": out.positive, "positive_true": math.nan if ref.positive_probability is None else ref.positive_probability,
        "positive_error": positive_error, "positive_z": positive_z,
    }


def _row(problem: str, runner: EvidenceRunner, seed: int, out: EvidenceOutput, ref: EvidenceReference) -> dict:
    return {
        "problem": problem, "method": runner.name, "family": runner.family, "seed": seed, "status": out.status,
        **score_evidence(out, ref), "evaluations": out.evaluations, "wall_time": out.wall_time, "run_time": out.run_time,
        "compile_time": out.compile_time, "notes": out.notes,
    }


def _run_one(runner: EvidenceRunner, problem, key) -> EvidenceOutput:
    """One run; an exception becomes a `failed` output carrying its message (Ctrl-C is not caught)."""
    reason = runner.unavailable()
    if reason is not None:
        return EvidenceOutput.empty("skipped", reason)
    started = time.perf_counter()
    try:
        return runner.run(problem, key)
    except Exception as error:  # a method that cannot handle a problem is a result, not a crash
        return EvidenceOutput.empty("failed", short_message(error), wall_time=time.perf_counter() - started)


def run_evidence(
    config: EvidenceConfig, out_dir: str | Path | None = None, *, progress: bool = True, log: Callable[[str], None] | None = None
) -> EvidenceResult:
    """Run `config` and (if `out_dir` is given) write `evidence.csv` and `evidence.md` there.

    Every method runs on every problem and seed. A method that raises (Restore's Laplace
    recipe on the funnel, which has no mode) gives a `failed` row with the error message;
    one that cannot run here (a missing package)
    gives a `skipped` row. Ctrl-C stops the run: the finished runs are kept, written, and
    the result says `interrupted=True`. `log`, if given, is called with one line per run.
    """
    from ._evidence_report import write_evidence
    from ._report import _version, machine_description

    started, machine = time.perf_counter(), machine_description()
    machine["dynesty"] = _version("dynesty")
    rows: list[dict] = []
    references: dict[str, EvidenceReference] = {}
    interrupted = False
    try:
        _run_all(config, rows, references, progress, log)
    except KeyboardInterrupt:
        interrupted = True
    result = EvidenceResult(config, rows, references, machine, time.perf_counter() - started, interrupted=interrupted)
    if out_dir is not None and (rows or not interrupted):
        result.files = write_evidence(result, Path(out_dir))
    return result


def _run_all(config: EvidenceConfig, rows: list[dict], references: dict, progress: bool, log) -> None:
    runners = config.runners()
    with _progress(len(config.problems) * config.seeds * len(runners), progress) as (describe, advance):
        for name in config.problems:
            problem = get_evidence_problem(name)
            describe(f"{name}: exact reference")
            ref = references[name] = problem.reference(_key(config, name, "reference"), config.reference_draws)
            for seed in range(config.seeds):
                for runner in runners:
                    describe(f"{name} seed {seed}: {runner.name}")
                    out = _run_one(runner, problem, _key(config, name, seed, runner.name))
                    rows.append(_row(name, runner, seed, out, ref))
                    advance()
                    if log is not None:
                        log(
                            f"{name} seed {seed} {runner.name}: {out.status}, log Z {out.log_z:.4f} (truth {ref.log_z:.4f}), "
                            f"{out.evaluations:,} evaluations, {out.run_time:.1f} s (+{out.compile_time:.1f} s compile)"
                            + (f"; {out.notes}" if out.notes else "")
                        )
