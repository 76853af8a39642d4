"""restore: Restore samplers in JAX.

A Restore process runs local dynamics (a Markov kernel embedded in continuous time, or a
diffusion), kills them at the state-dependent rate `gamma = L* p / p + c_tilde q / p`,
and restarts them at draws of a transfer kernel that leaves `q` invariant (a
regeneration distribution `q = u`, in the simplest case). `JumpRestore` is the
pi-invariant-kernel, independent-regeneration special case of `Restore`. The result is invariant for
the target `p`, regenerative (so many lanes run in parallel with no burn-in), and gives
estimates with honest standard errors and the normalising constant for free.
"""

from . import dynamics as dynamics
from . import local as local
from . import regeneration as regeneration
from . import transfer as transfer
from ._autosample import AutoResult as AutoResult
from ._autosample import autosample as autosample
from ._bounds import MinimalRate as MinimalRate
from ._bounds import RateBound as RateBound
from ._bounds import minimal_log_rate as minimal_log_rate
from ._bounds import rate_bound as rate_bound
from ._checkpoint import CheckpointError as CheckpointError
from ._diagnostics import TourStatistics as TourStatistics
from ._estimates import Estimate as Estimate
from ._estimates import UnreliableEstimateWarning as UnreliableEstimateWarning
from ._jump_restore import JumpRestore as JumpRestore
from ._jump_restore import JumpRestoreState as JumpRestoreState
from ._merge import merge_results as merge_results
from ._mixture_mh import MixtureMH as MixtureMH
from ._mixture_mh import MixtureMHState as MixtureMHState
from ._options import Checkpoint as Checkpoint
from ._options import SaveDraws as SaveDraws
from ._pareto import K_HAT_LIMIT as K_HAT_LIMIT
from ._point import Point as Point
from ._rate import JumpEvent as JumpEvent
from ._rate import PilotEstimate as PilotEstimate
from ._rate import jump_event as jump_event
from ._restore import AbstractRestore as AbstractRestore
from ._restore import KillTerms as KillTerms
from ._restore import Restore as Restore
from ._restore import RestoreState as RestoreState
from ._result import LogEstimate as LogEstimate
from ._result import SampleResult as SampleResult
from ._result import ThinnedDrawsWarning as ThinnedDrawsWarning
from ._sample import sample as sample
from ._sampler import AbstractSampler as AbstractSampler
from ._sampler import RunFacts as RunFacts
from ._sampler import StepInfo as StepInfo
from ._speculation import SpeculativeSteps as SpeculativeSteps
from ._speculation import speculative_steps as speculative_steps
from ._stages import StageReport as StageReport
from ._threefry import UNROLLED_THREEFRY as UNROLLED_THREEFRY
from ._threefry import unrolled_keys as unrolled_keys
from ._trace import RunTrace as RunTrace

__version__ = "0.1.0"
