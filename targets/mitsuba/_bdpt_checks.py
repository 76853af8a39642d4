"""What the bidirectional tracer supports: a pinhole camera, area lights sampled uniformly.

On top of what the path tracer needs (`check_tracer_support`), light tracing connects
to the camera through its importance, which is only written for Mitsuba's pinhole
`perspective` camera over an uncropped film; light subpaths start on area emitters
(uniform emitter choice, uniform position, cosine-weighted direction).
"""

from __future__ import annotations

from typing import Any

from ._scene_checks import UnsupportedSceneError, check_tracer_support


def check_bdpt_support(scene: Any) -> None:
    """Raise `UnsupportedSceneError` unless the bidirectional tracer handles the scene exactly."""
    import mitsuba as mi

    check_tracer_support(scene)
    sensor = scene.sensors()[0]
    if sensor.class_name() != "PerspectiveCamera":
        raise UnsupportedSceneError(
            f"bidirectional path tracing needs a pinhole `perspective` camera, not {sensor.class_name()}"
        )
    film = sensor.film()
    if tuple(film.crop_size()) != tuple(film.size()) or any(int(v) != 0 for v in film.crop_offset()):
        raise UnsupportedSceneError("bidirectional path tracing needs an uncropped film (no crop window)")
    emitters = list(scene.emitters())
    if not emitters:
        raise UnsupportedSceneError("the scene has no emitter")
    others = [e.class_name() for e in emitters if e.class_name() != "AreaLight"]
    if others:
        raise UnsupportedSceneError(
            f"bidirectional path tracing supports area emitters only, found {', '.join(sorted(set(others)))}; "
            "replace point, spot, directional and environment lights by emitting shapes"
        )
    n = len(emitters)
    pmf = [float(scene.pdf_emitter(mi.UInt32(i))[0]) for i in range(n)]
    if max(abs(p * n - 1) for p in pmf) > 1e-5:
        raise UnsupportedSceneError(
            "bidirectional path tracing needs emitters chosen uniformly; remove the emitters' `sampling_weight`"
        )
