"""Light-transport renderers in primary sample space (PSS), in JAX.

A PSS target (`PSSTarget`) maps points `u` of the torus `[0, 1)^D` to a luminance (the
density the renderers sample) and an RGB value; the image is
`I_j = W H ∫ rgb(u) 1{pixel(u) = j} du = W H Z E_p[rgb / lum 1{pixel = j}]` with
`p = lum` and `Z = ∫ lum du`. Renderers share the same small step (`restore.local.KelemenMutation`)
and the same large step (a uniform draw), and run on the core: `pss_logdensity(target)`
is the target as a log density of one point (with the contribution `rgb / lum` as aux),
and the local kernels are `restore.local`'s `TorusMetropolis`, `TorusMALA` and `TorusH2MC`:
- `MetropolisRestore`, `MALARestore` and `H2MCRestore`: the core's `JumpRestore` with a
  uniform regeneration (`UniformTorus`), killed at `c / lum`, splatting onto a film; or
  with a regeneration density `q` learned from the bootstrap paths (`LearnedRegeneration`),
  killed at `c q / lum`.
- `PSSMLT`: Kelemen et al.'s Metropolis light transport with expected-value splatting;
  with `TorusMALA` or `TorusH2MC` as its small step, MALA (Luan et al.) and H2MC (Li et al.).
- `ERPT`: energy redistribution path tracing, in rounds of equal-deposition chains.
- `UniformSampler`: plain PSS path tracing (the sanity baseline).
On a multiplexed target (`targets.mitsuba.MultiplexedBDPT`: `frozen_coordinates`,
`pixel_from_evaluation`) small steps keep the depth and strategy, so `PSSMLT` is MMLT, and
splats take the pixel the tracer found.
`render` runs any of them to a time or evaluation budget and reports each renderer's
diagnostics as a typed record (`RenderStatistics`: `RestoreStatistics`, `PSSMLTStatistics`,
`ERPTStatistics`, `UniformStatistics`); `restore.render` metrics
(`l1`, `mse`, `relative_mse`, `mrse`, `mape`, `variance_across`, `relative_variance`) compare images.
"""

from ._driver import RenderResult as RenderResult
from ._driver import render as render
from ._erpt import ERPT as ERPT
from ._erpt import ERPTStatistics as ERPTStatistics
from ._film import empty_film as empty_film
from ._film import splat as splat
from ._h2mc_restore import H2MCRestore as H2MCRestore
from ._learned_regeneration import LearnedRegeneration as LearnedRegeneration
from ._mala_restore import MALARestore as MALARestore
from ._metrics import l1 as l1
from ._metrics import mape as mape
from ._metrics import mrse as mrse
from ._metrics import mse as mse
from ._metrics import relative_mse as relative_mse
from ._metrics import relative_variance as relative_variance
from ._metrics import variance_across as variance_across
from ._metropolis_restore import MetropolisRestore as MetropolisRestore
from ._pss import EvaluatedPixel as EvaluatedPixel
from ._pss import PSSTarget as PSSTarget
from ._pss import evaluate_points as evaluate_points
from ._pss import pss_logdensity as pss_logdensity
from ._pssmlt import PSSMLT as PSSMLT
from ._pssmlt import PSSMLTStatistics as PSSMLTStatistics
from ._renderer import AbstractRenderer as AbstractRenderer
from ._renderer import RenderStatistics as RenderStatistics
from ._restore_renderer import AbstractPSSRestore as AbstractPSSRestore
from ._restore_renderer import RestoreStatistics as RestoreStatistics
from ._uniform import UniformSampler as UniformSampler
from ._uniform import UniformStatistics as UniformStatistics
