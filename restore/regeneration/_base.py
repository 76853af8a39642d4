"""The abstract interface shared by all regeneration distributions."""

from __future__ import annotations

import abc

import equinox as eqx
from jaxtyping import Array, Float, PRNGKeyArray


class AbstractRegeneration(eqx.Module):
    """A regeneration (state-independent transfer) distribution on R^d.

    In a Restore sampler the local process is killed at rate
    `gamma(x) = c_tilde * u(x) / p(x)` and restarted at an exact draw from the
    regeneration distribution with density `u`. Every subclass therefore has to
    provide exact sampling and a normalised log density.

    Concrete subclasses are final: they are not meant to be subclassed further.

    Attributes:
        dim: the dimension `d` of the space the distribution lives on (static).
    """

    dim: eqx.AbstractVar[int]

    @abc.abstractmethod
    def sample(
        self, key: PRNGKeyArray, shape: tuple[int, ...] = ()
    ) -> Float[Array, "*shape d"]:
        """Draw exact, independent samples.

        Arguments:
            key: a JAX PRNG key; the only source of randomness.
            shape: batch shape of the draws. `sample(key)` returns one point of
                shape `(d,)`, `sample(key, (n,))` returns `(n, d)`. An `int` `n`
                is accepted as shorthand for `(n,)`.

        Returns:
            An array of shape `(*shape, d)`.
        """

    @abc.abstractmethod
    def log_prob(self, x: Float[Array, " d"]) -> Float[Array, ""]:
        """Normalised log density of one point.

        Arguments:
            x: a single point of shape `(d,)`; use `jax.vmap` for batches.

        Returns:
            The log density w.r.t. Lebesgue measure as a scalar; exactly `-inf`
            outside the support. Works under `jit`, `vmap` and `grad`.
        """
