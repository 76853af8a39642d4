"""An analytic primary-sample-space image: a bumpy density on the torus with an exact image.

Renderers are validated against it without Mitsuba: it has the same interface as a
light-transport target (`dim`, `resolution`, `jax_evaluate`, `pixel_index`, ...), and
its image, `I_j = W H ∫ rgb(u) 1{j(u) = j} du`, is known in closed form per pixel.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int, PRNGKeyArray
from scipy.special import ndtr

from . import _checks

#: Rec. 709 luminance weights: `luminance(rgb) = REC709 . rgb`.
REC709 = (0.2126, 0.7152, 0.0722)
#: Periodic images `n` summed in the wrapped normal `sum_n N(u + n; m, s)`. With `u, m`
#: in `[0, 1)` and `s <= 0.25`, the first image left out lies 2 units away: its relative
#: weight is below `exp(-32)`. The exact image and `Z` use the same truncated sum, so they
#: are exact for the density as evaluated.
_IMAGES = np.arange(-2, 3)
_MAX_WIDTH = 0.25


class AnalyticImage(eqx.Module):
    """A multimodal density on the torus `[0, 1)^D` with an exact image, as a PSS target.

    `luminance(u) = floor + sum_k w_k prod_d WN(u_d; m_kd, s_kd)` with `WN` a wrapped
    normal density, and `rgb(u) = floor * (1, 1, 1) + sum_k w_k colour_k prod_d WN(...)`.
    Colours are rescaled to unit Rec. 709 luminance, so `luminance = REC709 . rgb`
    exactly, as for a real renderer. The pixel of `u` is
    `floor(u_0 W) + W floor(u_1 H)`; only `u_0, u_1` decide it, the other coordinates
    play the part of the path's later bounces and integrate to one.

    Attributes:
        means: bump centres `m`, shape `(K, D)`, in `[0, 1)`.
        widths: bump standard deviations `s`, shape `(K, D)`, in `(0, 0.25]`.
        weights: bump masses `w`, shape `(K,)`, positive.
        colours: bump colours, shape `(K, 3)`, each of unit luminance.
        floor: constant background luminance (grey), `>= 0`.
        dim: `D` (static).
        resolution: `(W, H)` (static).
    """

    means: Float[Array, "K D"]
    widths: Float[Array, "K D"]
    weights: Float[Array, " K"]
    colours: Float[Array, "K 3"]
    floor: Float[Array, ""]
    dim: int = eqx.field(static=True)
    resolution: tuple[int, int] = eqx.field(static=True)

    def __init__(
        self,
        means: ArrayLike,
        widths: ArrayLike,
        weights: ArrayLike | None = None,
        colours: ArrayLike | None = None,
        *,
        floor: float = 0.1,
        resolution: tuple[int, int] = (16, 16),
    ):
        """Arguments:
            means: bump centres, shape `(K, D)` with `D >= 2`; wrapped into `[0, 1)`.
            widths: standard deviations, a scalar, `(K,)` (isotropic per bump) or
                `(K, D)`; each in `(0, 0.25]` (wider bumps would need more periodic images).
            weights: positive masses `(K,)`; default all one.
            colours: non-negative RGB colours `(K, 3)` of positive luminance, rescaled to
                unit luminance; default a red, a green and a blue tint in turn.
            floor: background luminance `>= 0` (zero leaves regions of zero density).
            resolution: `(W, H)`, positive integers.

        Raises:
            ValueError: on wrong shapes or values out of range.
        """
        m = np.asarray(means, dtype=np.float64)
        if m.ndim != 2 or m.shape[0] < 1 or m.shape[1] < 2:
            raise ValueError(f"means must have shape (K, D) with K >= 1 and D >= 2, got {m.shape}")
        if not np.all(np.isfinite(m)):
            raise ValueError("means must be finite")
        k, d = m.shape
        s = np.asarray(widths, dtype=np.float64)
        if s.ndim == 0 or s.shape == (k,):
            s = np.broadcast_to(s.reshape(-1, 1) if s.ndim else s, (k, d))
        if s.shape != (k, d):
            raise ValueError(f"widths must be a scalar, ({k},) or ({k}, {d}), got shape {s.shape}")
        if not np.all((s > 0) & (s <= _MAX_WIDTH)):
            raise ValueError(f"widths must lie in (0, {_MAX_WIDTH}], got {s.min():.3g} .. {s.max():.3g}")
        w = np.ones(k) if weights is None else np.asarray(weights, dtype=np.float64)
        if w.shape != (k,) or not np.all(np.isfinite(w) & (w > 0)):
            raise ValueError(f"weights must be {k} positive finite numbers, got {weights!r}")
        if colours is None:
            palette = np.array([[1.0, 0.35, 0.25], [0.3, 1.0, 0.35], [0.35, 0.5, 1.0]])
            c = palette[np.arange(k) % 3]
        else:
            c = np.asarray(colours, dtype=np.float64)
        if c.shape != (k, 3) or not np.all(np.isfinite(c) & (c >= 0)):
            raise ValueError(f"colours must be ({k}, 3) non-negative and finite, got shape {c.shape}")
        lum = c @ np.asarray(REC709)
        if not np.all(lum > 0):
            raise ValueError("every colour must have positive luminance")
        floor = _checks.finite_float(floor, "floor")
        if floor < 0:
            raise ValueError(f"floor must be >= 0, got {floor}")
        if not (isinstance(resolution, (tuple, list)) and len(resolution) == 2):
            raise ValueError(f"resolution must be a pair (W, H), got {resolution!r}")
        width, height = (_checks.integer(r, "resolution", 1) for r in resolution)
        res = (width, height)
        self.means = jnp.asarray(np.mod(m, 1.0), jnp.float32)
        self.widths = jnp.asarray(s, jnp.float32)
        self.weights = jnp.asarray(w, jnp.float32)
        self.colours = jnp.asarray(c / lum[:, None], jnp.float32)
        self.floor = jnp.asarray(floor, jnp.float32)
        self.dim = d
        self.resolution = res

    @classmethod
    def default(
        cls, dim: int = 6, resolution: tuple[int, int] = (16, 16), num_bumps: int = 3, floor: float = 0.1
    ) -> AnalyticImage:
        """Well-separated bumps of increasing width (0.04, 0.06, 0.09, ...) and weight.

        Centres on the image plane follow Roberts' R2 sequence (so any number of bumps is
        spread evenly), the other coordinates a Kronecker sequence of square roots of primes.

        Raises:
            ValueError: if the bumps would overlap (centres closer than 2.5 times the sum
                of their widths on the image plane) or on bad arguments.
        """
        dim = _checks.integer(dim, "dim", 2)
        k = _checks.integer(num_bumps, "num_bumps", 1)
        plastic = 1.324717957244746
        primes = np.array([2, 3, 5, 7, 11, 13, 17, 19, 23, 29, 31, 37, 41, 43, 47, 53])
        alphas = np.concatenate([[1 / plastic, 1 / plastic**2], np.mod(np.sqrt(primes), 1.0)])
        alphas = np.resize(alphas, dim)
        means = np.mod(0.23 + np.arange(1, k + 1)[:, None] * alphas[None, :], 1.0)
        widths = 0.04 * 1.5 ** np.minimum(np.arange(k), 3)
        for i in range(k):
            for j in range(i):
                gap = np.abs(means[i, :2] - means[j, :2])
                gap = np.linalg.norm(np.minimum(gap, 1.0 - gap))
                if gap < 2.5 * (widths[i] + widths[j]):
                    raise ValueError(f"{k} bumps do not fit well separated on the torus; use fewer")
        weights = 1.0 + 0.5 * np.arange(k)
        return cls(means, widths, weights, floor=floor, resolution=resolution)

    # ------------------------------------------------------------------ PSS interface
    @property
    def num_pixels(self) -> int:
        return self.resolution[0] * self.resolution[1]

    def _log_bumps(self, u: Float[Array, " D"]) -> Float[Array, " K"]:
        """`log(w_k prod_d WN(u_d; m_kd, s_kd))` for one point."""
        u = jnp.mod(jnp.asarray(u, jnp.float32), 1.0)
        images = jnp.asarray(_IMAGES, jnp.float32)
        z = (u[None, :, None] - self.means[:, :, None] + images) / self.widths[:, :, None]
        log_wn = jax.nn.logsumexp(-0.5 * z * z, axis=-1) - jnp.log(self.widths) - 0.5 * math.log(2 * math.pi)
        return jnp.log(self.weights) + jnp.sum(log_wn, axis=-1)

    def _log_luminance(self, u: Float[Array, " D"]) -> Float[Array, ""]:
        terms = jnp.concatenate([jnp.log(self.floor)[None], self._log_bumps(u)])
        return jax.nn.logsumexp(terms)

    def _evaluate(self, u: Float[Array, " D"]) -> tuple[Float[Array, ""], Float[Array, " 3"]]:
        bumps = jnp.exp(self._log_bumps(u))
        rgb = self.floor + bumps @ self.colours
        return self.floor + jnp.sum(bumps), rgb

    def jax_evaluate(self, u: Float[Array, "N D"]) -> tuple[Float[Array, " N"], Float[Array, "N 3"]]:
        """Luminance `(N,)` and RGB `(N, 3)` of a batch of points (float32, jit-able)."""
        return jax.vmap(self._evaluate)(jnp.asarray(u, jnp.float32))

    def jax_evaluate_with_grad(
        self, u: Float[Array, "N D"]
    ) -> tuple[Float[Array, " N"], Float[Array, "N 3"], Float[Array, "N D"]]:
        """Luminance, RGB and the gradient of `log luminance` with respect to `u` (`jax.grad`)."""
        u = jnp.asarray(u, jnp.float32)
        lum, rgb = jax.vmap(self._evaluate)(u)
        return lum, rgb, jax.vmap(jax.grad(self._log_luminance))(u)

    def pixel_index(self, u: Float[Array, "N D"]) -> Int[Array, " N"]:
        """`floor(u_0 W) + W floor(u_1 H)` as int32 (clipped to the image)."""
        w, h = self.resolution
        col = jnp.clip(jnp.floor(u[:, 0] * w).astype(jnp.int32), 0, w - 1)
        row = jnp.clip(jnp.floor(u[:, 1] * h).astype(jnp.int32), 0, h - 1)
        return col + w * row

    # ------------------------------------------------------------------ exact answers
    def sample(self, key: PRNGKeyArray, n: int) -> Float[Array, "n D"]:
        """Exact draws from the normalised luminance `lum / Z` (float32, `(n, D)`).

        A mixture: the uniform floor with weight `floor`, bump `k` with weight `w_k`; a
        bump draw is `(m_k + s_k N(0, I)) mod 1`, an exact wrapped-normal draw (the
        density's image truncation changes its law by less than `exp(-32)`).
        """
        n = _checks.sample_count(n)
        k_pick, k_normal, k_uniform = jax.random.split(key, 3)
        logits = jnp.log(jnp.concatenate([self.floor[None], self.weights]))
        pick = jax.random.categorical(k_pick, logits, shape=(n,))
        bump = jnp.maximum(pick - 1, 0)
        z = jax.random.normal(k_normal, (n, self.dim), jnp.float32)
        bumps = jnp.mod(self.means[bump] + self.widths[bump] * z, 1.0)
        flat = jax.random.uniform(k_uniform, (n, self.dim), jnp.float32)
        u = jnp.where((pick == 0)[:, None], flat, bumps)
        return jnp.where(u >= 1.0, 0.0, u)


    def _cell_masses(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per bump: mass over each pixel column `(K, W)`, row `(K, H)`, and the product of
        the other coordinates' total masses `(K,)` (one, up to the image truncation)."""
        m = np.asarray(self.means, np.float64)
        s = np.asarray(self.widths, np.float64)

        def mass(lo, hi, d):  # (K, cells): integral of the truncated wrapped normal
            a = (lo[None, :, None] - m[:, d, None, None] + _IMAGES) / s[:, d, None, None]
            b = (hi[None, :, None] - m[:, d, None, None] + _IMAGES) / s[:, d, None, None]
            return np.sum(ndtr(b) - ndtr(a), axis=-1)

        w, h = self.resolution
        cols = mass(np.arange(w) / w, np.arange(1, w + 1) / w, 0)
        rows = mass(np.arange(h) / h, np.arange(1, h + 1) / h, 1)
        rest = np.ones(m.shape[0])
        for d in range(2, self.dim):
            rest = rest * mass(np.zeros(1), np.ones(1), d)[:, 0]
        return cols, rows, rest

    @property
    def Z(self) -> float:
        """`Z = ∫ luminance(u) du` over the torus, exact (float64)."""
        cols, rows, rest = self._cell_masses()
        bump_mass = cols.sum(1) * rows.sum(1) * rest
        return float(np.asarray(self.floor, np.float64) + np.sum(np.asarray(self.weights, np.float64) * bump_mass))

    def exact_image(self) -> np.ndarray:
        """The exact image `I[row, col] = W H ∫_pixel rgb(u) du`, float64, shape `(H, W, 3)`."""
        w, h = self.resolution
        cols, rows, rest = self._cell_masses()
        per_bump = np.asarray(self.weights, np.float64) * rest  # (K,)
        colours = np.asarray(self.colours, np.float64)
        image = np.einsum("k,kh,kw,kc->hwc", per_bump, rows, cols, colours) * (w * h)
        return image + float(self.floor)
