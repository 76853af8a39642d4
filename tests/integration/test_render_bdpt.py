"""Metropolis Restore and PSSMLT (then MMLT) on `MultiplexedBDPT` converge to Mitsuba's `path` image.

Skipped unless the `mitsuba` extra is installed. A 16x16 Cornell box, depth 3, fixed keys.

`R = 16` independent renders of each method (one compilation, keys split from a fixed
seed) are compared with 16 replicas of Mitsuba's `path` integrator at 256 spp by the
z-scores of `tests._image_agreement`, on 2x2-pixel bins (an 8x8 image: z per bin, per
8x8-pixel block and for the total). The renders dominate the variance (the native
replicas' is about 10x smaller), so each z is close to Student-t with 15 degrees of
freedom: `mean z^2` is about 1.15 (standard deviation about 0.25 over the 64 bins), and
a block or the total reaches `|z| = 4.5` or `4` with probability below 1%. Measured with
these keys: Restore 1.17 per bin, 0.71 per block, largest block `|z|` 1.19, total z
-1.55; PSSMLT 1.10, 0.83, 1.37, -1.05. (Per single pixel PSSMLT's `mean z^2` is 1.66
against Restore's 1.10, hence the bins.) Splatting at the film coordinates `u[0:2]`
instead of the traced pixel (light tracing lands anywhere on the film) fails the same
comparison by a wide margin.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests._image_agreement import LUMINANCE, agreement_z, failures
from tests._mitsuba_extra import mitsuba_extra_installed, mitsuba_or_skip

if not mitsuba_extra_installed():
    pytest.skip("the `mitsuba` extra is not installed", allow_module_level=True)

import jax
import jax.numpy as jnp

import restore.render as rr
from restore.render._methods import make_renderer
from targets.mitsuba import MultiplexedBDPT, render_native
from targets.mitsuba._jax_bridge import pixel_index_jax

RES, DEPTH = 16, 3
R, LANES, STEPS = 16, 256, 500  # 16 renders of 16384 bootstrap + 128000 evaluations


@pytest.fixture(scope="module")
def target():
    mitsuba_or_skip()
    return MultiplexedBDPT("cornell_box", resolution=(RES, RES), max_depth=DEPTH, bootstrap=2000)


@pytest.fixture(scope="module")
def native(target):
    images = [render_native(target.scene, 256, seed=500 + r, max_depth=DEPTH) for r in range(16)]
    return np.stack(images).astype(np.float64) @ LUMINANCE


class _Altered:
    """A target that behaves as `base` except for the attributes given (a defect or a probe)."""

    def __init__(self, base, **overrides):
        self._base = base
        self.__dict__.update(overrides)

    def __getattr__(self, name):
        return getattr(self._base, name)


def _realisations(renderer, target, r=R, lanes=LANES, steps=STEPS):
    """`r` luminance images from independent keys (compiled once): init, `steps` steps, finish."""

    @jax.jit
    def one(key):
        k_init, k_run, k_finish = jax.random.split(key, 3)
        state = renderer.run(target, k_run, renderer.init(target, k_init, lanes), steps)
        state, _ = renderer.finish(target, k_finish, state)  # Restore's open tours (PSSMLT: nothing)
        return renderer.image(target, state)

    keys = jax.random.split(jax.random.key(11), r)
    return np.stack([np.asarray(one(k), np.float64) @ LUMINANCE for k in keys])


def _bins(images):
    """Sums over 2x2 pixels: `(R, 16, 16) -> (R, 8, 8)`."""
    return images.reshape(len(images), RES // 2, 2, RES // 2, 2).sum((2, 4))


def _summary(z):
    return {
        "pixel mean z^2": float(np.mean(z["pixel"] ** 2)), "block mean z^2": float(np.mean(z["block"] ** 2)),
        "max block |z|": float(np.abs(z["block"]).max()), "total z": float(z["total"][0]),
    }


@pytest.mark.parametrize("method", ["restore", "restore-learned", "pssmlt"])
def test_mcmc_renders_of_multiplexed_bdpt_match_the_native_image(target, native, method):
    z = agreement_z(_bins(_realisations(_renderer(method), target)), _bins(native))
    assert failures(z) == [], (method, _summary(z))


def _renderer(method):
    """The method's renderer with the defaults of `make_renderer` and a smaller bootstrap."""
    if method == "restore":
        return rr.MetropolisRestore(n_bootstrap=16384)
    if method == "restore-learned":  # regenerating from kernels around bright bootstrap paths (the depth coordinate included)
        return rr.MetropolisRestore(n_bootstrap=16384, learned=rr.LearnedRegeneration())
    return rr.PSSMLT(n_bootstrap=16384)


def test_splatting_at_the_film_coordinates_fails_the_comparison(target, native):
    """Negative control: the pixel from `u[0:2]` (as a path tracer's) misplaces light tracing."""
    film_pixel = _Altered(
        target, pixel_from_evaluation=False, pixel_index=lambda x: pixel_index_jax(x[..., 1:3], RES, RES)
    )
    z = agreement_z(_bins(_realisations(_renderer("pssmlt"), film_pixel, r=4)), _bins(native))
    assert "per-block mean z^2" in " ".join(failures(z)), _summary(z)
    assert _summary(z)["block mean z^2"] > 100


def _refuse_retrace(x):
    raise AssertionError("a renderer traced a point again to find its pixel")


@pytest.mark.parametrize(
    "renderer",
    [rr.UniformSampler(), rr.PSSMLT(p_large=1e-6, n_bootstrap=256), rr.MetropolisRestore(n_bootstrap=256), rr.ERPT(chain_length=2)],
    ids=["uniform", "pssmlt", "restore", "erpt"],
)
def test_splats_take_the_pixel_from_the_evaluation(target, renderer):
    """No renderer calls `pixel_index` (a second trace) when the evaluation gives the pixel,
    and small steps keep `v` (the depth and strategy)."""
    probe = _Altered(target, pixel_index=_refuse_retrace)
    lanes = 64

    @jax.jit
    def run(key):
        start = renderer.init(probe, key, lanes)
        state, _ = renderer.finish(probe, key, renderer.run(probe, key, start, 3))
        return start, state

    start, state = run(jax.random.key(5))
    assert float(jnp.sum(state.tally.film)) > 0
    if isinstance(renderer, rr.PSSMLT):  # with p_large = 1e-6 every step is a small step
        np.testing.assert_array_equal(state.point.position[:, 0], start.point.position[:, 0])
        assert not np.array_equal(state.point.position[:, 1:], start.point.position[:, 1:])


def test_uniform_film_holds_the_traced_pixels(target):
    """The film of one step of uniform draws equals the tracer's own image of those points."""
    renderer = rr.UniformSampler()
    state = jax.jit(lambda k: renderer.step(target, k, renderer.init(target, k, 256)))(jax.random.key(2))
    traced = target.evaluate(np.asarray(state.point.position))
    expected = np.stack([np.bincount(traced.pixel, traced.rgb[:, c], target.num_pixels) for c in range(3)], 1)
    assert len(np.unique(traced.pixel)) > 50
    np.testing.assert_allclose(np.asarray(state.tally.film), expected, rtol=1e-5, atol=1e-6)


def test_mala_restore_is_refused_for_want_of_gradients(target):
    with pytest.raises(TypeError, match="needs gradients of the luminance"):
        rr.render(target, make_renderer("mala-restore"), key=jax.random.key(0), evaluations=10**6, progress=False)
