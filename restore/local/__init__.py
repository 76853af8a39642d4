"""Local dynamics: pi-invariant Markov kernels that a Restore process embeds in continuous time.

Each kernel is split at its one new density evaluation (`propose`, then `accept`), so a
sampler can share that evaluation with a regeneration draw. `TorusMetropolis` (with
`KelemenMutation` or `WrappedGaussianMutation`), `TorusMALA` and `TorusH2MC` move on the torus
`[0, 1)^d`, the primary sample space of light transport.
"""

from ._base import AbstractLocalKernel as AbstractLocalKernel
from ._base import LocalInfo as LocalInfo
from ._base import metropolis_accept as metropolis_accept
from ._blackjax import BlackJAXKernel as BlackJAXKernel
from ._correlated_random_walk import CorrelatedRandomWalk as CorrelatedRandomWalk
from ._guided_random_walk import GuidedRandomWalk as GuidedRandomWalk
from ._h2mc import H2MCGaussian as H2MCGaussian
from ._h2mc import TorusH2MC as TorusH2MC
from ._h2mc import h2mc_gaussian as h2mc_gaussian
from ._hmc import HMC as HMC
from ._mala import MALA as MALA
from ._random_walk import RandomWalk as RandomWalk
from ._torus import AbstractTorusMutation as AbstractTorusMutation
from ._torus import KelemenMutation as KelemenMutation
from ._torus import TorusMALA as TorusMALA
from ._torus import TorusMetropolis as TorusMetropolis
from ._torus import WrappedGaussianMutation as WrappedGaussianMutation
