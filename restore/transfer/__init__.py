"""Transfer kernels: where the next tour of a Restore process starts, given where the last one ended.

When a tour is killed at `x_exit`, the next one starts at a draw of `mu(x_exit, dy)`. A
transfer here leaves a known *reference* density `q` invariant,

    ∫ q(x) mu(x, y) dx = q(y),

and with pi-invariant local dynamics the Restore process is then exactly pi-invariant for
the kill rate `gamma = c_tilde q / p`. Every kernel is an `AbstractTransfer` (an Equinox
module) with

- `reference`: the invariant distribution `q`, a `restore.regeneration` distribution
  (exact draws and a normalised `log_prob`);
- `sample(key, exit_position)`: one start point `(d,)`, under `jit`/`vmap`, in the dtype of
  `exit_position`;
- `is_independent`: whether the kernel ignores the exit point (`mu(x, .) = q`);
- where it exists, `log_transition_density(exit_position, position)`.

Available: `Independent` (regeneration from `q`), `AutoregressiveGaussian` (a partial
refresh leaving a Gaussian invariant), `MetropolisTransfer` (random-walk Metropolis steps
targeting any regeneration distribution, from the exit point), `WrappedGaussianJump` (a
Gaussian jump on the unit torus, leaving the uniform distribution invariant) and
`TransferMixture` (a random choice among kernels sharing one reference).
"""

from ._autoregressive import AutoregressiveGaussian as AutoregressiveGaussian
from ._base import AbstractTransfer as AbstractTransfer
from ._base import Independent as Independent
from ._metropolis import MetropolisTransfer as MetropolisTransfer
from ._mixture import TransferMixture as TransferMixture
from ._wrapped import WrappedGaussianJump as WrappedGaussianJump

__all__ = [
    "AbstractTransfer",
    "AutoregressiveGaussian",
    "Independent",
    "MetropolisTransfer",
    "TransferMixture",
    "WrappedGaussianJump",
]
