"""Mixtures of transfer kernels that share one invariant reference."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Protocol, cast, final

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from .._validation import as_float_array, check_point, is_concrete
from ..regeneration import AbstractRegeneration
from ._base import AbstractTransfer


class _WithDensity(Protocol):
    """A transfer that has a transition density (not every `AbstractTransfer` does)."""

    def log_transition_density(self, exit_position: Float[Array, " d"], position: Float[Array, " d"]) -> Float[Array, ""]: ...


@final
class TransferMixture(AbstractTransfer):
    """Pick a component transfer with probability `w_k`, then draw from it.

    If every component leaves the same reference `q` invariant so does the mixture
    `sum_k w_k mu_k(x, dy)`. Components leaving *different* densities invariant are
    rejected: their mixture leaves, in general, neither invariant. Mixing an
    exit-dependent kernel with independent regeneration keeps local moves near the exit
    point and makes every tour start afresh with probability `w` of the independent part:

        m, S = jnp.zeros(2), jnp.eye(2)
        transfer = TransferMixture(
            [AutoregressiveGaussian(m, S, 0.9), Independent(Gaussian(m, S))],
            weights=[0.8, 0.2],
        )

    Arguments:
        components: a non-empty sequence of `AbstractTransfer`s whose references are
            equal (`equinox.tree_equal`: same class, dtypes and values, so build them
            from the same arrays).
        weights: positive, unnormalised probabilities of the components, shape `(k,)`;
            `None` means equal weights.

    Raises:
        TypeError: if a component is not an `AbstractTransfer`.
        ValueError: for no components, components with different references, or weights
            that are not finite and positive or not one per component.
    """

    components: tuple[AbstractTransfer, ...]
    log_weights: Float[Array, " k"]
    reference: AbstractRegeneration

    def __init__(self, components: Sequence[AbstractTransfer], weights: ArrayLike | None = None):
        components = tuple(components)
        if not components:
            raise ValueError("TransferMixture needs at least one component")
        for i, c in enumerate(components):
            if not isinstance(c, AbstractTransfer):
                raise TypeError(f"component {i} is a {type(c).__name__}, not a restore.transfer transfer kernel")
        reference = components[0].reference
        for i, c in enumerate(components[1:], start=1):
            if c.dim != reference.dim:
                raise ValueError(f"component {i} has dimension {c.dim} but component 0 has dimension {reference.dim}")
            same = eqx.tree_equal(c.reference, reference)
            if is_concrete(same) and not bool(same):
                raise ValueError(
                    f"component {i}'s reference ({type(c.reference).__name__}) differs from component 0's "
                    f"({type(reference).__name__}): a mixture of kernels leaving different densities invariant "
                    "leaves neither invariant; build all components from the same reference parameters"
                )
        k = len(components)
        if weights is None:
            log_weights = jnp.full((k,), -math.log(k), jnp.result_type(float))
        else:
            weights = as_float_array(weights)
            if weights.shape != (k,):
                raise ValueError(f"weights must have shape ({k},), one per component, got shape {weights.shape}")
            if is_concrete(weights):
                w = np.asarray(weights, dtype=np.float64)
                if not (np.all(np.isfinite(w)) and np.all(w > 0)):
                    raise ValueError(f"weights must be finite and strictly positive, got {w}")
            log_weights = jnp.log(weights) - jnp.log(jnp.sum(weights))
        self.components = components
        self.log_weights = log_weights
        self.reference = reference

    @property
    def is_independent(self) -> bool:  # type: ignore[override]  # the ClassVar is never set, so a property may replace it
        """True only if every component ignores the exit point."""
        return all(c.is_independent for c in self.components)

    @property
    def weights(self) -> Float[Array, " k"]:
        """The normalised component probabilities."""
        return jnp.exp(self.log_weights)

    def sample(self, key: PRNGKeyArray, exit_position: Float[Array, " d"]) -> Float[Array, " d"]:
        """A draw of a component chosen with probabilities `weights`, in the dtype of `exit_position`."""
        x = check_point(exit_position, self.dim, "exit_position")
        key_pick, key_draw = jax.random.split(key)
        if len(self.components) == 1:
            return self.components[0].sample(key_draw, x).astype(x.dtype)
        index = jax.random.categorical(key_pick, self.log_weights)
        branches = [lambda k, p, c=c: c.sample(k, p).astype(x.dtype) for c in self.components]
        return jax.lax.switch(index, branches, key_draw, x)

    def log_transition_density(
        self, exit_position: Float[Array, " d"], position: Float[Array, " d"]
    ) -> Float[Array, ""]:
        """`log sum_k w_k mu_k(x_exit, y)`; every component must have a `log_transition_density`.

        Raises:
            NotImplementedError: if a component has none (e.g. `MetropolisTransfer`, whose
                kernel has an atom at the exit point).
        """
        missing = [type(c).__name__ for c in self.components if not hasattr(c, "log_transition_density")]
        if missing:
            raise NotImplementedError(f"components {missing} have no transition density, so neither has the mixture")
        densities = cast(tuple[_WithDensity, ...], self.components)  # none is missing (checked above)
        terms = jnp.stack([c.log_transition_density(exit_position, position) for c in densities])
        return jax.scipy.special.logsumexp(self.log_weights + terms)
