"""Mitsuba's own `path` integrator: baseline renders, throughput, and cached references.

These are the yardsticks for the primary-sample-space estimators: equal-time native
renders (`render_native_for`), native path throughput (`native_paths_per_second`), and
high-spp reference images cached as EXR files (`reference_image`).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from restore._io import atomic_write

from ._llvm import load_mitsuba
from ._scene_checks import check_path_model, path_settings
from ._scenes import DEFAULT_MAX_DEPTH, is_scene_file, load_scene, scene_dict

MAX_LANES = 1 << 22  # paths per native render call (bounds memory)
CACHE_ENV_VAR = "RESTORE_CACHE_DIR"


class NativeRender(NamedTuple):
    """An equal-time native render: the average `image (H, W, 3)`, its total `spp` and `seconds`.

    `interrupted` is true when Ctrl-C stopped the render early; the image then averages
    the passes that finished.
    """

    image: np.ndarray
    spp: int
    seconds: float
    interrupted: bool = False


def render_native(scene: Any, spp: int, seed: int = 0, max_depth: int | None = None) -> np.ndarray:
    """Render `scene` with Mitsuba's `path` integrator; returns an `(H, W, 3)` float32 image.

    Arguments:
        scene: an `mi.Scene`.
        spp: samples per pixel (split into passes of at most `MAX_LANES` paths, each with
            its own seed derived from `seed`, and averaged).
        seed: the sampler seed of the first pass.
        max_depth: the integrator's maximum depth; `None` uses the scene's `path`
            integrator (Russian roulette starts at the scene's `rr_depth` either way).
    """
    mi = load_mitsuba()
    spp = _positive_int(spp, "spp")
    integrator = _integrator(mi, scene, max_depth)
    width, height = (int(v) for v in scene.sensors()[0].film().crop_size())
    per_pass = max(1, min(spp, MAX_LANES // (width * height)))
    total = np.zeros((height, width, 3), dtype=np.float64)
    done, pass_index = 0, 0
    while done < spp:
        n = min(per_pass, spp - done)
        image = mi.render(scene, integrator=integrator, spp=n, seed=_pass_seed(seed, pass_index))
        total += n * np.array(image, dtype=np.float64)[..., :3]
        done += n
        pass_index += 1
    return (total / spp).astype(np.float32)


def render_native_for(
    scene: Any,
    seconds: float,
    *,
    max_depth: int | None = None,
    pass_paths: int = 1 << 20,
    seed: int = 0,
    on_update: Callable[[np.ndarray, float], None] | None = None,
) -> NativeRender:
    """Render for `seconds` of wall time at full speed; returns the average image.

    Passes of about `pass_paths` paths (a whole number of samples per pixel, fresh seeds)
    run until less than one pass of time is left; a last pass sized from the measured
    rate then fills the rest, so the render ends close to `seconds` and never wastes the
    tracer on small batches. Call it once with warm kernels (e.g. after `render_native`
    with one pass) to keep compilation out of the time.

    `on_update(image_so_far, elapsed_seconds)`, if given, is called after every pass
    (its own time counts towards `seconds`). Ctrl-C stops the render and returns the
    passes that finished, marked `interrupted`."""
    mi = load_mitsuba()
    pass_paths = _positive_int(pass_paths, "pass_paths")
    if not seconds > 0:
        raise ValueError(f"seconds must be positive, got {seconds!r}")
    integrator = _integrator(mi, scene, max_depth)
    width, height = (int(v) for v in scene.sensors()[0].film().crop_size())
    pass_spp = max(1, pass_paths // (width * height))
    total, spp, passes = None, 0, 0
    start = time.perf_counter()
    try:
        n = pass_spp
        while n >= 1:
            image = mi.render(scene, integrator=integrator, spp=n, seed=_pass_seed(seed, passes))
            image = np.array(image, dtype=np.float64)[..., :3] * n
            # committed together, so that Ctrl-C never leaves a pass half counted
            total, spp, passes = (image if total is None else total + image), spp + n, passes + 1
            if on_update is not None:
                on_update((total / spp).astype(np.float32), time.perf_counter() - start)
            elapsed = time.perf_counter() - start
            left, per_spp = seconds - elapsed, elapsed / spp
            n = pass_spp if left >= 2 * pass_spp * per_spp else int(left / per_spp)
        assert total is not None  # the first pass always runs
        return NativeRender((total / spp).astype(np.float32), spp, time.perf_counter() - start)
    except KeyboardInterrupt:
        if total is None:
            raise  # nothing finished to keep
        return NativeRender((total / spp).astype(np.float32), spp, time.perf_counter() - start, interrupted=True)


def native_paths_per_second(
    scene: Any, spp: int = 16, *, max_depth: int | None = None, repeats: int = 3
) -> float:
    """Camera paths per second of Mitsuba's `path` integrator (best of `repeats`, after a warm-up)."""
    mi = load_mitsuba()
    integrator = _integrator(mi, scene, max_depth)
    width, height = (int(v) for v in scene.sensors()[0].film().crop_size())
    mi.render(scene, integrator=integrator, spp=spp, seed=0)  # compile
    best = np.inf
    for r in range(_positive_int(repeats, "repeats")):
        start = time.perf_counter()
        np.array(mi.render(scene, integrator=integrator, spp=spp, seed=r + 1))
        best = min(best, time.perf_counter() - start)
    return width * height * spp / best


def reference_image(
    scene: str | Path | Mapping[str, Any],
    spp: int,
    *,
    resolution: Sequence[int] | None = None,
    max_depth: int | None = None,
    cache_dir: str | Path | None = None,
    seed: int = 0,
) -> np.ndarray:
    """A high-spp native `path` render of `scene`, cached as an EXR file.

    The cache file lives under `cache_dir`, else `$RESTORE_CACHE_DIR/references`, else
    `~/.cache/restore/references`, named by a hash of the scene (its parameters, or the
    XML file's bytes), the overrides, `spp`, `seed` and the Mitsuba version. It is written
    atomically (temporary file, then rename), so concurrent runs never read half a file.

    Arguments:
        scene: a registry name, a scene dictionary or an XML path (see `load_scene`).
        spp: samples per pixel of the reference.
        resolution: film size override passed to `load_scene`.
        max_depth: maximum path depth override passed to `load_scene`.
        cache_dir: the cache folder (see above).
        seed: the sampler seed of the render (part of the cache key).

    Returns:
        The `(H, W, 3)` float32 image.
    """
    mi = load_mitsuba()
    spp = _positive_int(spp, "spp")
    key = _reference_key(mi, scene, spp, resolution, max_depth, seed)
    folder = _cache_folder(cache_dir)
    path = folder / f"{key}.exr"
    if path.is_file():
        return read_exr(path)
    loaded = load_scene(scene, resolution, max_depth)
    image = render_native(loaded, spp, seed=seed, max_depth=max_depth)
    folder.mkdir(parents=True, exist_ok=True)
    write_exr(path, image)
    return image


def write_exr(path: str | Path, image: np.ndarray) -> Path:
    """Write a linear `(H, W, 3)` image as EXR, atomically (temporary file beside it, then rename)."""
    mi = load_mitsuba()
    image = np.ascontiguousarray(image, dtype=np.float32)
    with _exr_threads():
        return atomic_write(path, lambda tmp: mi.util.write_bitmap(str(tmp), image, write_async=False))


def read_exr(path: str | Path) -> np.ndarray:
    """Read an EXR image as `(H, W, 3)` float32."""
    mi = load_mitsuba()
    with _exr_threads():
        return np.array(mi.Bitmap(str(path)), dtype=np.float32)[..., :3]


@contextlib.contextmanager
def _exr_threads() -> Iterator[None]:
    """At least two Dr.Jit worker threads while OpenEXR runs.

    Mitsuba's OpenEXR reader and writer wait on its thread pool and deadlock when the
    pool has a single thread (Dr.Jit sizes it by the CPU affinity, e.g. under `taskset -c 1`).
    """
    import drjit as dr

    threads = dr.thread_count()
    if threads >= 2:
        yield
        return
    dr.set_thread_count(2)
    try:
        yield
    finally:
        dr.set_thread_count(threads)


# --------------------------------------------------------------------------- helpers


def _integrator(mi: Any, scene: Any, max_depth: int | None) -> Any:
    """A `path` integrator: the scene's own, or one with `max_depth` and the scene's `rr_depth`.

    A scene with another integrator or with participating media is refused
    (`UnsupportedSceneError`): a `path` render of it would not be the scene's image.
    """
    check_path_model(scene)
    settings = path_settings(scene)
    if max_depth is None:
        if scene.integrator() is not None and scene.integrator().class_name() == "PathIntegrator":
            return scene.integrator()
        max_depth = settings.max_depth or DEFAULT_MAX_DEPTH
    return mi.load_dict(
        {"type": "path", "max_depth": _positive_int(max_depth, "max_depth"), "rr_depth": settings.rr_depth}
    )


def _pass_seed(seed: int, index: int) -> int:
    return (int(seed) * 1_000_003 + index) & 0x7FFFFFFF


def _positive_int(value: Any, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def _cache_folder(cache_dir: str | Path | None) -> Path:
    if cache_dir is not None:
        return Path(cache_dir).expanduser()
    root = os.environ.get(CACHE_ENV_VAR)
    base = Path(root).expanduser() if root else Path.home() / ".cache" / "restore"
    return base / "references"


def _reference_key(mi: Any, scene: Any, spp: int, resolution: Any, max_depth: Any, seed: int) -> str:
    digest = hashlib.sha256()
    digest.update(f"mitsuba={mi.__version__};variant={mi.variant()};spp={spp};seed={seed};".encode())
    if is_scene_file(scene):
        path = Path(scene).expanduser()
        if not path.is_file():
            raise FileNotFoundError(f"Mitsuba scene file not found: {str(path)!r}")
        digest.update(b"xml:" + str(path.resolve()).encode() + b":" + path.read_bytes())
        digest.update(repr((resolution, max_depth)).encode())
        name = path.stem
    else:
        _fingerprint(mi, scene_dict(scene, resolution, max_depth), digest)
        name = scene if isinstance(scene, str) else "scene"
    return f"{name}-spp{spp}-{digest.hexdigest()[:20]}"


def _fingerprint(mi: Any, obj: Any, digest: Any) -> None:
    """Feed a canonical description of a scene dictionary (values, not identities) to `digest`."""
    if isinstance(obj, Mapping):
        digest.update(b"{")
        for k in sorted(obj, key=str):
            digest.update(repr(k).encode() + b":")
            _fingerprint(mi, obj[k], digest)
        digest.update(b"}")
    elif isinstance(obj, (list, tuple)):
        digest.update(b"[")
        for v in obj:
            _fingerprint(mi, v, digest)
        digest.update(b"]")
    elif isinstance(obj, (str, int, float, bool, type(None))):
        digest.update(repr(obj).encode() + b";")
    elif isinstance(obj, np.ndarray):
        digest.update(obj.tobytes() + repr(obj.shape).encode())
    elif hasattr(obj, "matrix"):  # a transform
        digest.update(np.array(obj.matrix, dtype=np.float64).tobytes())
    elif isinstance(obj, mi.Object):  # e.g. an mi.Mesh: hash its parameters' values
        digest.update(type(obj).__name__.encode())
        params = mi.traverse(obj)
        for k in sorted(params.keys()):
            digest.update(k.encode())
            try:
                digest.update(np.array(params[k]).tobytes())
            except Exception:
                digest.update(repr(params[k]).encode())
        digest.update(str(obj).encode())
    else:
        digest.update(repr(obj).encode())
