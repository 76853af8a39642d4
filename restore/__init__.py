"""restore: Restore samplers in JAX.

A Restore process runs local dynamics (any pi-invariant Markov kernel, embedded in
continuous time), kills them at the state-dependent rate `gamma = c_tilde u / p`, and
restarts them at draws of a regeneration distribution `u`. The result is invariant for
the target `p`, regenerative (so many lanes run in parallel with no burn-in), and gives
estimates with honest standard errors and the normalising constant for free.
"""

from . import local as local
from . import regeneration as regeneration
from ._estimates import Estimate as Estimate
from ._diagnostics import TourStatistics as TourStatistics
from ._jump_restore import JumpRestore as JumpRestore
from ._jump_restore import JumpRestoreInfo as JumpRestoreInfo
from ._jump_restore import JumpRestoreState as JumpRestoreState
from ._mixture_mh import MixtureMH as MixtureMH
from ._mixture_mh import MixtureMHInfo as MixtureMHInfo
from ._mixture_mh import MixtureMHState as MixtureMHState
from ._point import Point as Point
from ._rate import PilotEstimate as PilotEstimate
from ._result import LogEstimate as LogEstimate
from ._result import SampleResult as SampleResult
from ._sample import sample as sample

__version__ = "0.1.0"
