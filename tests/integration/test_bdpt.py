"""Tests of multiplexed bidirectional path tracing (`targets.mitsuba.MultiplexedBDPT`).

Skipped unless the `mitsuba` extra is installed. Scenes are tiny (16x16, depth 3-4) and
every random quantity has a fixed seed.

The BDPT image is compared with Mitsuba's own `path` integrator as the PSS path tracer
is (`test_mitsuba_target.py`): independent replicas of both images, z-scores of their
difference per pixel, per 4x4 block and for the image total, from the replicas' sample
variances. With 16 replicas each z is roughly Student-t with ~30 degrees of freedom, so
`mean z^2` is about 1 and `|z| < 4` holds for every one of the 16 blocks with
probability > 0.99. Defects injected through the target's private `_defect` switch
(weights of 1, a heuristic normalised wrongly, the strategy `s = 0` left out) must fail
the very same comparison.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests._mitsuba_extra import mitsuba_extra_installed, mitsuba_or_skip

if not mitsuba_extra_installed():
    pytest.skip("the `mitsuba` extra is not installed", allow_module_level=True)

import jax
import jax.numpy as jnp

from targets.mitsuba import (
    MultiplexedBDPT,
    UnsupportedSceneError,
    cornell_box,
    render_native,
)
from targets.mitsuba._multiplex import depth_pmf, select_pairs, strategy_pairs, strategy_pmf
from tests._image_agreement import LUMINANCE, agreement_z, failures

REPLICAS = 16
RES = 16


@pytest.fixture(scope="module")
def mi():
    return mitsuba_or_skip()


@pytest.fixture(scope="module")
def cornell(mi):
    return MultiplexedBDPT("cornell_box", resolution=(RES, RES), max_depth=4, bootstrap=2000)


@pytest.fixture(scope="module")
def native_cornell(cornell):
    return _native_replicas(cornell.scene, cornell.max_depth)


def _native_replicas(scene, max_depth: int, seed: int = 200, spp: int = 32) -> np.ndarray:
    """`REPLICAS` luminance images of Mitsuba's `path` integrator (`spp` each)."""
    images = [render_native(scene, spp, seed=seed + r, max_depth=max_depth) for r in range(REPLICAS)]
    return np.stack(images).astype(np.float64) @ LUMINANCE


def _bdpt_replicas(target: MultiplexedBDPT, spp: int = 64) -> np.ndarray:
    images = [target.render_uniform(spp, seed=100 + r) for r in range(REPLICAS)]
    return np.stack(images).astype(np.float64) @ LUMINANCE


# --------------------------------------------------------------------------- agreement with `path`


def test_bdpt_matches_native_cornell_box(cornell, native_cornell):
    assert failures(agreement_z(_bdpt_replicas(cornell), native_cornell)) == []


def test_bdpt_matches_native_through_glass(mi):
    """A glass sphere under a small light: delta vertices are never connected through,
    and the MIS weights leave out the strategies that would need it."""
    target = MultiplexedBDPT("caustic", resolution=(RES, RES), max_depth=4, bootstrap=2000)
    assert failures(agreement_z(_bdpt_replicas(target), _native_replicas(target.scene, 4))) == []


def test_bdpt_matches_native_through_a_gap_onto_glossy_surfaces(mi):
    """`door_gap`: a rough-plastic floor and a rough-aluminium door (glossy, non-delta
    vertices in every strategy's densities) in a room lit only through a 4 cm gap, behind
    a zero-thickness wall. Shadow rays that stop a relative 1e-3 short of their camera end
    let the light in the next room leak through the wall onto the strips of floor, ceiling
    and side walls that meet it (total +10%, |total z| ~ 8.6 here); the connection must
    test the whole edge, as `path`'s emitter sampling does."""
    target = MultiplexedBDPT("door_gap", resolution=(RES, RES), max_depth=3, bootstrap=2000)
    native = _native_replicas(target.scene, 3, spp=2048)
    assert failures(agreement_z(_bdpt_replicas(target, spp=2048), native)) == []


def test_bdpt_matches_native_with_glossy_walls(mi):
    """The Cornell box with a rough-plastic floor (GGX, alpha 0.08) and a rough-aluminium
    back wall (alpha 0.15): BSDF values and reverse densities of glossy vertices on both
    subpaths, without thin occluders."""
    scene = cornell_box(resolution=(RES, RES), max_depth=4)
    scene["floor"]["bsdf"] = {
        "type": "roughplastic", "distribution": "ggx", "alpha": 0.08,
        "diffuse_reflectance": {"type": "rgb", "value": [0.35, 0.3, 0.25]},
    }
    scene["back"]["bsdf"] = {"type": "twosided", "bsdf": {"type": "roughconductor", "material": "Al", "alpha": 0.15}}
    target = MultiplexedBDPT(scene, bootstrap=2000)
    native = _native_replicas(target.scene, 4, spp=1024)
    assert failures(agreement_z(_bdpt_replicas(target, spp=512), native)) == []


def test_power_heuristic_matches_native(mi, native_cornell, cornell):
    target = MultiplexedBDPT("cornell_box", resolution=(RES, RES), max_depth=4, depth_pmf=cornell.pmf, heuristic="power")
    assert failures(agreement_z(_bdpt_replicas(target), native_cornell)) == []


@pytest.mark.parametrize("defect", ["unit_weights", "unnormalised_power", "drop_light_tracing"])
def test_defects_fail_the_comparison(mi, cornell, native_cornell, defect):
    target = MultiplexedBDPT("cornell_box", resolution=(RES, RES), max_depth=4, depth_pmf=cornell.pmf, _defect=defect)
    failed = failures(agreement_z(_bdpt_replicas(target), native_cornell))
    print(defect, failed)
    assert failed != []


def _large_light(mi) -> dict:
    """Direct and one-bounce light from a light covering most of the ceiling, where BSDF
    sampling and emitter sampling have comparable densities (as in `test_mitsuba_target`)."""
    scene = cornell_box(resolution=(RES, RES), max_depth=2)
    scene["light"]["to_world"] = mi.ScalarTransform4f().translate([0, 0.99, 0]).rotate([1, 0, 0], 90).scale(
        [0.9, 0.9, 1]
    )
    scene["light"]["emitter"]["radiance"]["value"] = [1.5, 1.2, 0.9]
    return scene


@pytest.mark.parametrize("defect", [None, "drop_s0"])
def test_camera_paths_hitting_the_light_matter(mi, defect):
    """With a large light, unidirectional hits (`s = 0`) carry a large MIS weight: leaving
    them out must fail the comparison that the full estimator passes."""
    target = MultiplexedBDPT(_large_light(mi), bootstrap=2000, _defect=defect)
    failed = failures(agreement_z(_bdpt_replicas(target), _native_replicas(target.scene, 2)))
    print(defect, failed)
    assert (failed == []) == (defect is None)


def test_strategies_of_one_depth_sum_to_that_depth(cornell, native_cornell):
    """For each depth `k`, the sum over its strategies is the depth-`k` part of the image
    (`path` with `max_depth = k` minus `max_depth = k - 1`); all together, the whole image."""
    k_of_pair = cornell.pairs[0]
    per_pair = np.stack([cornell.strategy_images(8, seed=300 + r) for r in range(REPLICAS)]) @ LUMINANCE
    previous = np.zeros_like(native_cornell)
    for k in range(1, cornell.max_depth + 1):
        upto_k = native_cornell if k == cornell.max_depth else _native_replicas(cornell.scene, k, seed=400 + 50 * k)
        z = agreement_z(per_pair[:, k_of_pair == k].sum(1), upto_k - previous, min_lit=0.0)  # k = 1: the light
        assert abs(z["total"][0]) < 4.0, f"depth {k}: total z = {z['total'][0]:.2f}"
        assert np.mean(z["block"] ** 2) < 2.5, f"depth {k}: per-block mean z^2 = {np.mean(z['block'] ** 2):.2f}"
        previous = _native_replicas(cornell.scene, k, seed=500 + 50 * k)


def test_light_tracing_pixel_comes_from_the_connection(cornell):
    rng = np.random.default_rng(3)
    u = rng.random((4000, cornell.strategy_dim), dtype=np.float32)
    out = cornell.evaluate_strategies(np.full(4000, 2), np.full(4000, 2), u)  # k = 2, s = 2: t = 1
    film = np.minimum((u[:, 0] * RES).astype(int), RES - 1) + RES * np.minimum((u[:, 1] * RES).astype(int), RES - 1)
    seen = out.luminance > 0
    assert seen.mean() > 0.2
    assert np.mean(out.pixel[seen] != film[seen]) > 0.8
    assert np.all((out.pixel >= 0) & (out.pixel < RES * RES))


# --------------------------------------------------------------------------- multiplexing


def test_pairs_and_their_probabilities():
    ks, ss = strategy_pairs(3)
    assert list(zip(ks.tolist(), ss.tolist())) == [(1, 0), (1, 1), (2, 0), (2, 1), (2, 2), (3, 0), (3, 1), (3, 2), (3, 3)]
    pmf = depth_pmf(np.array([2.0, 0.0, 1.0]), floor=0.03)
    np.testing.assert_allclose(pmf, np.array([2 / 3, 0.01, 1 / 3]) / 1.01)
    q = strategy_pmf(pmf)
    assert q.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(q[ks == 3], pmf[2] / 4)
    v = (np.arange(100_000) + 0.5) / 100_000
    counts = np.bincount(select_pairs(v.astype(np.float32), q), minlength=len(q)) / len(v)
    np.testing.assert_allclose(counts, q, atol=2e-5)
    assert select_pairs(np.float32([np.nextafter(np.float32(1), np.float32(0))]), q)[0] == len(q) - 1
    with pytest.raises(ValueError):
        depth_pmf(np.array([1.0, -1.0]))
    with pytest.raises(ValueError):
        strategy_pmf(np.array([0.5, 0.6]))


def test_density_is_luminance_over_q(cornell):
    x = np.random.default_rng(4).random((3000, cornell.dim), dtype=np.float32)
    out = cornell.evaluate(x)
    pair = select_pairs(x[:, 0], cornell.q)
    raw = cornell.evaluate_strategies(cornell.pairs[0][pair], cornell.pairs[1][pair], x[:, 1:])
    np.testing.assert_allclose(out.luminance, raw.luminance / cornell.q[pair], rtol=1e-5)
    np.testing.assert_allclose(out.rgb, raw.rgb / cornell.q[pair][:, None], rtol=1e-5, atol=1e-12)
    np.testing.assert_array_equal(out.pixel, raw.pixel)
    np.testing.assert_allclose(out.luminance, out.rgb @ LUMINANCE.astype(np.float32), rtol=1e-4, atol=1e-6)


def test_jax_bridge_returns_the_traced_pixel(cornell):
    x = jnp.asarray(np.random.default_rng(5).random((64, cornell.dim), dtype=np.float32))
    lum, rgb, pixel = jax.jit(cornell.jax_evaluate_with_pixel)(x)
    ref = cornell.evaluate(np.asarray(x))
    np.testing.assert_array_equal(np.asarray(lum), ref.luminance)
    np.testing.assert_array_equal(np.asarray(pixel), ref.pixel)
    np.testing.assert_array_equal(np.asarray(jax.vmap(cornell.pixel_index)(x)), ref.pixel)
    lum2, rgb2 = jax.jit(jax.vmap(cornell.jax_evaluate))(x)
    np.testing.assert_array_equal(np.asarray(rgb2), np.asarray(rgb))


# --------------------------------------------------------------------------- scenes and inputs


def test_unsupported_scenes_are_refused(mi):
    scene = cornell_box(resolution=(RES, RES), max_depth=3)
    scene["point"] = {"type": "point", "position": [0, 0.5, 0], "intensity": {"type": "rgb", "value": 1.0}}
    with pytest.raises(UnsupportedSceneError, match="area emitters only"):
        MultiplexedBDPT(scene, bootstrap=10)
    scene = cornell_box(resolution=(RES, RES), max_depth=3)
    scene["sensor"]["type"] = "orthographic"
    del scene["sensor"]["fov"], scene["sensor"]["fov_axis"]
    with pytest.raises(UnsupportedSceneError, match="perspective"):
        MultiplexedBDPT(scene, bootstrap=10)


def test_bad_inputs(cornell):
    with pytest.raises(ValueError, match="shape"):
        cornell.evaluate(np.zeros((3, cornell.dim - 1), np.float32))
    with pytest.raises(ValueError, match="finite"):
        cornell.evaluate(np.full((3, cornell.dim), np.nan, np.float32))
    with pytest.raises(ValueError, match="heuristic"):
        MultiplexedBDPT(cornell.scene, heuristic="maximum", bootstrap=10)
    with pytest.raises(ValueError, match="entries"):
        cornell.set_depth_pmf(np.array([1.0]))
    out = cornell.evaluate_strategies(np.array([0, 5, 2]), np.array([0, 0, 3]), np.full((3, cornell.strategy_dim), 0.5))
    np.testing.assert_array_equal(out.luminance, 0)  # k outside 1..M, or s > k
