"""NumPyro models as targets: sample a model's posterior with Restore, read it back by name.

`NumPyroTarget(model, *args, **kwargs)` turns a NumPyro model and its data into a log
density on the unconstrained space (Jacobians included, via NumPyro's own
`numpyro.infer.util`), with the transforms of draws back to the constrained parameters,
observables by parameter name, and a Student-t covering the prior for
`restore.autosample(..., prior=target.prior())`. Two classic models come with their real
data: `eight_schools` with `EIGHT_SCHOOLS`, and `normal_mixture` (label switching) with
`OLD_FAITHFUL_ERUPTIONS`. Needs the `numpyro` extra: `pip install 'restore-mcmc[numpyro]'`.
"""

from ._data import EIGHT_SCHOOLS as EIGHT_SCHOOLS
from ._data import OLD_FAITHFUL_ERUPTIONS as OLD_FAITHFUL_ERUPTIONS
from ._models import eight_schools as eight_schools
from ._models import normal_mixture as normal_mixture
from ._target import NumPyroTarget as NumPyroTarget
