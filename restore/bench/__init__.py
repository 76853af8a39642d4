"""A side-by-side comparison suite: jump Restore against the MH baseline, emcee and BlackJAX.

Every sampler gets the same starting information (random starts and the Laplace mixture
built from them), the same target evaluations and the same wall time as jump Restore,
measured in the same run, on problems with exact answers. `run_suite(SuiteConfig.quick(),
"out/")` writes `results.csv`, `results.md` and plots; `restore bench` runs it from the
command line. See `docs/comparison.md`.

The evidence benchmark (`run_evidence(EvidenceConfig.quick(), "out/")`, or `restore bench
--evidence`) compares the normalising constants of Restore, BlackJAX's adaptive tempered
SMC and dynesty's nested sampler on problems with an exact `log Z`, writing `evidence.csv`
and `evidence.md`.
"""

from ._blackjax_runner import BlackJAXRunner as BlackJAXRunner
from ._config import SuiteConfig as SuiteConfig
from ._emcee_runner import EmceeRunner as EmceeRunner
from ._evidence import EvidenceConfig as EvidenceConfig
from ._evidence import EvidenceResult as EvidenceResult
from ._evidence import run_evidence as run_evidence
from ._evidence_problems import EVIDENCE_PROBLEMS as EVIDENCE_PROBLEMS
from ._evidence_problems import EvidenceProblem as EvidenceProblem
from ._evidence_problems import EvidenceReference as EvidenceReference
from ._evidence_problems import get_evidence_problem as get_evidence_problem
from ._evidence_report import write_evidence as write_evidence
from ._evidence_restore import AutosampleRunner as AutosampleRunner
from ._evidence_restore import LaplaceRestoreRunner as LaplaceRestoreRunner
from ._evidence_runner import CountedDensity as CountedDensity
from ._evidence_runner import EvidenceOutput as EvidenceOutput
from ._evidence_runner import EvidenceRunner as EvidenceRunner
from ._exact_runner import ExactRunner as ExactRunner
from ._metrics import pooled_rms as pooled_rms
from ._metrics import score as score
from ._mmd import median_bandwidth as median_bandwidth
from ._mmd import mmd as mmd
from ._nested_runner import DynestyRunner as DynestyRunner
from ._nuts_runner import NUTSRunner as NUTSRunner
from ._plots import plot_curves as plot_curves
from ._plots import plot_ratios as plot_ratios
from ._problems import PROBLEMS as PROBLEMS
from ._problems import Problem as Problem
from ._problems import Reference as Reference
from ._problems import get_problem as get_problem
from ._ratios import Ratio as Ratio
from ._ratios import recorded_ratios as recorded_ratios
from ._report import machine_description as machine_description
from ._report import write_results as write_results
from ._restore_runners import JumpRestoreRunner as JumpRestoreRunner
from ._restore_runners import MixtureMHRunner as MixtureMHRunner
from ._runner import Budget as Budget
from ._runner import Runner as Runner
from ._runner import RunOutput as RunOutput
from ._smc_runner import TemperedSMCRunner as TemperedSMCRunner
from ._starting import StartingInformation as StartingInformation
from ._starting import starting_information as starting_information
from ._suite import SuiteResult as SuiteResult
from ._suite import check_dependencies as check_dependencies
from ._suite import run_suite as run_suite
from ._timing import Stopwatch as Stopwatch
from ._timing import raw_rate as raw_rate
