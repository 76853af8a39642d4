"""H2MC on the torus: Metropolis-Hastings with the anisotropic Gaussian of Hessian-Hamiltonian dynamics.

Li et al. (2015) propose a light-transport move from the second-order expansion of
`log f` at the current path, `log f(x + d) ~ log f(x) + g.d + d.H.d / 2`: Hamiltonian
dynamics with unit mass in that quadratic potential, started with momentum `p ~ N(0, I)`,
move `x` by an affine function of `p`, so the move is Gaussian. In the eigenbasis of
`H` (eigenvalue `lam`, gradient component `g`), run for the angle `T` (`sqrt|lam| t = T`):

- `lam < 0` (the luminance peaks): `d = g (1 - cos T) / |lam| + p sin T / sqrt|lam|`;
- `lam > 0` (a valley): `d = g (cosh T - 1) / lam + p sinh T / sqrt(lam)`;
- `lam ~ 0`: time `T` of free flight, `d = g T^2 / 2 + p T`.

That Gaussian, `N(m_i, v_i)` per direction, is then multiplied by an isotropic prior
`N(0, sigma^2)` on the move, which bounds every step by `sigma`: the proposal has
precision `1 / v_i + 1 / sigma^2` and mean `(m_i / v_i) / precision` per direction.
The authors' settings are `T = pi / 2` and `sigma = 0.01` in primary sample space.

The move depends on the state through `g` and `H`, so the Hastings ratio needs the
reverse move's Gaussian, built at the candidate (its gradient and Hessian). Leaving it
out breaks invariance (the negative control of the tests).

The Hessian comes from forward differences of the exact gradients: the light-transport
log densities of this library differentiate once, by a custom VJP, and so have no second
derivative from JAX. The differences only shape the proposal, which the Hastings test
makes exact whatever it is. Each point's Gaussian is built once, when the point is
evaluated (`evaluate_point`: its value and gradient and the `dim` gradients of the
differences in one batch), and kept with it (`Point.geometry`): it is the reverse move's
Gaussian while the point is a candidate and the forward one's for every move from it,
as Li et al. keep the current path's derivatives across rejected moves.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, ClassVar, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, PRNGKeyArray

from .._point import Point, evaluate
from ._base import AbstractLocalKernel, LocalInfo, gradient_of, metropolis_accept
from ._torus import wrap

#: The largest `sigma`: the proposal's standard deviations are at most `sigma`, so any
#: periodic image but the nearest lies at least 1/2 away in some coordinate, a relative
#: weight below `exp(-1 / (8 sigma^2)) = exp(-50)`: the nearest-image density is exact.
MAX_SIGMA = 0.05
#: Eigenvalues of a smaller magnitude count as flat directions (free flight).
_FLAT = 1e-8


class H2MCGaussian(NamedTuple):
    """The proposal's Gaussian for moves `d`: in the orthonormal `basis` (columns), per
    direction a `mean` and a `precision`."""

    basis: Float[Array, "d d"]
    mean: Float[Array, " d"]
    precision: Float[Array, " d"]

    def sample(self, key: PRNGKeyArray) -> Float[Array, " d"]:
        """A move `d`."""
        z = jax.random.normal(key, self.mean.shape, self.mean.dtype)
        return self.basis @ (self.mean + z / jnp.sqrt(self.precision))

    def mean_move(self) -> Float[Array, " d"]:
        return self.basis @ self.mean

    def log_density(self, move: Float[Array, " d"]) -> Float[Array, ""]:
        """`log N(move)` up to the constant `-d log(2 pi) / 2`, the same for every Gaussian."""
        r = self.basis.T @ move - self.mean
        return 0.5 * jnp.sum(jnp.log(self.precision) - self.precision * r**2)


def h2mc_gaussian(
    grad: Float[Array, " d"], hessian: Float[Array, "d d"], sigma: float, angle: float = math.pi / 2
) -> H2MCGaussian:
    """The H2MC proposal at a point with gradient `grad` and Hessian `hessian` of `log f` (module docstring).

    A gradient or Hessian that is not finite, or a proposal that would not be (an overflow),
    gives the prior alone, `N(0, sigma^2 I)`: a function of the state all the same, so the
    Hastings test stays exact.
    """
    dtype = grad.dtype
    finite = jnp.all(jnp.isfinite(grad)) & jnp.all(jnp.isfinite(hessian))
    hessian = jnp.where(finite, 0.5 * (hessian + hessian.T), 0.0)
    size = jnp.max(jnp.abs(hessian))
    size = jnp.where(size > 0, size, 1.0)
    lam, basis = jnp.linalg.eigh(hessian / size)  # scaled: no overflow inside the decomposition
    lam = lam * size
    g = basis.T @ jnp.where(finite, grad, 0.0)
    curved, peak = jnp.abs(lam) > _FLAT, lam < 0
    # per direction, the dynamics' variance v = |lam|^-1 sin^2 T (peak), |lam|^-1 sinh^2 T
    # (valley), T^2 (flat), and the mean over the variance, m / v = g * shift / spread
    spread = jnp.where(peak, math.sin(angle) ** 2, math.sinh(angle) ** 2)
    shift = jnp.where(peak, 1.0 - math.cos(angle), math.cosh(angle) - 1.0)
    inverse_variance = jnp.where(curved, jnp.abs(lam) / spread, 1.0 / angle**2)
    mean_over_variance = g * jnp.where(curved, shift / spread, 0.5)
    precision = inverse_variance + 1.0 / sigma**2
    mean = mean_over_variance / precision
    usable = finite & jnp.all(jnp.isfinite(basis)) & jnp.all(jnp.isfinite(mean)) & jnp.all(jnp.isfinite(precision))
    prior = jnp.full_like(precision, 1.0 / sigma**2)
    return H2MCGaussian(
        jnp.where(usable, basis, jnp.eye(grad.shape[0], dtype=basis.dtype)).astype(dtype),
        jnp.where(usable, mean, 0.0).astype(dtype),
        jnp.where(usable, precision, prior).astype(dtype),
    )


def _centred(v: Array) -> Array:
    """`v` moved by whole numbers into `[-1/2, 1/2]`: the nearest periodic image."""
    return v - jnp.round(v)


class TorusH2MC(AbstractLocalKernel):
    """H2MC (Li et al. 2015) on the torus: anisotropic Gaussian moves from the gradient and Hessian.

    From `u` the move is drawn from the Gaussian of Hessian-Hamiltonian dynamics for the
    angle `T` (module docstring), bounded by an isotropic `N(0, sigma^2)`, and wrapped
    into `[0, 1)`; it is accepted with the Hastings ratio of the forward and reverse
    Gaussians (each at its own end), with the nearest periodic image, exact for
    `sigma <= 0.05`. The Hessian is forward differences of the exact gradients, step
    `difference`: evaluating a point (`evaluate_point`, which samplers call for every
    point) takes `dim + 1` gradients in one batch, where `TorusMALA` takes one, and the
    point keeps its Gaussian (`Point.geometry`) for every move from it.

    Arguments:
        sigma: the bound on each step, in `(0, 0.05]` (default 0.01, as its authors run it).
        angle: `T`, in `(0, pi)` (default `pi / 2`, as its authors run it).
        difference: the step of the Hessian's differences, in `(0, 0.01]` (default 1e-3).
    """

    sigma: float = eqx.field(static=True)
    angle: float = eqx.field(static=True)
    difference: float = eqx.field(static=True)
    uses_gradient: ClassVar[bool] = True
    keeps_geometry: ClassVar[bool] = True

    def __init__(self, sigma: float = 0.01, angle: float = math.pi / 2, difference: float = 1e-3):
        sigma, angle, difference = float(sigma), float(angle), float(difference)
        if not (math.isfinite(sigma) and 0 < sigma <= MAX_SIGMA):
            raise ValueError(f"TorusH2MC sigma must lie in (0, {MAX_SIGMA}], got {sigma!r}")
        if not (math.isfinite(angle) and 0 < angle < math.pi):
            raise ValueError(f"TorusH2MC angle must lie in (0, pi), got {angle!r}")
        if not (math.isfinite(difference) and 0 < difference <= 0.01):
            raise ValueError(f"TorusH2MC difference must lie in (0, 0.01], got {difference!r}")
        self.sigma, self.angle, self.difference = sigma, angle, difference

    def gaussian(self, grad_fn: Callable[[Array], Array], u: Float[Array, " d"], grad: Float[Array, " d"]) -> H2MCGaussian:
        """The proposal's Gaussian at `u` (gradient `grad`; `grad_fn` gives the gradient anywhere)."""
        return self._from_gradients(grad, jax.vmap(grad_fn)(self._probes(u)))

    def evaluate_point(
        self, logdensity_fn: Callable[[Array], Any], position: Array, has_aux: bool = False
    ) -> tuple[Point, Bool[Array, ""]]:
        """The point at `position` with its value, gradient and proposal Gaussian (`geometry`):
        the point and the `dim` points of the Hessian's differences in one batch of gradients."""
        rows, invalid = jax.vmap(lambda x: evaluate(logdensity_fn, x, True, has_aux))(
            jnp.concatenate([position[None], self._probes(position)])
        )
        point = jax.tree.map(lambda a: a[0], rows)
        assert rows.grad is not None and point.grad is not None
        return point._replace(geometry=self._from_gradients(point.grad, rows.grad[1:])), invalid[0]

    def _probes(self, u: Float[Array, " d"]) -> Float[Array, "d d"]:
        """Row `j`: `u` a step `difference` along axis `j`, on the torus."""
        return wrap(u + self.difference * jnp.eye(u.shape[0], dtype=u.dtype))

    def _from_gradients(self, grad: Float[Array, " d"], columns: Float[Array, "d d"]) -> H2MCGaussian:
        """The Gaussian from the gradient at `u` and those at `_probes(u)` (row `j`: a step along axis `j`)."""
        return h2mc_gaussian(grad, (columns - grad).T / self.difference, self.sigma, self.angle)

    def propose(
        self, key: PRNGKeyArray, point: Point, logdensity_fn: Callable[[Array], Array] | None = None
    ) -> tuple[Array, Array]:
        """The candidate and the forward move's `log q(u -> candidate)` (`accept` adds the
        reverse move's, from the Gaussian the candidate's evaluation built).

        Uses the point's own Gaussian (`Point.geometry`); a point evaluated without it gets
        one built here, from `logdensity_fn`'s gradients."""
        u = point.position
        forward = point.geometry
        if forward is None:
            if logdensity_fn is None:
                raise ValueError("TorusH2MC needs the log density (its Hessian comes from differences of its gradient)")
            forward = self.gaussian(jax.grad(logdensity_fn), u, gradient_of(point))
        candidate = wrap(u + forward.sample(key))
        log_forward = forward.log_density(forward.mean_move() + _centred(candidate - u - forward.mean_move()))
        return candidate, log_forward

    def accept(self, key: PRNGKeyArray, point: Point, candidate: Point, aux: Array) -> tuple[Point, LocalInfo]:
        """Accept with `f(candidate) q(candidate -> u) / (f(u) q(u -> candidate))`, the reverse move's
        Gaussian the candidate's own (`Point.geometry`, built by `evaluate_point`)."""
        backward = candidate.geometry
        if backward is None:
            raise ValueError(
                "TorusH2MC needs the candidate's Gaussian: evaluate candidates with its evaluate_point, which keeps it"
            )
        if point.geometry is None:  # a point evaluated without its Gaussian: the lane keeps none
            candidate = candidate._replace(geometry=None)
        u, y = point.position, candidate.position
        log_backward = backward.log_density(backward.mean_move() + _centred(u - y - backward.mean_move()))
        return metropolis_accept(key, point, candidate, candidate.logdensity - point.logdensity + log_backward - aux)
