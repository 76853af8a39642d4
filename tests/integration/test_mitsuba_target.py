"""Tests of `targets.mitsuba`: the primary-sample-space (PSS) path tracer against Mitsuba.

Skipped unless the `mitsuba` extra is installed (Mitsuba is never imported before
`load_mitsuba` has chosen Dr.Jit's libLLVM). Scenes are tiny (16x16, depth 3-4) so the
file runs in well under a minute on one core; every random quantity has a fixed seed.

The agreement tests compare the uniform-PSS image with Mitsuba's own `path` integrator
through independent replicas of both: per-pixel and per-4x4-block z-scores built from
the replicas' sample variances, and the z-score of the image total. The negative controls
plant defects in the tracer (MIS weights that do not sum to one, dropped next-event
estimates, a path one bounce short): each biases whole regions by tens of percent and
must fail the comparison by a wide margin. Where Mitsuba is installed but libLLVM is
missing, the tests skip and say so.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from tests._image_agreement import LUMINANCE, agreement_z, failures
from tests._mitsuba_extra import mitsuba_extra_installed, mitsuba_or_skip, xml_scene

if not mitsuba_extra_installed():
    pytest.skip("the `mitsuba` extra is not installed", allow_module_level=True)

import jax
import jax.numpy as jnp

from targets.mitsuba import (
    SCENES,
    LLVMNotFoundError,
    PrimarySampleSpace,
    UnsupportedSceneError,
    _llvm,
    cornell_box,
    dimension,
    find_libllvm,
    load_scene,
    native_paths_per_second,
    reference_image,
    render_native,
    render_native_for,
)
from tests._tracer_defects import dropped_next_event, unbalanced_mis

REPLICAS = 16
RES = 16


@pytest.fixture(scope="module")
def mi():
    return mitsuba_or_skip()


@pytest.fixture(scope="module")
def cornell(mi):
    return PrimarySampleSpace("cornell_box", resolution=(RES, RES), max_depth=4)


@pytest.fixture(scope="module")
def cornell_smooth(mi):
    return PrimarySampleSpace("cornell_box", resolution=(RES, RES), max_depth=3, russian_roulette=False)


# --------------------------------------------------------------------------- agreement


def _agreement_z(target: PrimarySampleSpace, spp: int, native_depth: int | None = None) -> dict[str, np.ndarray]:
    """z-scores of (PSS - native) luminance per pixel, per 4x4 block and for the total."""
    depth = target.max_depth if native_depth is None else native_depth
    pss = np.stack([target.render_uniform(spp, seed=100 + r) for r in range(REPLICAS)])
    native = np.stack([render_native(target.scene, spp, seed=200 + r, max_depth=depth) for r in range(REPLICAS)])
    return agreement_z(pss.astype(np.float64) @ LUMINANCE, native.astype(np.float64) @ LUMINANCE)


def _assert_agree(z: dict[str, np.ndarray]) -> None:
    assert failures(z) == [], failures(z)


def _assert_disagree(z: dict[str, np.ndarray]) -> None:
    """A planted defect fails the comparison by a wide margin, block by block."""
    assert "per-block mean z^2" in " ".join(failures(z)), failures(z)
    assert np.mean(z["block"] ** 2) > 25, failures(z)  # ten times the limit


def test_uniform_pss_matches_native_cornell_box(cornell):
    _assert_agree(_agreement_z(cornell, spp=32))


def test_uniform_pss_matches_native_caustic(mi):
    target = PrimarySampleSpace("caustic", resolution=(RES, RES), max_depth=4)
    _assert_agree(_agreement_z(target, spp=32))


@pytest.mark.parametrize("name", ["door_gap", "pool"])
def test_uniform_pss_matches_native_on_the_hard_scenes(mi, name):
    """Glossy lobes (rough plastic, rough aluminium) and a triangle-mesh water surface: the
    PSS tracer must read and weight their random numbers exactly as Mitsuba does."""
    target = PrimarySampleSpace(name, resolution=(RES, RES), max_depth=5)
    _assert_agree(_agreement_z(target, spp=32))


def _large_light(mi) -> dict:
    """Direct light only, from a light covering most of the ceiling: BSDF and light sampling
    have comparable densities, so MIS weights that do not sum to one bias the image visibly."""
    scene = cornell_box(resolution=(RES, RES), max_depth=2)
    scene["light"]["to_world"] = mi.ScalarTransform4f().translate([0, 0.99, 0]).rotate([1, 0, 0], 90).scale(
        [0.9, 0.9, 1]
    )
    scene["light"]["emitter"]["radiance"]["value"] = [1.5, 1.2, 0.9]
    return scene


def test_uniform_pss_matches_native_large_light(mi):
    _assert_agree(_agreement_z(PrimarySampleSpace(_large_light(mi)), spp=32))


def test_mis_weights_that_do_not_sum_to_one_fail(mi, monkeypatch):
    """Negative control: each strategy's weight uses twice the other's pdf."""
    unbalanced_mis(monkeypatch)
    _assert_disagree(_agreement_z(PrimarySampleSpace(_large_light(mi)), spp=32))


def test_dropped_next_event_estimates_fail(mi, monkeypatch):
    """Negative control: next-event estimates weighed zero, emitter hits weighed as before."""
    dropped_next_event(monkeypatch)
    _assert_disagree(_agreement_z(PrimarySampleSpace("cornell_box", resolution=(RES, RES), max_depth=4), spp=32))


def test_a_path_one_bounce_short_fails(mi):
    """Negative control: the PSS tracer at depth 3 against Mitsuba's `path` at depth 4."""
    target = PrimarySampleSpace("cornell_box", resolution=(RES, RES), max_depth=3)
    _assert_disagree(_agreement_z(target, spp=32, native_depth=4))


def test_russian_roulette_matches_native(mi):
    scene = cornell_box(resolution=(RES, RES), max_depth=4)
    scene["integrator"]["rr_depth"] = 1  # roulette from the first bounce on
    target = PrimarySampleSpace(scene)
    assert target.rr_depth == 1
    _assert_agree(_agreement_z(target, spp=32))


# --------------------------------------------------------------------------- gradients


def _check_gradient(target: PrimarySampleSpace, n: int, seed: int) -> int:
    """Compare `evaluate_with_grad` with central differences where `log p` is smooth; returns #checked."""
    d = target.dim
    u = np.random.default_rng(seed).uniform(0.02, 0.98, (n, d)).astype(np.float32)
    samples, grad = target.evaluate_with_grad(u)
    assert np.all(np.isfinite(grad))
    assert np.all(grad[samples.luminance == 0] == 0)
    np.testing.assert_array_equal(samples.luminance, target.evaluate(u).luminance)

    steps = (2e-3, 5e-4)
    shifted = [u]
    for h in steps:
        for sign in (1, -1):
            for k in range(d):
                v = u.copy()
                v[:, k] += np.float32(sign * h)
                shifted.append(v)
    with np.errstate(divide="ignore"):
        logp = np.log(target.evaluate(np.concatenate(shifted)).luminance.astype(np.float64)).reshape(-1, n)
    base = logp[0]
    diffs = {}
    for i, h in enumerate(steps):
        plus = logp[1 + 2 * i * d : 1 + (2 * i + 1) * d].T
        minus = logp[1 + (2 * i + 1) * d : 1 + (2 * i + 2) * d].T
        with np.errstate(invalid="ignore"):
            diffs[h] = ((plus - minus) / (2 * h), (plus - base[:, None]) / h, (base[:, None] - minus) / h)
    central, forward, backward = diffs[steps[1]]
    coarse = diffs[steps[0]][0]

    def close(a, b, tol):
        return np.abs(a - b) <= tol * (1 + np.abs(b))

    with np.errstate(invalid="ignore"):
        # Smooth: finite, equal one-sided slopes (no kink, e.g. the concentric disk map's
        # diagonals) and step-size independent (no jump, e.g. visibility).
        smooth = (
            (samples.luminance > 0)
            & np.all(np.isfinite(central) & np.isfinite(coarse), axis=1)
            & np.all(close(forward, backward, 0.05) & close(coarse, central, 0.02), axis=1)
        )
    assert smooth.sum() >= n // 4, f"only {smooth.sum()} of {n} points are smooth"
    np.testing.assert_allclose(grad[smooth], central[smooth], rtol=0.02, atol=0.02)
    return int(smooth.sum())


def test_gradient_matches_finite_differences_cornell_box(cornell_smooth):
    _check_gradient(cornell_smooth, n=400, seed=1)


def test_gradient_matches_finite_differences_through_glass(mi):
    # Dielectric lobes: Mitsuba's sample weights carry parameter-gradient tricks that the
    # tracer must replace for derivatives with respect to the primary samples.
    target = PrimarySampleSpace("caustic", resolution=(RES, RES), max_depth=4, russian_roulette=False)
    _check_gradient(target, n=300, seed=2)


# --------------------------------------------------------------------------- pixels, wrapping, JAX


def test_pixel_index_matches_tracer(cornell):
    rng = np.random.default_rng(3)
    u = rng.uniform(-2, 3, (2000, cornell.dim)).astype(np.float32)
    edges = np.array([0.0, 1 / RES, 0.5, 1 - 2**-24, 1.0, -(2**-30), 7 / RES - 1], dtype=np.float32)
    u[: len(edges) ** 2, 0] = np.repeat(edges, len(edges))
    u[: len(edges) ** 2, 1] = np.tile(edges, len(edges))
    traced = cornell.evaluate(u).pixel
    assert traced.dtype == np.int32 and traced.min() >= 0 and traced.max() < cornell.num_pixels
    np.testing.assert_array_equal(np.asarray(cornell.pixel_index(jnp.asarray(u))), traced)
    np.testing.assert_array_equal(np.asarray(jax.jit(cornell.pixel_index)(jnp.asarray(u, jnp.float64))), traced)
    # The documented mapping: x = floor(u0 W), y = floor(u1 H), pixel = y W + x.
    w = np.mod(u[len(edges) ** 2 :, :2].astype(np.float64), 1.0)
    expect = np.floor(w[:, 1] * RES) * RES + np.floor(w[:, 0] * RES)
    np.testing.assert_array_equal(traced[len(edges) ** 2 :], expect.astype(np.int32))


def test_points_wrap_around_the_torus(cornell):
    u = np.random.default_rng(4).integers(0, 4096, (500, cornell.dim)) / 4096  # exact in float32
    a = cornell.evaluate(u)
    b = cornell.evaluate(u + np.random.default_rng(5).integers(-3, 4, u.shape))
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)


def test_jax_bridge_under_jit_and_vmap(cornell):
    u = np.random.default_rng(6).random((300, cornell.dim))
    samples, grad = cornell.evaluate_with_grad(u)
    ref = cornell.evaluate(u)
    np.testing.assert_array_equal(samples.luminance, ref.luminance)

    lum, rgb = jax.jit(cornell.jax_evaluate)(jnp.asarray(u))
    np.testing.assert_array_equal(np.asarray(lum), ref.luminance)
    np.testing.assert_array_equal(np.asarray(rgb), ref.rgb)

    lum_v, rgb_v = jax.jit(jax.vmap(cornell.jax_evaluate))(jnp.asarray(u))  # per-point calls, one callback
    np.testing.assert_array_equal(np.asarray(lum_v), ref.luminance)
    np.testing.assert_array_equal(np.asarray(rgb_v), ref.rgb)

    lum_g, rgb_g, grad_g = jax.jit(cornell.jax_evaluate_with_grad)(jnp.asarray(u))
    np.testing.assert_array_equal(np.asarray(lum_g), samples.luminance)
    np.testing.assert_array_equal(np.asarray(grad_g), grad)

    def total_log_density(x):
        logp = cornell.jax_log_density(x)
        return jnp.sum(jnp.where(jnp.isfinite(logp), logp, 0.0))

    np.testing.assert_allclose(np.asarray(jax.jit(jax.grad(total_log_density))(jnp.asarray(u))), grad, rtol=1e-6)


def test_evaluate_rejects_bad_points(cornell):
    with pytest.raises(ValueError, match=r"shape \(N, 20\)"):
        cornell.evaluate(np.zeros((4, 3)))
    bad = np.full((2, cornell.dim), 0.5)
    bad[1, 3] = np.nan
    with pytest.raises(ValueError, match="finite"):
        cornell.evaluate(bad)
    assert cornell.evaluate(np.zeros((0, cornell.dim))).luminance.shape == (0,)


# --------------------------------------------------------------------------- scenes and errors


def test_registry_scenes_load_with_box_filter(mi):
    for name, build in SCENES.items():
        scene = load_scene(name, resolution=(8, 6), max_depth=2)
        film = scene.sensors()[0].film()
        assert film.rfilter().class_name() == "BoxFilter", name
        assert tuple(film.crop_size()) == (8, 6), name
        assert build(resolution=(8, 6), max_depth=2)["integrator"] == {"type": "path", "max_depth": 2}
    # The door-ajar room never sees its light directly, and few pixels receive direct light.
    door = PrimarySampleSpace("door_ajar", resolution=(RES, RES), max_depth=2)
    direct = door.render_uniform(8, seed=7)
    assert np.all(PrimarySampleSpace(door.scene, max_depth=1).render_uniform(2) == 0)
    assert 0 < np.mean(direct.sum(-1) > 0) < 0.3


def test_xml_scene_gets_box_filter_and_overrides(mi, tmp_path):
    path = tmp_path / "scene.xml"
    path.write_text(xml_scene(32, 24, 5))
    target = PrimarySampleSpace(path, resolution=(8, 4))
    assert target.resolution == (8, 4) and target.max_depth == 5 and target.dim == dimension(5)
    assert target.scene.sensors()[0].film().rfilter().class_name() == "BoxFilter"
    assert PrimarySampleSpace(str(path), max_depth=2).max_depth == 2


def test_scene_errors(mi, tmp_path):
    missing = tmp_path / "nowhere.xml"
    with pytest.raises(FileNotFoundError, match="nowhere.xml"):
        load_scene(missing)
    broken = tmp_path / "broken.xml"
    broken.write_text('<scene version="3.0.0">\n  <shape type="sphere"><bsdf type="diffuse"/>\n</scene>\n')
    with pytest.raises(ValueError, match=r"broken\.xml.*(mismatch|[Pp]ars)") as info:
        load_scene(broken)
    assert "Mitsuba could not load" in str(info.value)
    with pytest.raises(ValueError, match="cornell_box"):
        load_scene("cornel_box")
    with pytest.raises(ValueError, match="max_depth"):
        PrimarySampleSpace("cornell_box", resolution=(4, 4), max_depth=0)


def test_delta_lights_are_rejected_for_gradients(mi, cornell):
    cornell.check_gradient_support()  # an area light is fine
    scene = cornell_box(resolution=(8, 8), max_depth=3)
    del scene["light"]
    scene["bulb"] = {"type": "point", "position": [0.0, 0.9, 0.0], "intensity": {"type": "rgb", "value": 5.0}}
    target = PrimarySampleSpace(scene)
    assert target.evaluate(np.full((4, target.dim), 0.5)).luminance.shape == (4,)
    with pytest.raises(UnsupportedSceneError, match="PointLight.*area light"):
        target.check_gradient_support()


def test_unsupported_camera_is_rejected(mi):
    scene = cornell_box(resolution=(8, 8), max_depth=2)
    scene["sensor"]["type"] = "thinlens"
    scene["sensor"]["aperture_radius"] = 0.1
    with pytest.raises(UnsupportedSceneError, match="aperture"):
        PrimarySampleSpace(scene)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda scene: scene.update(integrator={"type": "volpath", "max_depth": 3}), r"`volpath` integrator"),
        (lambda scene: scene.update(integrator={"type": "direct"}), r"`direct` integrator"),
        (lambda scene: scene["small-box"].update(interior={"type": "homogeneous", "sigma_t": 1.0}), r"participating media \(Homog"),
        (lambda scene: scene["sensor"].update(medium={"type": "homogeneous", "sigma_t": 0.1}), r"participating media .*Camera"),
    ],
    ids=["volpath", "direct", "interior medium", "sensor medium"],
)
def test_light_transport_the_tracer_does_not_model_is_refused(mi, change, message):
    """Another integrator or participating media would be traced as plain `path`: refused, naming the feature."""
    scene = cornell_box(resolution=(8, 8), max_depth=3)
    change(scene)
    with pytest.raises(UnsupportedSceneError, match=message):
        PrimarySampleSpace(scene)
    with pytest.raises(UnsupportedSceneError, match=message):  # Mitsuba's own path tracer would ignore it too
        render_native(mi.load_dict(scene), 1)


def test_scene_changes_are_reported(mi, tmp_path):
    notes = []
    load_scene("cornell_box", (8, 8), 2, log=notes.append)
    assert notes == []  # a built-in scene is ours to set
    scene = cornell_box(resolution=(8, 6), max_depth=3)
    scene["sensor"]["film"]["rfilter"] = {"type": "gaussian"}
    load_scene(scene, log=notes.append)
    assert notes == ["the film's gaussian reconstruction filter is replaced by a box filter (each path lands in one pixel)"]
    notes.clear()
    load_scene(scene, (8, 6), 4, log=notes.append)
    assert notes[1:] == ["maximum path depth 4 replaces the scene's 3"]


def test_find_libllvm_explains_what_to_install(monkeypatch, tmp_path):
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(tmp_path / "libLLVM-missing.so"))
    monkeypatch.setattr(_llvm, "SYSTEM_LIB_DIRS", (str(tmp_path),))
    monkeypatch.setattr(_llvm, "_karellen_libraries", lambda: [])
    (tmp_path / "libLLVM-15.so.1").write_bytes(b"")  # too old: crashes Dr.Jit
    with pytest.raises(LLVMNotFoundError) as info:
        find_libllvm()
    message = str(info.value)
    assert "libLLVM-missing.so" in message
    assert "pip install 'restore-mcmc[mitsuba]'" in message
    assert "DRJIT_LIBLLVM_PATH" in message and ">= 16" in message
    assert isinstance(info.value, RuntimeError)


def test_a_missing_libllvm_is_named_in_the_skip_reason(monkeypatch):
    import targets.mitsuba

    def missing(variant):
        raise LLVMNotFoundError("Dr.Jit's CPU backend needs a shared libLLVM")

    monkeypatch.setattr(targets.mitsuba, "load_mitsuba", missing)
    with pytest.raises(pytest.skip.Exception, match="libLLVM is missing"):
        mitsuba_or_skip()


def test_find_libllvm_search_order(monkeypatch, tmp_path):
    for name in ("libLLVM-15.so", "libLLVM.so.19.1", "libLLVM-17.so"):
        (tmp_path / name).write_bytes(b"")
    karellen = tmp_path / "wheel" / "libLLVM.so.23.1"
    karellen.parent.mkdir()
    karellen.write_bytes(b"")
    monkeypatch.setattr(_llvm, "SYSTEM_LIB_DIRS", (str(tmp_path),))
    monkeypatch.setattr(_llvm, "_karellen_libraries", lambda: [karellen])
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    assert find_libllvm() == tmp_path / "libLLVM.so.19.1"  # newest system library >= 16
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", str(tmp_path / "libLLVM-15.so"))
    assert find_libllvm() == tmp_path / "libLLVM-15.so"  # an explicit choice is honoured
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", "")
    monkeypatch.setattr(_llvm, "SYSTEM_LIB_DIRS", (str(tmp_path / "empty"),))
    assert find_libllvm() == karellen


# --------------------------------------------------------------------------- native renders and timing


def test_reference_image_is_cached(mi, tmp_path):
    first = reference_image("cornell_box", 4, resolution=(8, 8), max_depth=2, cache_dir=tmp_path)
    files = list(tmp_path.glob("*.exr"))
    assert len(files) == 1 and first.shape == (8, 8, 3)
    os.utime(files[0], (0, 0))
    again = reference_image("cornell_box", 4, resolution=(8, 8), max_depth=2, cache_dir=tmp_path)
    np.testing.assert_array_equal(again, first)
    assert files[0].stat().st_mtime == 0  # read back, not re-rendered
    reference_image("cornell_box", 8, resolution=(8, 8), max_depth=2, cache_dir=tmp_path)
    assert len(list(tmp_path.glob("*.exr"))) == 2  # another key for another spp
    assert not list(Path(tmp_path).glob(".*"))  # no temporary files left


def test_render_native_for_spends_the_time(mi):
    scene = load_scene("cornell_box", resolution=(8, 8), max_depth=2)
    render_native(scene, 2, max_depth=2)  # warm kernels, as the docstring asks
    passes = []
    result = render_native_for(scene, 0.5, pass_paths=128, on_update=lambda image, t: passes.append(t))  # 2 spp a pass
    # whole passes while time is left, then passes sized to the rest: it ends near the budget
    assert 0.35 <= result.seconds < 1.5 and result.spp >= 2 * (len(passes) - 1) and len(passes) >= 2
    assert result.image.shape == (8, 8, 3) and np.all(np.isfinite(result.image))


def test_report_paths_per_second(mi):
    """PSS target vs native `path` throughput on the Cornell box (printed, not asserted)."""
    target = PrimarySampleSpace("cornell_box", resolution=(64, 64), max_depth=4)
    pss = target.paths_per_second(n=1 << 16, repeats=2)
    native = native_paths_per_second(target.scene, spp=16, max_depth=4, repeats=2)
    print(f"\nCornell box 64x64, max_depth 4: PSS {pss:,.0f} paths/s, native {native:,.0f} paths/s, "
          f"ratio {pss / native:.2f}")
    assert pss > 0 and native > 0


def test_cuda_variant_is_preferred_only_when_built_and_usable(mi, monkeypatch):
    class FakeMitsuba:
        def __init__(self, variants):
            self._variants = variants

        def variants(self):
            return self._variants

    import drjit as dr

    built = FakeMitsuba(["scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb"])
    for usable, expected in ((True, "cuda_ad_rgb"), (False, "llvm_ad_rgb")):
        monkeypatch.setattr(_llvm, "_has_backend", lambda dr, name, usable=usable: name == "LLVM" or usable)
        assert _llvm.preferred_variant(built, dr) == expected
    assert _llvm.preferred_variant(FakeMitsuba(["scalar_rgb", "llvm_ad_rgb"]), dr) == "llvm_ad_rgb"
