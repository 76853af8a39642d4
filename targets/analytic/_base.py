"""Abstract interfaces of the analytic targets: `AbstractTarget` and `AbstractMixture`."""

from __future__ import annotations

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.scipy.special import logsumexp
from jaxtyping import Array, ArrayLike, Float, Int, PRNGKeyArray

from . import _checks


class AbstractTarget(eqx.Module):
    """A probability density on R^d with exact samples and exact reference quantities.

    Targets are used to test samplers: `logdensity` is what a sampler sees, while
    `sample`, `mean`, `covariance` and `marginal_cdf` are the exact answers its
    output is compared against. Concrete subclasses are final.

    Attributes:
        dim: the dimension `d` of the space (static).
    """

    dim: eqx.AbstractVar[int]

    @abc.abstractmethod
    def logdensity(self, x: Float[Array, " d"]) -> Float[Array, ""]:
        """Log density of one point: normalised (it integrates to one) unless
        `log_normalising_constant` says otherwise.

        Arguments:
            x: a single point of shape `(d,)`; use `jax.vmap` for batches.

        Returns:
            A scalar. Works under `jit`, `vmap` and `grad`; never NaN for finite `x`.
        """

    @property
    def log_normalising_constant(self) -> float:
        """The exact `log Z = log ∫ exp(logdensity(x)) dx`: 0 for a normalised target.

        Targets given in an unnormalised form from the literature (e.g. `ManyWell`) report
        their exact, non-zero value here.
        """
        return 0.0

    def sample(self, key: PRNGKeyArray, n: int) -> Float[Array, "n d"]:
        """Exact, independent draws (compiled with `eqx.filter_jit`).

        Arguments:
            key: a JAX PRNG key, the only source of randomness.
            n: the number of draws (a Python integer: it fixes the output shape).

        Returns:
            An array of shape `(n, d)`.
        """
        return _sample_jit(self, key, _checks.sample_count(n))

    @abc.abstractmethod
    def _sample(self, key: PRNGKeyArray, n: int) -> Float[Array, "n d"]:
        """`sample` without input checks or compilation; `n` is a validated `int`."""

    @property
    @abc.abstractmethod
    def mean(self) -> Float[Array, " d"]:
        """The exact mean vector, shape `(d,)`."""

    @property
    @abc.abstractmethod
    def covariance(self) -> Float[Array, "d d"]:
        """The exact covariance matrix, shape `(d, d)`."""

    def marginal_cdf(self, i: int, t: ArrayLike) -> Float[Array, ...]:
        """Exact CDF of coordinate `i`, evaluated elementwise at `t`.

        Arguments:
            i: the coordinate, a Python integer in `[0, d)`.
            t: where to evaluate the CDF; any shape.

        Raises:
            ValueError: for a coordinate outside `[0, d)`.
            NotImplementedError: where the marginal has no closed form.
        """
        i = _checks.coordinate(i, self.dim)
        return _marginal_cdf_jit(self, i, _checks.float_array(t, "t"))

    @abc.abstractmethod
    def _marginal_cdf(self, i: int, t: Float[Array, ...]) -> Float[Array, ...]:
        """`marginal_cdf` for a validated coordinate and a floating-point array `t`."""


class AbstractMixture(AbstractTarget):
    """A finite mixture `sum_k w_k p_k(x)` of densities with known components.

    Subclasses provide the per-component log densities, marginal CDFs, moments and
    a sampler that also reports which component produced each draw; the mixture
    density, mode assignment, marginal CDF and moments follow from those here.

    Attributes:
        weights: the normalised mixture weights, shape `(k,)`.
    """

    weights: eqx.AbstractVar[Float[Array, " k"]]

    @property
    def num_modes(self) -> int:
        """The number of components `k`."""
        return self.weights.shape[0]

    @abc.abstractmethod
    def component_logdensities(self, x: Float[Array, " d"]) -> Float[Array, " k"]:
        """Normalised log density `log p_k(x)` of every component at one point."""

    @abc.abstractmethod
    def component_marginal_cdfs(self, i: int, t: Float[Array, "*t"]) -> Float[Array, "*t k"]:
        """CDF of coordinate `i` under every component, stacked on a new last axis."""

    @property
    @abc.abstractmethod
    def component_means(self) -> Float[Array, "k d"]:
        """Mean of every component."""

    @property
    @abc.abstractmethod
    def component_covariances(self) -> Float[Array, "k d d"]:
        """Covariance of every component."""

    def sample_with_modes(
        self, key: PRNGKeyArray, n: int
    ) -> tuple[Float[Array, "n d"], Int[Array, " n"]]:
        """Exact draws together with the index of the component each came from.

        Arguments:
            key: a JAX PRNG key.
            n: the number of draws (a Python integer).

        Returns:
            `(x, modes)` with shapes `(n, d)` and `(n,)`; `x` equals `sample(key, n)`.
        """
        return _sample_with_modes_jit(self, key, _checks.sample_count(n))

    @abc.abstractmethod
    def _sample_with_modes(
        self, key: PRNGKeyArray, n: int
    ) -> tuple[Float[Array, "n d"], Int[Array, " n"]]:
        """`sample_with_modes` without input checks or compilation."""

    def _joint_logdensities(self, x: Float[Array, " d"]) -> Float[Array, " k"]:
        x = _checks.point(x, self.dim)
        return jnp.log(self.weights) + self.component_logdensities(x)

    def logdensity(self, x: Float[Array, " d"]) -> Float[Array, ""]:
        return logsumexp(self._joint_logdensities(x))

    def responsibilities(self, x: Float[Array, " d"]) -> Float[Array, " k"]:
        """Posterior component probabilities `w_k p_k(x) / p(x)` at one point."""
        return jax.nn.softmax(self._joint_logdensities(x))

    def assign_mode(self, x: Float[Array, " d"]) -> Int[Array, ""]:
        """Index of the component with the highest `log w_k + log p_k(x)` at one point.

        Arguments:
            x: a single point of shape `(d,)`; `jax.vmap` for batches.
        """
        return jnp.argmax(self._joint_logdensities(x))

    def _sample(self, key: PRNGKeyArray, n: int) -> Float[Array, "n d"]:
        return self._sample_with_modes(key, n)[0]

    def _marginal_cdf(self, i: int, t: Float[Array, ...]) -> Float[Array, ...]:
        t = t.astype(jnp.result_type(t, self.weights))
        return self.component_marginal_cdfs(i, t) @ self.weights

    @property
    def mean(self) -> Float[Array, " d"]:
        return self.weights @ self.component_means

    @property
    def covariance(self) -> Float[Array, "d d"]:
        # Law of total variance, with the between-component term centred first.
        centred = self.component_means - self.mean
        within = jnp.einsum("k,kij->ij", self.weights, self.component_covariances)
        between = jnp.einsum("k,ki,kj->ij", self.weights, centred, centred)
        return within + between


@eqx.filter_jit
def _sample_jit(target: AbstractTarget, key: PRNGKeyArray, n: int) -> Array:
    return target._sample(key, n)


@eqx.filter_jit
def _sample_with_modes_jit(
    target: AbstractMixture, key: PRNGKeyArray, n: int
) -> tuple[Array, Array]:
    return target._sample_with_modes(key, n)


@eqx.filter_jit
def _marginal_cdf_jit(target: AbstractTarget, i: int, t: Array) -> Array:
    return target._marginal_cdf(i, t)
