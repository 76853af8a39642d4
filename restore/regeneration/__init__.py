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
`DiagonalMixture` (axis-aligned components, `O(K d)` per evaluation),
`ConditionalGaussian` (each coordinate Gaussian given the earlier ones: curved targets),
`ProductMixture` (a product of one-dimensional mixtures), `TorusKernelMixture`
(uniform on the torus mixed with kernels around learned centres: light transport), `RotatedProductMixture`
(the same along other directions, found by `independent_axes`), and `laplace_mixture`
(with `find_modes` / `LaplaceModes` / `mixture_from_modes`) which builds a
mixture of Laplace approximations at the modes of a target found by multi-start
optimisation. `fit_mixture`, `fit_product`, `fit_rotated_product`, `fit_conditional` and `choose_regeneration` fit
regenerations to weighted draws of the target (what `restore.autosample` does
in stages).
"""

from ._base import AbstractRegeneration as AbstractRegeneration
from ._choose import Candidate as Candidate
from ._choose import Choice as Choice
from ._choose import choose_regeneration as choose_regeneration
from ._conditional import ConditionalGaussian as ConditionalGaussian
from ._conditional_fit import fit_conditional as fit_conditional
from ._diagonal_mixture import DiagonalMixture as DiagonalMixture
from ._fit import Fit as Fit
from ._fit import fit_mixture as fit_mixture
from ._fit import fit_product as fit_product
from ._fit import fit_rotated_product as fit_rotated_product
from ._gaussian import Gaussian as Gaussian
from ._independent_axes import IndependentAxes as IndependentAxes
from ._independent_axes import independent_axes as independent_axes
from ._laplace import (
    LaplaceModes as LaplaceModes,
)
from ._laplace import (
    find_modes as find_modes,
)
from ._laplace import (
    laplace_mixture as laplace_mixture,
)
from ._laplace import (
    mixture_from_modes as mixture_from_modes,
)
from ._mixture import Mixture as Mixture
from ._product_mixture import ProductMixture as ProductMixture
from ._rotated_product import RotatedProductMixture as RotatedProductMixture
from ._student_t import StudentT as StudentT
from ._torus_kernels import TorusKernelMixture as TorusKernelMixture
from ._uniform import UniformBox as UniformBox
from ._uniform import UniformTorus as UniformTorus

__all__ = [
    "AbstractRegeneration",
    "Candidate",
    "Choice",
    "ConditionalGaussian",
    "DiagonalMixture",
    "Fit",
    "Gaussian",
    "IndependentAxes",
    "LaplaceModes",
    "Mixture",
    "ProductMixture",
    "RotatedProductMixture",
    "StudentT",
    "TorusKernelMixture",
    "UniformBox",
    "UniformTorus",
    "choose_regeneration",
    "find_modes",
    "fit_conditional",
    "fit_mixture",
    "fit_product",
    "fit_rotated_product",
    "independent_axes",
    "laplace_mixture",
    "mixture_from_modes",
]
