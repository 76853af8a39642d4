"""A ring (spherical shell) of mass around the origin."""

from __future__ import annotations

import math
from types import ModuleType
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.special as jsp
import numpy as np
import scipy.special as ssp
from jax.scipy.special import log_ndtr
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from . import _checks
from ._base import AbstractTarget
from ._special import safe_norm, standard_normal


def log_radial_tail(
    t: Any, m: int, radius: float, width: float, xp: ModuleType, special: ModuleType
) -> Any:
    """`log K_m(t)` with `K_m(t) = int_t^inf rho^m exp(-(rho - r)^2 / (2 w^2)) d rho`, `t >= 0`.

    Substituting `rho = r + w u` and expanding `(r + w u)^m` binomially gives
    `K_m(t) = sum_j C(m, j) r^(m-j) w^(j+1) J_j(a)` with `a = (t - r) / w` and
    `J_j(a) = int_a^inf u^j exp(-u^2 / 2) du = 2^((j-1)/2) Gamma((j+1)/2) F_j(a)`, where
    `F_j = Q((j+1)/2, a^2/2)` (regularised upper incomplete gamma) except for even
    `j` and `a < 0`, where `F_j = 2 - Q((j+1)/2, a^2/2)`. At half-integers `Q` is a
    finite sum, `Q(s, h) = Q(s0, h) + sum_{0 < i < s - s0} h^(s-i) e^(-h) / Gamma(s-i+1)`,
    started from `Q(1/2, h) = erfc(sqrt h)` or `Q(1, h) = e^(-h)`: cumulative
    log-sum-exps along the two parity chains. Every term of every sum is positive,
    so nothing cancels.

    Arguments:
        t: lower limit(s), non-negative, any shape.
        m: the power of `rho`, a non-negative Python integer (`d - 1` for the normaliser).
        radius, width: the ring's `r >= 0` and `w > 0` (Python floats).
        xp, special: `numpy` and `scipy.special` (construction-time constants in
            float64), or `jax.numpy` and `jax.scipy.special` (traceable).
    """
    cumlogsumexp = np.logaddexp.accumulate if xp is np else jax.lax.cumlogsumexp
    a = ((xp.asarray(t) - radius) / width)[..., None]
    h = 0.5 * a * a
    log_h = xp.log(h)
    j = np.arange(m + 1)
    s = 0.5 * (j + 1)
    # log of h^(s-1) e^(-h) / Gamma(s), the step from Q(s - 1, h) to Q(s, h), for j >= 2.
    steps = (s[2:] - 1) * log_h - h - ssp.gammaln(s[2:])
    even_start = math.log(2.0) + special.log_ndtr(-xp.abs(a))  # log erfc(sqrt h), j = 0
    odd_start = -h  # j = 1
    last = a.ndim - 1
    log_q_even = cumlogsumexp(xp.concatenate([even_start, steps[..., 0::2]], axis=last), axis=last)
    log_q_odd = cumlogsumexp(xp.concatenate([odd_start, steps[..., 1::2]], axis=last), axis=last)
    log_q_odd = log_q_odd[..., : (m + 1) // 2]  # only j = 1, 3, ... <= m
    log_f_even = xp.where(a < 0, xp.log(2.0 - xp.exp(log_q_even)), log_q_even)
    log_f = xp.concatenate([log_f_even, log_q_odd], axis=-1)
    j = np.concatenate([j[0::2], j[1::2]])  # the order of log_f
    log_coeff = (
        ssp.gammaln(m + 1)
        - ssp.gammaln(j + 1)
        - ssp.gammaln(m - j + 1)
        + (j + 1) * math.log(width)
        + 0.5 * (j - 1) * math.log(2.0)
        + ssp.gammaln(0.5 * (j + 1))
    )
    if radius > 0:
        log_coeff = log_coeff + (m - j) * math.log(radius)
    else:  # r^(m - j) = 0 unless j = m
        log_coeff = np.where(j == m, log_coeff, -np.inf)
    log_coeff = xp.asarray(log_coeff, dtype=a.dtype)
    return special.logsumexp(log_coeff + log_f, axis=-1)


def _log_tail_np(t: float, m: int, radius: float, width: float) -> float:
    with np.errstate(divide="ignore"):
        return float(log_radial_tail(np.float64(t), m, radius, width, np, ssp))


class Ring(AbstractTarget):
    """A thin spherical shell: density proportional to `exp(-(|x| - radius)^2 / (2 width^2))`.

    In 2-D a ring, in `d` dimensions a shell around a sphere; a non-convex target
    whose mass a random walk must traverse around the hole. Exactly normalised:
    `Z = |S^(d-1)| int_0^inf rho^(d-1) exp(-(rho - r)^2 / (2 w^2)) d rho`, with the
    radial integral in closed form (see `log_radial_tail`), computed in float64
    at construction. Mean zero; covariance `E[rho^2] / d * I`. Exact draws: a
    uniform direction times a radius from rejection sampling. `radial_cdf` gives
    the CDF of `|x|` in any dimension; `marginal_cdf` exists in closed form only
    for `d = 1` and `d = 3` and raises `NotImplementedError` otherwise.

    Attributes:
        dim: the dimension `d >= 1` (static).
        radius: the radius `r >= 0` of the ridge (static).
        width: the Gaussian width `w > 0` across the ridge (static).
        log_normaliser: `log Z` (static, float64 precision).
        log_radial_mass: `log K_(d-1)(0)`, the radial integral in `Z` (static).
        second_moment: `E[|x|^2]` (static, float64 precision).
    """

    dim: int = eqx.field(static=True)
    radius: float = eqx.field(static=True)
    width: float = eqx.field(static=True)
    log_normaliser: float = eqx.field(static=True)
    log_radial_mass: float = eqx.field(static=True)
    second_moment: float = eqx.field(static=True)

    def __init__(self, dim: int = 2, radius: float = 3.0, width: float = 0.5):
        """Arguments:
            dim: the dimension, at least 1 (in 1-D: two bumps at `+-radius`).
            radius: the radius of the ridge, `>= 0` (`0` gives a Gaussian).
            width: the standard deviation across the ridge, positive; smaller is
                harder to sample.

        Raises:
            ValueError: for `dim < 1`, a negative radius or a non-positive width.
        """
        dim = _checks.integer(dim, "dim", 1)
        radius = _checks.finite_float(radius, "radius")
        if radius < 0:
            raise ValueError(f"radius must be >= 0, got {radius}")
        width = _checks.positive_float(width, "width")
        m = dim - 1
        log_sphere = math.log(2.0) + 0.5 * dim * math.log(math.pi) - math.lgamma(0.5 * dim)
        log_k = _log_tail_np(0.0, m, radius, width)
        self.dim = dim
        self.radius = radius
        self.width = width
        self.log_normaliser = log_sphere + log_k
        self.log_radial_mass = log_k
        self.second_moment = math.exp(_log_tail_np(0.0, m + 2, radius, width) - log_k)

    def logdensity(self, x: Float[Array, " d"]) -> Float[Array, ""]:
        x = _checks.point(x, self.dim)
        z = (safe_norm(x) - self.radius) / self.width
        return -0.5 * z * z - self.log_normaliser

    def _log_tail(self, t: Float[Array, ...], m: int) -> Float[Array, ...]:
        return log_radial_tail(t, m, self.radius, self.width, jnp, jsp)

    def radial_cdf(self, t: ArrayLike) -> Float[Array, ...]:
        """Exact CDF of the radius `|x|`, evaluated elementwise at `t`.

        Arguments:
            t: where to evaluate; any shape (negative values give 0).
        """
        return _radial_cdf_jit(self, _checks.float_array(t, "t"))

    def _radial_cdf(self, t: Float[Array, ...]) -> Float[Array, ...]:
        tail = jnp.exp(self._log_tail(jnp.maximum(t, 0.0), self.dim - 1) - self.log_radial_mass)
        return jnp.where(t > 0, 1.0 - tail, 0.0)

    def _sample(self, key: PRNGKeyArray, n: int) -> Float[Array, "n d"]:
        key_dir, key_rad = jax.random.split(key)
        g = standard_normal(key_dir, (n, self.dim))
        norm = jnp.linalg.norm(g, axis=1, keepdims=True)
        fallback = jnp.zeros((self.dim,), g.dtype).at[0].set(1.0)
        direction = jnp.where(norm > 0, g / jnp.where(norm > 0, norm, 1.0), fallback)
        return direction * self._sample_radii(key_rad, n, g.dtype)[:, None]

    def _sample_radii(self, key: PRNGKeyArray, n: int, dtype: Any) -> Float[Array, " n"]:
        """Exact draws from `f(rho) = rho^m exp(-(rho - r)^2 / (2 w^2))` on `rho > 0`.

        `log f` is concave with curvature at most `-1 / w^2`, so around its mode
        `rho* = (r + sqrt(r^2 + 4 m w^2)) / 2` it lies below the parabola
        `log f(rho*) - (rho - rho*)^2 / (2 w^2)`. Rejection sampling from
        `N(rho*, w^2)` is therefore exact, with acceptance probability
        `1{rho > 0} exp(m (log u - u + 1))`, `u = rho / rho*` (at least ~0.5 for all
        parameters). Each of the `n` slots redraws until it accepts.
        """
        m = self.dim - 1
        w = self.width
        mode = 0.5 * (self.radius + math.sqrt(self.radius**2 + 4.0 * m * w * w))

        def propose(key: PRNGKeyArray) -> tuple[Array, Array]:
            # One normal draw per slot for the proposal, one for the accept test
            # (Phi(z) is uniform, so log U = log_ndtr(z)).
            z = standard_normal(key, (2, n), dtype)
            rho = mode + w * z[0]
            positive = rho > 0
            if m == 0:
                return rho, positive
            u = jnp.where(positive, rho / mode, 1.0)
            log_accept = m * (jnp.log(u) - u + 1.0)
            return rho, positive & (log_ndtr(z[1]) < log_accept)

        def not_done(state: tuple[Array, Array, Array]) -> Array:
            return ~jnp.all(state[2])

        def redraw(state: tuple[Array, Array, Array]) -> tuple[Array, Array, Array]:
            key, rho, accepted = state
            key, sub = jax.random.split(key)
            new_rho, new_accepted = propose(sub)
            rho = jnp.where(accepted, rho, new_rho)
            return key, rho, accepted | new_accepted

        init = (key, jnp.zeros((n,), dtype), jnp.zeros((n,), bool))
        return jax.lax.while_loop(not_done, redraw, init)[1]

    @property
    def mean(self) -> Float[Array, " d"]:
        return jnp.zeros((self.dim,))

    @property
    def covariance(self) -> Float[Array, "d d"]:
        return (self.second_moment / self.dim) * jnp.eye(self.dim)

    def _marginal_cdf(self, i: int, t: Float[Array, ...]) -> Float[Array, ...]:
        # The same for every coordinate. 1-D: x = +-rho with equal probability. 3-D:
        # x_i = rho u with u ~ U[-1, 1] (Archimedes), so for s >= 0
        # P(x_i > s) = E[(1 - s / rho) / 2; rho > s] = (K_2(s) - s K_1(s)) / (2 K_2(0)).
        s = jnp.abs(t)
        if self.dim == 1:
            upper = 0.5 * (1.0 - self._radial_cdf(s))
        elif self.dim == 3:
            upper = 0.5 * (
                jnp.exp(self._log_tail(s, 2) - self.log_radial_mass)
                - s * jnp.exp(self._log_tail(s, 1) - self.log_radial_mass)
            )
            upper = jnp.clip(upper, 0.0, 0.5)
        else:
            raise NotImplementedError(
                f"Ring: the marginal CDF of a coordinate has no closed form in dimension "
                f"{self.dim} (only 1 and 3); use radial_cdf for the radius instead"
            )
        return jnp.where(t >= 0, 1.0 - upper, upper)


@eqx.filter_jit
def _radial_cdf_jit(ring: Ring, t: Array) -> Array:
    return ring._radial_cdf(t)
