"""Regeneration distributions for Restore samplers.

A Restore sampler kills its local Markov process at rate
`gamma(x) = c_tilde * u(x) / p(x)` and restarts it at an exact draw from the
regeneration distribution with density `u`. Every distribution here is an
`AbstractRegeneration` (an Equinox module) with

- `dim`: the dimension `d`;
- `sample(key, shape=())`: exact draws of shape `(*shape, d)`;
- `log_prob(x)`: the normalised log density of one point `(d,)`, exactly
  `-inf` outside the support; jit/vmap/grad-able.

Available: `Gaussian`, `StudentT`, `UniformBox`, `UniformTorus`, `Mixture`,
and `laplace_mixture` (with `find_modes` / `LaplaceModes` /
`mixture_from_modes`) which builds a mixture of Laplace approximations at the
modes of a target found by multi-start optimisation.
"""

from ._base import AbstractRegeneration as AbstractRegeneration
from ._gaussian import Gaussian as Gaussian
from ._laplace import (
    LaplaceModes as LaplaceModes,
    find_modes as find_modes,
    laplace_mixture as laplace_mixture,
    mixture_from_modes as mixture_from_modes,
)
from ._mixture import Mixture as Mixture
from ._student_t import StudentT as StudentT
from ._uniform import UniformBox as UniformBox, UniformTorus as UniformTorus

__all__ = [
    "AbstractRegeneration",
    "Gaussian",
    "LaplaceModes",
    "Mixture",
    "StudentT",
    "UniformBox",
    "UniformTorus",
    "find_modes",
    "laplace_mixture",
    "mixture_from_modes",
]
