"""The interface of transfer kernels: where the next tour starts, given where the last one ended."""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
from jaxtyping import Array, Float, PRNGKeyArray

from ..regeneration import AbstractRegeneration


class AbstractTransfer(eqx.Module):
    """A transfer kernel `mu(x_exit, dy)` that leaves a *reference* density `q` invariant.

    When a tour is killed at `x_exit`, the next tour starts at a draw of
    `mu(x_exit, .)`. A Restore process with pi-invariant local dynamics is exactly
    pi-invariant when its kill rate is `gamma = c_tilde q / p` and `q` is invariant under
    the transfer (`∫ q(x) mu(x, y) dx = q(y)`); an independent transfer (`mu(x, .) = nu`)
    is the special case `q = u`, and only then may the local dynamics be non-invariant
    (`gamma = L* p / p + c_tilde u / p`). See the theory page for why the rate
    `(L* p + c mu* p) / p` is *not* enough once the transfer depends on `x_exit`.

    Attributes:
        reference: the invariant reference distribution `q` (an exact sampler with a
            normalised log density): the kill rate uses its density, and pilot
            estimates of `Z` draw from it.
        is_independent: the transfer ignores the exit point (tours are i.i.d., lanes
            are regenerative from their first tour).
    """

    reference: eqx.AbstractVar[AbstractRegeneration]
    is_independent: ClassVar[bool] = False

    @property
    def dim(self) -> int:
        return self.reference.dim

    @abc.abstractmethod
    def sample(self, key: PRNGKeyArray, exit_position: Float[Array, " d"]) -> Float[Array, " d"]:
        """A start point of the next tour, given the exit point of the last one."""


class Independent(AbstractTransfer):
    """Regeneration: every tour starts at an independent draw of `regeneration`.

    Arguments:
        regeneration: any `restore.regeneration` distribution; it is also the reference `q`.
    """

    reference: AbstractRegeneration
    is_independent: ClassVar[bool] = True

    def __init__(self, regeneration: AbstractRegeneration):
        if not isinstance(regeneration, AbstractRegeneration):
            raise TypeError(f"regeneration must be a restore.regeneration distribution, got {type(regeneration).__name__}")
        self.reference = regeneration

    def sample(self, key: PRNGKeyArray, exit_position: Float[Array, " d"]) -> Float[Array, " d"]:
        return self.reference.sample(key).astype(exit_position.dtype)

    def log_transition_density(self, exit_position: Float[Array, " d"], position: Float[Array, " d"]) -> Float[Array, ""]:
        """`log u(y)`, whatever the exit point."""
        return self.reference.log_prob(position)
