"""Analytic test densities with exact samplers and exact reference quantities.

Every target provides a `logdensity` (jit/vmap/grad-able) with its exact
`log_normalising_constant` (0 for all but `ManyWell`, which keeps the literature's
unnormalised form), exact independent draws (`sample`), the exact `mean` and
`covariance`, and exact marginal CDFs where a closed form exists. Mixtures
additionally report the component a point most likely came from (`assign_mode`).
"""

from ._banana import Banana as Banana
from ._base import AbstractMixture as AbstractMixture
from ._base import AbstractTarget as AbstractTarget
from ._builders import (
    spread_gaussian_mixture as spread_gaussian_mixture,
)
from ._builders import (
    well_separated_gaussian_mixture as well_separated_gaussian_mixture,
)
from ._builders import (
    well_separated_student_t_mixture as well_separated_student_t_mixture,
)
from ._funnel import Funnel as Funnel
from ._gaussian_mixture import GaussianMixture as GaussianMixture
from ._many_well import ManyWell as ManyWell
from ._pss_image import AnalyticImage as AnalyticImage
from ._ring import Ring as Ring
from ._rotated import Rotated as Rotated
from ._rotated import random_rotation as random_rotation
from ._student_t_mixture import StudentTMixture as StudentTMixture
