"""Every PSS renderer converges to Mitsuba's own image of a tiny Cornell box."""

import importlib.util

import numpy as np
import pytest

if not all(importlib.util.find_spec(name) is not None for name in ("mitsuba", "drjit")):
    pytest.skip("the `mitsuba` extra is not installed", allow_module_level=True)

import jax

import restore.render as rr
from restore.render._methods import make_renderer
from targets.mitsuba import PrimarySampleSpace, load_scene, render_native

RESOLUTION, DEPTH = (8, 8), 3


@pytest.fixture(scope="module")
def scene_and_reference():
    scene = load_scene("cornell_box", RESOLUTION, DEPTH)
    return scene, render_native(scene, 32768, seed=1, max_depth=DEPTH).astype(np.float64)


def _errors(image, reference):
    """Relative error of the image total, and the median relative error of 2x2-pixel block sums."""
    blocks = lambda a: a.reshape(4, 2, 4, 2, 3).sum(axis=(1, 3))  # noqa: E731
    b, r = blocks(np.asarray(image, np.float64)), blocks(reference)
    return abs(image.sum() / reference.sum() - 1), float(np.median(np.abs(b - r) / r))


@pytest.mark.parametrize("method", ["uniform", "pssmlt", "restore", "mala-restore", "erpt"])
def test_renderer_converges_to_the_native_image(scene_and_reference, method):
    scene, reference = scene_and_reference
    target = PrimarySampleSpace(scene, russian_roulette=method != "mala-restore")
    renderer = make_renderer(method)  # the defaults: complete tours of L = 1, p_large = 0.3
    result = rr.render(target, renderer, key=jax.random.key(3), evaluations=1_500_000, lanes=2048, progress=False)
    total, block = _errors(result.image, reference)
    assert total < 0.08 and block < 0.08, (method, total, block)
    # the same check rejects an image that is 15% too bright
    assert max(_errors(1.15 * result.image, reference)) > 0.08
