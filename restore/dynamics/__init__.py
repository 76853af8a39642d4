"""Local dynamics in continuous time, each with its generator's adjoint `L* p / p`.

A Restore process kills its local process `Y` at rate `gamma = L* p / p + c_tilde q / p`,
so every dynamics here says how to move and what `L* p / p` is:

- jump dynamics (`AbstractJumpDynamics`): a Markov kernel run at the times of a Poisson
  process. `Jump` wraps any pi-invariant `restore.local` kernel (`L* p = 0`);
  `UnadjustedJump` makes always-accepted Gaussian moves and needs the kernel's
  convolution with the target.
- diffusions (`AbstractDiffusion`): `BrownianMotion` and `OrnsteinUhlenbeck` move exactly;
  `OverdampedLangevin` (pi-invariant) and the generic `Diffusion` move by Euler-Maruyama
  sub-steps and are approximate. `diffusion_adjoint_ratio` computes `L* p / p` of any
  diffusion with a constant diffusion matrix by autodiff.
"""

from ._base import AbstractDiffusion as AbstractDiffusion
from ._base import AbstractDynamics as AbstractDynamics
from ._base import AbstractJumpDynamics as AbstractJumpDynamics
from ._base import Jump as Jump
from ._brownian import BrownianMotion as BrownianMotion
from ._diffusion import Diffusion as Diffusion
from ._diffusion import diffusion_adjoint_ratio as diffusion_adjoint_ratio
from ._langevin import OverdampedLangevin as OverdampedLangevin
from ._ornstein_uhlenbeck import OrnsteinUhlenbeck as OrnsteinUhlenbeck
from ._unadjusted_jump import UnadjustedJump as UnadjustedJump
