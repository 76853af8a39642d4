"""Statistical agreement of two sets of independent luminance images (replicas first).

z-scores of the difference of their means per pixel, per 4x4 block and for the image
total, from the replicas' sample variances; `failures` lists the criteria they break.
With 16 replicas of each image every z is roughly Student-t with ~30 degrees of freedom,
so `mean z^2` is about 1 and `|z| < 4` holds for every one of 16 blocks with probability
> 0.99.
"""

from __future__ import annotations

import numpy as np

#: Rec. 709 luminance weights, as Mitsuba's.
LUMINANCE = np.array([0.212671, 0.715160, 0.072169])


def agreement_z(a: np.ndarray, b: np.ndarray, min_lit: float = 0.5) -> dict[str, np.ndarray]:
    """z-scores of `mean(a) - mean(b)` per pixel, per 4x4 block and for the total (replicas first).

    At least a fraction `min_lit` of the pixels and blocks must be lit (non-zero error).
    """
    n_a, n_b = len(a), len(b)
    h, w = a.shape[1:]

    def blocks(x: np.ndarray) -> np.ndarray:
        return x.reshape(len(x), h // 4, 4, w // 4, 4).sum((2, 4)).reshape(len(x), -1)

    views = {
        "pixel": (a.reshape(n_a, -1), b.reshape(n_b, -1)),
        "block": (blocks(a), blocks(b)),
        "total": (a.sum((1, 2))[:, None], b.sum((1, 2))[:, None]),
    }
    out = {}
    for name, (x, y) in views.items():
        se = np.sqrt(x.var(0, ddof=1) / n_a + y.var(0, ddof=1) / n_b)
        se += 1e-5 * (np.abs(x.mean(0)) + np.abs(y.mean(0)))  # float32 rounding
        keep = se > 0
        assert keep.mean() >= min_lit, f"{name}: too many black {name}s"
        out[name] = (x.mean(0) - y.mean(0))[keep] / se[keep]
    return out


def failures(z: dict[str, np.ndarray]) -> list[str]:
    """The agreement criteria that `z` violates (empty: the images agree)."""
    checks = {
        "per-pixel mean z^2": (np.mean(z["pixel"] ** 2), 1.5),
        "per-block mean z^2": (np.mean(z["block"] ** 2), 2.5),
        "max block |z|": (np.abs(z["block"]).max(), 4.5),
        "|total z|": (abs(z["total"][0]), 4.0),
    }
    return [f"{name} = {value:.2f} >= {limit}" for name, (value, limit) in checks.items() if value >= limit]
