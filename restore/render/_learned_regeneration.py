"""A Restore renderer's regeneration density learned from its bootstrap paths."""

from __future__ import annotations

import equinox as eqx
from jaxtyping import Array, Float, PRNGKeyArray

from ..regeneration import TorusKernelMixture
from ._renderer import check_count, resample


class LearnedRegeneration(eqx.Module):
    """Regenerate from a kernel mixture fitted to the bootstrap paths, kept defensive with the uniform.

    With uniform regeneration a tour is killed at rate `c / lum`, so a tour that starts
    on a path much brighter than average (a caustic) lasts about `lum / c` events: on the
    pool scene a few hundred such tours last thousands of events and carry much of the
    light, and the render has to finish them. Regenerating from a density `q` that is large
    where the light is kills at `c q / lum` instead: tours on bright paths end sooner, and
    more tours start there. Any `q` that is positive everywhere keeps the image exact
    (a tour's expected splats are `(1 / c) ∫ lum h`, whatever `q`), so `q` only changes the
    noise and the tour lengths.

    The fit: `components` centres drawn from the bootstrap's uniform paths with
    probability proportional to their luminance, each the centre of a wrapped, truncated
    Gaussian kernel of standard deviation `bandwidth` in every coordinate; a share
    `uniform_share` of the regenerations stays uniform, so bright regions the bootstrap
    missed are still killed at no less than `uniform_share` of the uniform rate
    (`restore.regeneration.TorusKernelMixture`). It costs no evaluation: the bootstrap
    is made anyway (for `Z_hat`), but every event evaluates `q` at its state, `O(K D)`.

    What it does in practice (`docs/rendering.md`, "A regeneration learned from the
    bootstrap"): on the pool scene it cuts the tail of the tour durations (`k_hat` from
    1.4-2.0 to 0.6-0.8) and the error per evaluation, but in 32 dimensions evaluating `q`
    costs more than a path on a 2-core CPU, so at equal time it renders worse than the
    uniform regeneration there. It is an option, not the default.

    Attributes:
        components: kernel centres drawn from the bootstrap.
        bandwidth: the kernels' standard deviation per coordinate of the torus, in `(0, 1/2]`.
        uniform_share: the probability of a uniform regeneration, in `(0, 1)`.
    """

    components: int = eqx.field(static=True, default=64)
    bandwidth: float = eqx.field(static=True, default=0.05)
    uniform_share: float = eqx.field(static=True, default=0.8)

    def __check_init__(self):
        check_count(self.components, "components")
        if not (isinstance(self.bandwidth, (int, float)) and 0 < self.bandwidth <= 0.5):
            raise ValueError(f"bandwidth must be in (0, 1/2], got {self.bandwidth!r}")
        if not (isinstance(self.uniform_share, (int, float)) and 0 < self.uniform_share < 1):
            raise ValueError(f"uniform_share must be in (0, 1), got {self.uniform_share!r}")

    def fit(self, key: PRNGKeyArray, positions: Float[Array, "B D"], luminance: Float[Array, " B"]) -> Float[Array, "K D"]:
        """The kernel centres: `components` bootstrap paths drawn with probability proportional to luminance."""
        return positions[resample(key, luminance, self.components)]

    def distribution(self, centres: Float[Array, "K D"]) -> TorusKernelMixture:
        """The regeneration density with these centres."""
        return TorusKernelMixture(centres, self.bandwidth, self.uniform_share)
