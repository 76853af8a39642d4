"""Every PSS renderer converges to Mitsuba's own image of a tiny Cornell box, within its noise.

Skipped unless the `mitsuba` extra is installed (the reason says so where libLLVM is missing).
An 8x8 image, depth 3, fixed keys. `R = 16` independent renders of each method (its default
settings, a smaller bootstrap) are compared with 16 replicas of Mitsuba's `path` integrator
by two-sample z-scores from the replicas' own variances, per 2x2-pixel block (16 blocks) and
for the image total: each z is close to Student-t with about 30 degrees of freedom, so every
`|z|` stays below 4.5 with probability above 0.99 over the 17 of them. A render that is
right but noisy passes; a bias of a few standard errors in any block fails.

The negative controls render with planted defects in the tracer, which the renderers sample
as they would a correct one: a path one bounce too short, and next-event estimates dropped.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests._mitsuba_extra import mitsuba_extra_installed, mitsuba_or_skip

if not mitsuba_extra_installed():
    pytest.skip("the `mitsuba` extra is not installed", allow_module_level=True)

import jax

import restore.render as rr
from targets.mitsuba import PrimarySampleSpace, load_scene, render_native
from tests._image_agreement import LUMINANCE
from tests._tracer_defects import dropped_next_event

RESOLUTION, DEPTH, R, LIMIT = (8, 8), 3, 16, 4.5
EVALUATIONS, LANES, BOOTSTRAP = 40_000, 256, 4096
RENDERERS = {
    "uniform": lambda: rr.UniformSampler(),
    "pssmlt": lambda: rr.PSSMLT(n_bootstrap=BOOTSTRAP),
    "restore": lambda: rr.MetropolisRestore(n_bootstrap=BOOTSTRAP),
    "mala-restore": lambda: rr.MALARestore(n_bootstrap=BOOTSTRAP),
    "erpt": lambda: rr.ERPT(),
}


@pytest.fixture(scope="module")
def scene_and_native():
    mitsuba_or_skip()
    scene = load_scene("cornell_box", RESOLUTION, DEPTH)
    native = [render_native(scene, 1024, seed=100 + r, max_depth=DEPTH) for r in range(R)]
    return scene, np.stack(native).astype(np.float64) @ LUMINANCE


def _renders(target, method: str, r: int = R) -> np.ndarray:
    """`r` luminance images of `method` from independent keys."""
    keys = jax.random.split(jax.random.key(3), r)
    images = [
        rr.render(target, RENDERERS[method](), key=k, evaluations=EVALUATIONS, num_lanes=LANES, progress=False).image
        for k in keys
    ]
    return np.stack(images).astype(np.float64) @ LUMINANCE


def block_z(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """z-scores of `mean(a) - mean(b)` per 2x2-pixel block, then for the total (replicas first)."""
    def blocks(x):
        n, h, w = x.shape
        per_block = x.reshape(n, h // 2, 2, w // 2, 2).sum((2, 4)).reshape(n, -1)
        return np.concatenate([per_block, x.sum((1, 2))[:, None]], axis=1)

    x, y = blocks(a), blocks(b)
    se = np.sqrt(x.var(0, ddof=1) / len(x) + y.var(0, ddof=1) / len(y))
    return (x.mean(0) - y.mean(0)) / se


@pytest.mark.parametrize("method", list(RENDERERS))
def test_renderer_converges_to_the_native_image(scene_and_native, method):
    scene, native = scene_and_native
    target = PrimarySampleSpace(scene, russian_roulette=method != "mala-restore")
    z = block_z(_renders(target, method), native)
    assert np.abs(z).max() < LIMIT, (method, np.round(z, 2))


def test_a_path_one_bounce_short_fails(scene_and_native):
    """Negative control: the target traces depth 2 (direct light only) against Mitsuba's depth 3."""
    scene, native = scene_and_native
    z = block_z(_renders(PrimarySampleSpace(scene, max_depth=DEPTH - 1), "restore", r=8), native)
    assert np.abs(z).max() > 3 * LIMIT, np.round(z, 2)


def test_dropped_next_event_estimates_fail(scene_and_native, monkeypatch):
    """Negative control: the tracer weighs its next-event estimates zero (uniform sampling, the fastest)."""
    scene, native = scene_and_native
    dropped_next_event(monkeypatch)
    z = block_z(_renders(PrimarySampleSpace(scene), "uniform", r=8), native)
    assert np.abs(z).max() > 3 * LIMIT, np.round(z, 2)
