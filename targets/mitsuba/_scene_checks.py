"""What the primary-sample-space tracer supports in a loaded scene, and the scene's path settings.

The tracer models a pinhole-like camera (no aperture or time samples), a box-filtered
film (one pixel per path) and Mitsuba's `path` integrator, without participating media.
Delta lights (point, spot, directional) are fine for evaluation but not for
gradient-based moves.
"""

from __future__ import annotations

import re
from typing import Any, NamedTuple

from ._path_tracer import DEFAULT_RR_DEPTH


class UnsupportedSceneError(ValueError):
    """The scene uses a feature the primary-sample-space target cannot handle."""


class PathSettings(NamedTuple):
    """The `path` integrator settings of a scene (`max_depth` is `None` if unbounded or unknown)."""

    max_depth: int | None
    rr_depth: int


_UNBOUNDED = 1 << 30


def path_settings(scene: Any) -> PathSettings:
    """`max_depth` and `rr_depth` of the scene's integrator if it is a `path` integrator.

    Mitsuba does not expose them as attributes; they are read from the integrator's
    description. Other integrators give `(None, 5)` (Mitsuba's default `rr_depth`).
    """
    integrator = scene.integrator()
    if integrator is None or integrator.class_name() != "PathIntegrator":
        return PathSettings(None, DEFAULT_RR_DEPTH)
    text = str(integrator)
    max_depth = _read_int(text, "max_depth")
    rr_depth = _read_int(text, "rr_depth")
    if max_depth is not None and (max_depth < 1 or max_depth >= _UNBOUNDED):
        max_depth = None
    return PathSettings(max_depth, DEFAULT_RR_DEPTH if rr_depth is None else rr_depth)


def check_tracer_support(scene: Any) -> None:
    """Raise `UnsupportedSceneError` unless the tracer reproduces the scene's camera and film."""
    sensors = scene.sensors()
    if len(sensors) == 0:
        raise UnsupportedSceneError("the scene has no sensor (camera)")
    sensor = sensors[0]
    if sensor.needs_aperture_sample():
        raise UnsupportedSceneError(
            f"the camera ({sensor.class_name()}) needs aperture samples (depth of field); "
            "use a pinhole `perspective` or `orthographic` camera"
        )
    if sensor.shutter_open_time() > 0:
        raise UnsupportedSceneError(
            "the camera has a non-zero shutter time (motion blur); set shutter_close = shutter_open"
        )
    film = sensor.film()
    rfilter = film.rfilter()
    if rfilter.class_name() != "BoxFilter" or film.sample_border():
        raise UnsupportedSceneError(
            f"the film uses a {rfilter.class_name()} reconstruction filter; the primary-sample-space "
            "target needs a box filter ({'type': 'box'}) so that each path lands in one pixel "
            "(`load_scene` sets it automatically)"
        )
    check_path_model(scene)
    integrator = scene.integrator()
    if integrator is not None and getattr(integrator, "hide_emitters", False):
        raise UnsupportedSceneError("the integrator hides directly visible emitters (hide_emitters); not supported")
    width, height = (int(v) for v in film.crop_size())
    if width * height >= MAX_PIXELS:
        raise UnsupportedSceneError(
            f"the film has {width} x {height} pixels; pixel indices are int32, so at most {MAX_PIXELS - 1:,} "
            "pixels are supported (pass a smaller resolution)"
        )
    _check_camera_rays(sensor)


#: Mitsuba's plugin names of its integrators, by class name (for messages).
_INTEGRATOR_PLUGINS = {
    "VolumetricPathIntegrator": "volpath",
    "VolumetricMISPathIntegrator": "volpathmis",
    "DirectIntegrator": "direct",
    "AOVIntegrator": "aov",
    "ParticleTracerIntegrator": "ptracer",
    "PRBIntegrator": "prb",
    "PRBVolpathIntegrator": "prbvolpath",
    "MomentIntegrator": "moment",
    "StokesIntegrator": "stokes",
    "DepthIntegrator": "depth",
}


def check_path_model(scene: Any) -> None:
    """Raise `UnsupportedSceneError` unless the scene's light transport is what the tracer
    computes: Mitsuba's `path` integrator, with no participating media.

    Any other integrator (`volpath`, `direct`, `ptracer`, ...) would otherwise be traced
    as `path` without a word, and media would be ignored (as `path` ignores them).
    """
    integrator = scene.integrator()
    if integrator is not None and integrator.class_name() != "PathIntegrator":
        name = integrator.class_name()
        plugin = _INTEGRATOR_PLUGINS.get(name)
        described = f"the `{plugin}` integrator ({name})" if plugin else f"a {name}"
        raise UnsupportedSceneError(
            f"the scene uses {described}; the primary-sample-space tracer reproduces Mitsuba's `path` "
            "integrator only (no volumes, no other estimators): use <integrator type=\"path\"> "
            "(or {'type': 'path'} in a scene dictionary)"
        )
    media = participating_media(scene)
    if media:
        raise UnsupportedSceneError(
            f"the scene has participating media ({', '.join(media)}); the primary-sample-space tracer, like "
            "Mitsuba's `path` integrator, ignores them, so the image would not be the scene's: remove the "
            "media (interior/exterior media of shapes, the sensor's or emitters' medium)"
        )


def participating_media(scene: Any) -> list[str]:
    """Where the scene has participating media: shapes' interiors and exteriors, sensors, emitters."""
    found = []

    def describe(obj: Any, what: str) -> str:
        name = obj.id() if hasattr(obj, "id") else ""
        return f"{what} '{name}'" if name else what

    for shape in scene.shapes():
        for side in ("interior", "exterior"):
            medium = getattr(shape, f"{side}_medium", lambda: None)()
            if medium is not None:
                found.append(f"{medium.class_name()} as the {side} of {describe(shape, shape.class_name())}")
    for endpoint in list(scene.sensors()) + list(scene.emitters()):
        medium = endpoint.get_medium() if hasattr(endpoint, "get_medium") else None
        if medium is not None:
            found.append(f"{medium.class_name()} around {describe(endpoint, endpoint.class_name())}")
    return found


#: Pixel indices `y W + x` are int32 (NumPy and JAX images).
MAX_PIXELS = 1 << 31


def _check_camera_rays(sensor: Any) -> None:
    """The camera must produce finite rays: Mitsuba accepts e.g. a NaN field of view or a
    singular `to_world`, whose NaN rays would silently give a black image."""
    import drjit as dr
    import mitsuba as mi

    corners = [(0.5, 0.5), (0.0, 0.0), (1.0, 1.0)]
    film_pos = mi.Point2f([c[0] for c in corners], [c[1] for c in corners])
    ray, _ = sensor.sample_ray(time=sensor.shutter_open(), sample1=0.5, sample2=film_pos, sample3=mi.Point2f(0.5))
    finite = dr.isfinite(ray.o.x) & dr.isfinite(ray.o.y) & dr.isfinite(ray.o.z)
    finite &= dr.isfinite(ray.d.x) & dr.isfinite(ray.d.y) & dr.isfinite(ray.d.z)
    if not bool(dr.all(finite)):
        raise UnsupportedSceneError(
            f"the camera ({sensor.class_name()}) produces non-finite rays; check its field of view "
            "(fov), near/far clip and to_world transform"
        )


def delta_emitters(scene: Any) -> list[str]:
    """Descriptions of the scene's delta emitters (point, spot, directional, ...)."""
    import mitsuba as mi

    found = []
    for emitter in scene.emitters():
        if mi.has_flag(emitter.flags(), mi.EmitterFlags.Delta):
            name = emitter.id()
            found.append(f"{emitter.class_name()}" + (f" '{name}'" if name else ""))
    return found


def check_gradient_support(scene: Any) -> None:
    """Raise `UnsupportedSceneError` if the scene has delta emitters.

    A delta light is reached only by next-event estimation, never by a BSDF-sampled
    direction, so light paths through specular chains (caustics) have zero contribution
    and the path contribution jumps where a shadow ray's visibility changes; area lights
    are needed for gradient-based moves in primary sample space.
    """
    deltas = delta_emitters(scene)
    if deltas:
        raise UnsupportedSceneError(
            f"the scene has delta light sources ({', '.join(deltas)}), which gradient-based methods "
            "in primary sample space cannot handle; replace them with small area lights "
            "(e.g. an emitting rectangle or sphere)"
        )


def _read_int(text: str, key: str) -> int | None:
    match = re.search(rf"\b{key}\s*=\s*(-?\d+)", text)
    return int(match.group(1)) if match else None
