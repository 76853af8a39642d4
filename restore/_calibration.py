"""Calibration: a Restore sampler given a mean tour length gets its kill-rate constant from a pilot.

The kill rate `gamma = c_tilde u / p` needs `c_tilde = Z / T` for a mean tour duration `T`,
and `Z` is what the run is for. A sampler built with a `tour_length` is therefore
calibrated before it runs: `AbstractRestore.calibrate` estimates `Z` by importance sampling
from the regeneration (the pilot) and sets `log_rate`. These functions are what the run
driver knows of it, so the sampler contract (`AbstractSampler`) carries no calibration
method: samplers that need none (a given `log_rate`, `MixtureMH`, any sampler of the user's)
pass through unchanged.
"""

from __future__ import annotations

from jaxtyping import PRNGKeyArray

from ._rate import PilotEstimate
from ._restore import AbstractRestore
from ._sampler import AbstractSampler


def needs_calibration(sampler: AbstractSampler) -> bool:
    """Whether `sampler` has a `tour_length` and no `log_rate` yet (it cannot step before `calibrate`)."""
    return isinstance(sampler, AbstractRestore) and sampler.log_rate is None and sampler.tour_length is not None


def calibrate(sampler: AbstractSampler, key: PRNGKeyArray) -> tuple[AbstractSampler, PilotEstimate | None]:
    """`sampler` ready to run, and the pilot that calibrated it (`None` when it needed none)."""
    if not needs_calibration(sampler):
        return sampler, None
    assert isinstance(sampler, AbstractRestore)  # (`needs_calibration` said so)
    return sampler.calibrate(key)


def calibrated_like(sampler: AbstractSampler) -> AbstractSampler:
    """A sampler of the structure `calibrate` will return (array shapes, dtypes and static
    fields), with `log Z = 0` in place of the pilot's estimate: the run's programs are
    compiled from it while the pilot runs (`restore._ahead`)."""
    if not needs_calibration(sampler):
        return sampler
    assert isinstance(sampler, AbstractRestore)
    return sampler.calibrated_to(0.0)
