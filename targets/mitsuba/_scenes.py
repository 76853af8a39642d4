"""Test scenes for the primary-sample-space target, built as Mitsuba scene dictionaries.

Every scene is made in code (nothing is downloaded), renders with the `path` integrator
at a given `max_depth`, and uses an `hdrfilm` with a *box* reconstruction filter, so that
each camera path contributes to exactly one pixel. Only area lights are used: a delta
light (point, spot, directional) would make caustics impossible for a path tracer and
breaks gradient-based moves.

`load_scene` accepts a registry name, a scene dictionary or the path of a Mitsuba XML file.
"""

from __future__ import annotations

import copy
import logging
import os
import tempfile
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any
from xml.etree import ElementTree

import numpy as np

from ._llvm import load_mitsuba

DEFAULT_RESOLUTION = (128, 128)
DEFAULT_MAX_DEPTH = 8


# --------------------------------------------------------------------------- helpers


def _mi() -> Any:
    return load_mitsuba()


def _film(resolution: Sequence[int]) -> dict[str, Any]:
    width, height = _resolution(resolution)
    return {
        "type": "hdrfilm",
        "width": width,
        "height": height,
        "rfilter": {"type": "box"},
        "pixel_format": "rgb",
        "component_format": "float32",
    }


def _resolution(resolution: Sequence[int]) -> tuple[int, int]:
    try:
        width, height = (int(r) for r in resolution)
    except (TypeError, ValueError) as err:
        raise ValueError(f"resolution must be a pair (width, height), got {resolution!r}") from err
    if width < 1 or height < 1 or (width, height) != tuple(resolution):
        raise ValueError(f"resolution must be two positive integers, got {resolution!r}")
    return width, height


def _max_depth(max_depth: int) -> int:
    if isinstance(max_depth, bool) or not isinstance(max_depth, (int, np.integer)) or max_depth < 1:
        raise ValueError(f"max_depth must be an integer >= 1, got {max_depth!r}")
    return int(max_depth)


def _camera(mi: Any, resolution: Sequence[int], origin, target, fov: float, spp: int = 16) -> dict[str, Any]:
    return {
        "type": "perspective",
        "fov": fov,
        "fov_axis": "smaller",
        "near_clip": 0.001,
        "far_clip": 100.0,
        "to_world": mi.ScalarTransform4f().look_at(origin=origin, target=target, up=[0, 1, 0]),
        "sampler": {"type": "independent", "sample_count": spp},
        "film": _film(resolution),
    }


def _diffuse(rgb: Sequence[float], two_sided: bool = True) -> dict[str, Any]:
    bsdf = {"type": "diffuse", "reflectance": {"type": "rgb", "value": list(rgb)}}
    return {"type": "twosided", "bsdf": bsdf} if two_sided else bsdf


def _quad(mi: Any, center, half_u, half_v, bsdf: dict[str, Any], emitter: dict | None = None) -> dict[str, Any]:
    """A rectangle `center + s half_u + t half_v`, `s, t in [-1, 1]`; normal along `half_u x half_v`."""
    c, u, v = (np.asarray(a, dtype=float) for a in (center, half_u, half_v))
    n = np.cross(u, v)
    n /= np.linalg.norm(n)
    matrix = np.eye(4)
    matrix[:3, 0], matrix[:3, 1], matrix[:3, 2], matrix[:3, 3] = u, v, n, c
    shape = {"type": "rectangle", "to_world": mi.ScalarTransform4f(matrix.tolist()), "bsdf": bsdf}
    if emitter is not None:
        shape["emitter"] = emitter
    return shape


def _area_light(radiance: Sequence[float]) -> dict[str, Any]:
    return {"type": "area", "radiance": {"type": "rgb", "value": list(radiance)}}


def _path_integrator(max_depth: int) -> dict[str, Any]:
    return {"type": "path", "max_depth": _max_depth(max_depth)}


# --------------------------------------------------------------------------- scenes


def cornell_box(
    *, resolution: Sequence[int] = DEFAULT_RESOLUTION, max_depth: int = DEFAULT_MAX_DEPTH
) -> dict[str, Any]:
    """Mitsuba's classic Cornell box (`mi.cornell_box()`) with a box filter.

    Camera: at `(0, 0, 3.9)` looking down `-z` into the open side of the box (red wall on
    the left, green on the right, the small ceiling light visible at the top).
    """
    mi = _mi()
    scene = mi.cornell_box()
    scene["sensor"]["film"] = _film(resolution)
    scene["integrator"] = _path_integrator(max_depth)
    return scene


def door_ajar(
    *,
    resolution: Sequence[int] = DEFAULT_RESOLUTION,
    max_depth: int = DEFAULT_MAX_DEPTH,
    door_angle: float = 15.0,
    glossy: bool = False,
) -> dict[str, Any]:
    """A dark room lit only through a door left ajar into a lit neighbouring room.

    Geometry (y up, all rectangles, two-sided diffuse): the dark room spans
    `x in [-2, 2], y in [0, 2.5], z in [0, 4]`; the lit room `z in [-3, 0]`. They share the
    wall `z = 0`, which has a doorway `x in [0.4, 1.2], y in [0, 2]`; the door, hinged at
    `x = 1.2`, is opened `door_angle` degrees (default 15) into the lit room. An area light
    on the lit room's ceiling, out of sight of the camera, faces down. Camera: inside the
    dark room at `(-1.6, 1.4, 3.8)` looking at the door, `(0.6, 0.9, 0)`; almost every pixel
    receives light only after several bounces through the gap. With `glossy`, the dark
    room's floor is a rough plastic (GGX, alpha 0.08) and the door rough aluminium (alpha
    0.15), so that light through the gap also travels along narrow glossy lobes.
    """
    door_angle = float(door_angle)
    if not 0 < door_angle <= 90:
        raise ValueError(f"door_angle must lie in (0, 90] degrees, got {door_angle!r}")
    mi = _mi()
    white, grey, door = _diffuse([0.8, 0.8, 0.8]), _diffuse([0.6, 0.6, 0.55]), _diffuse([0.55, 0.35, 0.2])
    x0, x1, h, z_dark, z_lit = -2.0, 2.0, 2.5, 4.0, -3.0
    door_lo, door_hi, door_h = 0.4, 1.2, 2.0
    cx, w = 0.5 * (x0 + x1), 0.5 * (x1 - x0)

    def box_walls(prefix: str, z_a: float, z_b: float) -> dict[str, Any]:
        cz, d = 0.5 * (z_a + z_b), 0.5 * abs(z_b - z_a)
        return {
            f"{prefix}-floor": _quad(mi, [cx, 0, cz], [w, 0, 0], [0, 0, -d], white),
            f"{prefix}-ceiling": _quad(mi, [cx, h, cz], [w, 0, 0], [0, 0, d], white),
            f"{prefix}-left": _quad(mi, [x0, h / 2, cz], [0, 0, d], [0, h / 2, 0], grey),
            f"{prefix}-right": _quad(mi, [x1, h / 2, cz], [0, h / 2, 0], [0, 0, d], grey),
            f"{prefix}-end": _quad(mi, [cx, h / 2, z_b], [w, 0, 0], [0, h / 2, 0], white),
        }

    angle = np.deg2rad(door_angle)
    half_door = 0.5 * (door_hi - door_lo)
    # The door swings about its hinge (x = door_hi, z = 0) into the lit room (z < 0).
    door_dir = np.array([-np.cos(angle), 0.0, -np.sin(angle)])
    if glossy:
        door = {"type": "twosided", "bsdf": {"type": "roughconductor", "material": "Al", "alpha": 0.15}}
    scene: dict[str, Any] = {
        "type": "scene",
        "integrator": _path_integrator(max_depth),
        "sensor": _camera(mi, resolution, [-1.6, 1.4, 3.8], [0.6, 0.9, 0.0], fov=60.0),
        **box_walls("dark", 0.0, z_dark),
        **box_walls("lit", 0.0, z_lit),
        # The shared wall z = 0, minus the doorway.
        "wall-left": _quad(
            mi, [0.5 * (x0 + door_lo), h / 2, 0], [0.5 * (door_lo - x0), 0, 0], [0, h / 2, 0], white
        ),
        "wall-right": _quad(
            mi, [0.5 * (door_hi + x1), h / 2, 0], [0.5 * (x1 - door_hi), 0, 0], [0, h / 2, 0], white
        ),
        "wall-top": _quad(
            mi,
            [0.5 * (door_lo + door_hi), 0.5 * (door_h + h), 0],
            [half_door, 0, 0],
            [0, 0.5 * (h - door_h), 0],
            white,
        ),
        "door": _quad(
            mi,
            np.array([door_hi, door_h / 2, 0.0]) + half_door * door_dir,
            half_door * door_dir,
            [0, door_h / 2, 0],
            door,
        ),
        "light": _quad(
            mi,
            [-1.0, h - 1e-3, -2.0],
            [0.4, 0, 0],
            [0, 0, 0.4],  # normal (0.4, 0, 0) x (0, 0, 0.4) points down
            _diffuse([0.0, 0.0, 0.0], two_sided=False),
            _area_light([600.0, 540.0, 450.0]),
        ),
    }
    if glossy:
        scene["dark-floor"]["bsdf"] = {
            "type": "roughplastic", "distribution": "ggx", "alpha": 0.08,
            "diffuse_reflectance": {"type": "rgb", "value": [0.35, 0.3, 0.25]},
        }
    return scene


def door_gap(
    *, resolution: Sequence[int] = DEFAULT_RESOLUTION, max_depth: int = DEFAULT_MAX_DEPTH
) -> dict[str, Any]:
    """`door_ajar` with the door opened only 3 degrees and glossy floor and door: nearly all
    light reaches the visible room through a gap of about 4 cm, and much of it along glossy
    lobes (a hard scene for path tracing)."""
    return door_ajar(resolution=resolution, max_depth=max_depth, door_angle=3.0, glossy=True)


def pool(
    *, resolution: Sequence[int] = DEFAULT_RESOLUTION, max_depth: int = DEFAULT_MAX_DEPTH, grid: int = 64
) -> dict[str, Any]:
    """A pool of water under a small light: specular-diffuse-specular caustics.

    Geometry (y up): a pool `x, z in [-1, 1]`, 0.6 deep (floor `y = 0`, light tiles; walls),
    surrounded by a deck at `y = 0.6`; the water surface is a wavy height field
    `y = 0.5 + 0.02 (sin + sin)` (a `grid x grid` triangle mesh with smooth normals, a
    dielectric of IOR 1.33). A small square light (side 0.2) hangs at `(0.5, 2.5, -0.3)`,
    facing down. Camera: at `(0, 2.2, 1.9)` looking at `(0, 0, -0.15)`. The pool floor is
    lit only through the water, and seen only through it: light-floor-eye paths are
    specular-diffuse-specular, which a path tracer finds only by refracting into the small light.
    """
    mi = _mi()
    n = int(grid)
    if n < 2:
        raise ValueError(f"grid must be >= 2, got {grid!r}")
    x, z = np.meshgrid(np.linspace(-1, 1, n + 1), np.linspace(-1, 1, n + 1), indexing="ij")
    y = 0.5 + 0.02 * (np.sin(7.0 * x + 2.0 * z) + np.sin(5.0 * z - 3.0 * x + 1.0))
    verts = np.stack([x, y, z], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a, b = i * (n + 1) + j, (i + 1) * (n + 1) + j
    faces = np.concatenate([np.stack([a, a + 1, b], -1).reshape(-1, 3), np.stack([b, a + 1, b + 1], -1).reshape(-1, 3)])
    water = triangle_mesh("water", verts, faces, {"type": "dielectric", "int_ior": 1.33, "ext_ior": 1.0})

    tiles, wall, deck = _diffuse([0.75, 0.8, 0.8]), _diffuse([0.5, 0.65, 0.75]), _diffuse([0.7, 0.65, 0.55])
    d = 0.6
    return {
        "type": "scene",
        "integrator": _path_integrator(max_depth),
        "sensor": _camera(mi, resolution, [0.0, 2.2, 1.9], [0.0, 0.0, -0.15], fov=55.0),
        "pool-floor": _quad(mi, [0, 0, 0], [1, 0, 0], [0, 0, -1], tiles),
        "pool-wall-back": _quad(mi, [0, d / 2, -1], [1, 0, 0], [0, d / 2, 0], wall),
        "pool-wall-front": _quad(mi, [0, d / 2, 1], [0, d / 2, 0], [1, 0, 0], wall),
        "pool-wall-left": _quad(mi, [-1, d / 2, 0], [0, 0, 1], [0, d / 2, 0], wall),
        "pool-wall-right": _quad(mi, [1, d / 2, 0], [0, d / 2, 0], [0, 0, 1], wall),
        "deck-back": _quad(mi, [0, d, -2.5], [4, 0, 0], [0, 0, -1.5], deck),
        "deck-front": _quad(mi, [0, d, 2.5], [4, 0, 0], [0, 0, -1.5], deck),
        "deck-left": _quad(mi, [-2.5, d, 0], [1.5, 0, 0], [0, 0, -1], deck),
        "deck-right": _quad(mi, [2.5, d, 0], [1.5, 0, 0], [0, 0, -1], deck),
        "water": water,
        "light": _quad(
            mi,
            [0.5, 2.5, -0.3],
            [0.1, 0, 0],
            [0, 0, 0.1],
            _diffuse([0.0, 0.0, 0.0], two_sided=False),
            _area_light([800.0, 760.0, 700.0]),
        ),
    }


def caustic(
    *, resolution: Sequence[int] = DEFAULT_RESOLUTION, max_depth: int = DEFAULT_MAX_DEPTH
) -> dict[str, Any]:
    """A glass sphere on a diffuse floor under a small area light: a refractive caustic.

    Geometry: floor `y = 0` and back wall `z = -2`; a dielectric sphere (IOR 1.5) of
    radius 0.5 centred at `(0, 0.5, 0)`; a small square area light (side 0.3) at height 3,
    offset to `(0.6, 3, 0.4)`, facing down. Camera: at `(0, 2.2, 4)` looking at
    `(0, 0.3, 0)`. The caustic under the sphere is reachable only by BSDF sampling
    through the glass hitting the small light.
    """
    mi = _mi()
    floor = _diffuse([0.75, 0.75, 0.75])
    return {
        "type": "scene",
        "integrator": _path_integrator(max_depth),
        "sensor": _camera(mi, resolution, [0.0, 2.2, 4.0], [0.0, 0.3, 0.0], fov=40.0),
        "floor": _quad(mi, [0, 0, 0], [4, 0, 0], [0, 0, -4], floor),
        "back": _quad(mi, [0, 2, -2], [4, 0, 0], [0, 2, 0], _diffuse([0.6, 0.65, 0.7])),
        "sphere": {
            "type": "sphere",
            "center": [0.0, 0.5, 0.0],
            "radius": 0.5,
            "bsdf": {"type": "dielectric", "int_ior": 1.5, "ext_ior": 1.0},
        },
        "light": _quad(
            mi,
            [0.6, 3.0, 0.4],
            [0.15, 0, 0],
            [0, 0, 0.15],
            _diffuse([0.0, 0.0, 0.0], two_sided=False),
            _area_light([300.0, 280.0, 250.0]),
        ),
    }


def glass_torus(
    *,
    resolution: Sequence[int] = DEFAULT_RESOLUTION,
    max_depth: int = DEFAULT_MAX_DEPTH,
    segments: tuple[int, int] = (48, 24),
) -> dict[str, Any]:
    """A diffuse torus inside a closed glass box on a floor, lit by an area light.

    Geometry: floor `y = 0`; a dielectric cube (IOR 1.5) of half-size 0.7 centred at
    `(0, 0.71, 0)`; inside it a torus (radii 0.45 and 0.15, a triangle mesh built from
    `segments`) centred at `(0, 0.71, 0)` and tilted 60 degrees about `x`; a square area
    light (side 1) at height 3 facing down. Camera: at `(2.4, 2.0, 3.2)` looking at
    `(0, 0.6, 0)`. Light reaches the torus only through the glass (specular chains).
    """
    mi = _mi()
    centre = (0.0, 0.71, 0.0)
    torus = torus_mesh(0.45, 0.15, segments, bsdf=_diffuse([0.8, 0.3, 0.15]), centre=centre, tilt_deg=60.0)
    return {
        "type": "scene",
        "integrator": _path_integrator(max_depth),
        "sensor": _camera(mi, resolution, [2.4, 2.0, 3.2], [0.0, 0.6, 0.0], fov=40.0),
        "floor": _quad(mi, [0, 0, 0], [5, 0, 0], [0, 0, -5], _diffuse([0.7, 0.7, 0.7])),
        "glass": {
            "type": "cube",
            "to_world": mi.ScalarTransform4f().translate(list(centre)).scale(0.7),
            "bsdf": {"type": "dielectric", "int_ior": 1.5, "ext_ior": 1.0},
        },
        "torus": torus,
        "light": _quad(
            mi,
            [0.3, 3.0, 0.2],
            [0.5, 0, 0],
            [0, 0, 0.5],
            _diffuse([0.0, 0.0, 0.0], two_sided=False),
            _area_light([25.0, 25.0, 25.0]),
        ),
    }


def torus_mesh(
    major_radius: float,
    minor_radius: float,
    segments: tuple[int, int],
    *,
    bsdf: dict[str, Any],
    centre: Sequence[float] = (0.0, 0.0, 0.0),
    tilt_deg: float = 0.0,
) -> Any:
    """A closed triangle-mesh torus (an `mi.Mesh`) with smooth vertex normals.

    The torus lies in the `xz` plane around `centre`, rotated by `tilt_deg` about `x`;
    `segments = (around the ring, around the tube)`.
    """
    n_ring, n_tube = (int(s) for s in segments)
    if n_ring < 3 or n_tube < 3:
        raise ValueError(f"segments must both be >= 3, got {segments!r}")
    if not 0 < minor_radius < major_radius:
        raise ValueError("need 0 < minor_radius < major_radius")
    phi = 2 * np.pi * np.arange(n_ring) / n_ring
    theta = 2 * np.pi * np.arange(n_tube) / n_tube
    P, T = np.meshgrid(phi, theta, indexing="ij")
    radial = major_radius + minor_radius * np.cos(T)
    verts = np.stack([radial * np.cos(P), minor_radius * np.sin(T), radial * np.sin(P)], axis=-1).reshape(-1, 3)
    c, s = np.cos(np.deg2rad(tilt_deg)), np.sin(np.deg2rad(tilt_deg))
    rotation = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    verts = verts @ rotation.T + np.asarray(centre, dtype=float)

    i, j = np.meshgrid(np.arange(n_ring), np.arange(n_tube), indexing="ij")
    a = i * n_tube + j
    b = ((i + 1) % n_ring) * n_tube + j
    c_ = ((i + 1) % n_ring) * n_tube + (j + 1) % n_tube
    d = i * n_tube + (j + 1) % n_tube
    faces = np.concatenate([np.stack([a, d, b], -1).reshape(-1, 3), np.stack([b, d, c_], -1).reshape(-1, 3)])
    return triangle_mesh("torus", verts, faces, bsdf)


def triangle_mesh(name: str, verts: np.ndarray, faces: np.ndarray, bsdf: dict[str, Any]) -> Any:
    """An `mi.Mesh` from vertices `(V, 3)` and triangles `(F, 3)`, with smooth vertex normals."""
    mi = _mi()
    import drjit as dr

    props = mi.Properties()
    props["bsdf"] = mi.load_dict(bsdf)
    mesh = mi.Mesh(name, len(verts), len(faces), props=props, has_vertex_normals=True)
    params = mi.traverse(mesh)
    params["vertex_positions"] = dr.ravel(mi.Point3f(*(np.asarray(verts).T.astype(np.float32).copy())))
    params["faces"] = dr.ravel(mi.Vector3u(*(np.asarray(faces).T.astype(np.uint32).copy())))
    params.update()
    mesh.recompute_vertex_normals()
    return mesh


SCENES: dict[str, Callable[..., dict[str, Any]]] = {
    "cornell_box": cornell_box,
    "door_ajar": door_ajar,
    "caustic": caustic,
    "glass_torus": glass_torus,
    "door_gap": door_gap,
    "pool": pool,
}
"""The built-in scenes by name, each a function returning a Mitsuba scene dictionary."""


# --------------------------------------------------------------------------- loading


def scene_dict(
    spec: str | Mapping[str, Any],
    resolution: Sequence[int] | None = None,
    max_depth: int | None = None,
    log: Callable[[str], object] | None = None,
) -> dict[str, Any]:
    """The scene dictionary for a registry name or a dictionary, with the overrides applied.

    For a user dictionary, `resolution` and `max_depth` replace the film size and the
    `path` integrator depth (other integrator settings, e.g. `rr_depth`, are kept; a
    scene without an integrator gets a `path` one; another integrator is left for
    `PrimarySampleSpace` to refuse); the film's filter is always a box. Each change to the
    user's settings is described by a sentence passed to `log` (default: the
    `targets.mitsuba` logger, at INFO level).
    """
    if isinstance(spec, str):
        if spec not in SCENES:
            raise ValueError(f"unknown scene name {spec!r}; known scenes: {', '.join(sorted(SCENES))}")
        kwargs: dict[str, Any] = {}
        if resolution is not None:
            kwargs["resolution"] = _resolution(resolution)
        if max_depth is not None:
            kwargs["max_depth"] = _max_depth(max_depth)
        return SCENES[spec](**kwargs)
    if not isinstance(spec, Mapping):
        raise TypeError(f"a scene must be a name, a dict or a path, got {type(spec).__name__}")
    log = log or _logger.info
    scene = _copy_dict(spec)
    sensors = [v for v in scene.values() if isinstance(v, dict) and v.get("type") in _SENSOR_TYPES]
    for sensor in sensors:
        film = sensor.setdefault("film", {"type": "hdrfilm"})
        rfilter = film.get("rfilter")
        _note_filter(rfilter.get("type") if isinstance(rfilter, Mapping) else None, log)
        film["rfilter"] = {"type": "box"}
        if resolution is not None:
            size = _resolution(resolution)
            _note_change("film size", "x".join(map(str, size)), f"{film.get('width', 768)}x{film.get('height', 576)}", log)
            film["width"], film["height"] = size
    if max_depth is not None:
        integrators = [k for k, v in scene.items() if isinstance(v, dict) and v.get("type") == "path"]
        for key in integrators:
            _note_change("maximum path depth", str(_max_depth(max_depth)), str(scene[key].get("max_depth", -1)), log)
            scene[key]["max_depth"] = _max_depth(max_depth)
        if not integrators and "integrator" not in scene:
            _note_change("maximum path depth", str(_max_depth(max_depth)), "-1 (unbounded)", log)
            scene["integrator"] = _path_integrator(max_depth)
    return scene


def load_scene(
    spec: str | Path | Mapping[str, Any],
    resolution: Sequence[int] | None = None,
    max_depth: int | None = None,
    log: Callable[[str], object] | None = None,
) -> Any:
    """Load a scene as an `mi.Scene` (the Mitsuba variant is chosen by `load_mitsuba`).

    Arguments:
        spec: a name in `SCENES`, a Mitsuba scene dictionary, or the path of a Mitsuba
            XML file (see `is_scene_file`).
        resolution: `(width, height)` of the film, or `None` to keep the scene's.
        max_depth: the `path` integrator's maximum depth, or `None` to keep the scene's.
        log: called with a sentence for each setting of a user's scene (dictionary or
            file) that is changed: the reconstruction filter, and the film size and depth
            where they differ from the scene's. Default: the `targets.mitsuba` logger,
            at INFO level.

    The film's reconstruction filter is replaced by a box filter (XML files included):
    the primary-sample-space target assigns each path to exactly one pixel.

    Raises:
        FileNotFoundError: for a path that does not exist.
        ValueError: for an unknown name, a directory, a file that cannot be read, is not
            XML, or is XML but not a Mitsuba `<scene>`, or a scene Mitsuba cannot load
            (the message is Mitsuba's, naming the file and line).
    """
    mi = _mi()
    if isinstance(spec, Path) or (isinstance(spec, str) and is_scene_file(spec)):
        return _load_xml(mi, Path(spec), resolution, max_depth, log or _logger.info)
    scene = scene_dict(spec, resolution, max_depth, log)
    try:
        return mi.load_dict(scene)
    except Exception as err:
        raise ValueError(f"Mitsuba could not load the scene dictionary: {err}") from err


def is_scene_file(spec: Any) -> bool:
    """Whether `spec` names a scene file: a `Path`, or a string that is not a registry name
    and ends in `.xml`, contains a path separator or names an existing file."""
    if isinstance(spec, Path):
        return True
    if not isinstance(spec, str) or spec in SCENES:
        return False
    return spec.lower().endswith(".xml") or os.sep in spec or "/" in spec or os.path.isfile(spec)


_SENSOR_TYPES = {"perspective", "thinlens", "orthographic", "radiancemeter", "irradiancemeter"}


def _copy_dict(d: Mapping[str, Any]) -> dict[str, Any]:
    """A copy of the nested dicts of `d`; Mitsuba objects in it are shared, not copied."""
    out: dict[str, Any] = {}
    for key, value in d.items():
        if isinstance(value, Mapping):
            out[key] = _copy_dict(value)
        elif isinstance(value, list):
            out[key] = copy.copy(value)
        else:
            out[key] = value
    return out


def _load_xml(mi: Any, path: Path, resolution: Sequence[int] | None, max_depth: int | None, log: Callable[[str], object]) -> Any:
    path = path.expanduser()
    if path.is_dir():
        raise ValueError(f"{str(path)!r} is a directory, not a Mitsuba scene file")
    if not path.is_file():
        raise FileNotFoundError(f"Mitsuba scene file not found: {str(path)!r}")
    try:
        tree = ElementTree.parse(path)
    except OSError as err:  # e.g. no permission to read it
        raise ValueError(f"cannot read the scene file {str(path)!r}: {err.strerror or err}") from err
    except (ElementTree.ParseError, LookupError, ValueError) as err:  # LookupError: an unknown encoding
        raise ValueError(f"Mitsuba could not load the scene file {str(path)!r}: XML parsing failed: {err}") from err
    root = tree.getroot()
    if root.tag != "scene":
        raise ValueError(
            f"the file {str(path)!r} does not describe a Mitsuba scene: its root element is <{root.tag}>, not <scene>"
        )
    _override_xml(root, resolution, max_depth, log)
    # Written beside the original, so that relative paths (meshes, textures, includes) still resolve.
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}-", suffix=".xml", dir=path.parent)
    except OSError as err:
        reason = err.strerror or err
        raise ValueError(f"cannot load the scene file {str(path)!r}: its folder is not writable ({reason})") from err
    os.close(fd)
    try:
        tree.write(tmp, encoding="utf-8", xml_declaration=True)
        scene = mi.load_file(tmp)
    except Exception as err:
        # Mitsuba names the temporary copy; the user knows the original.
        message = str(err).replace(tmp, str(path)).replace(Path(tmp).name, path.name)
        raise ValueError(f"Mitsuba could not load the scene file {str(path)!r}: {message}") from err
    finally:
        Path(tmp).unlink(missing_ok=True)
    if not isinstance(scene, mi.Scene):
        raise ValueError(f"the file {str(path)!r} does not describe a Mitsuba scene")
    return scene


def _set_child(parent: ElementTree.Element, tag: str, name: str, value: str) -> str | None:
    """Set `<tag name=name value=value/>` in `parent`; returns the value it replaces (`None` if unset)."""
    before = None
    for child in parent.findall(tag):
        if child.get("name") == name:
            before = child.get("value")
            parent.remove(child)
    ElementTree.SubElement(parent, tag, name=name, value=value)
    return before


def _override_xml(
    root: ElementTree.Element, resolution: Sequence[int] | None, max_depth: int | None, log: Callable[[str], object]
) -> None:
    """Box filters on every film, then the resolution and `path` depth overrides, on the XML tree.

    A sensor without a film gets an `hdrfilm` (Mitsuba's default film, whose default filter
    is Gaussian), so that its filter can be set too; with a `max_depth`, a scene without an
    integrator gets a `path` one. Each change is described to `log`.
    """
    for sensor in root.iter("sensor"):
        if sensor.find("film") is None:
            ElementTree.SubElement(sensor, "film", type="hdrfilm")
    for film in root.iter("film"):
        filters = film.findall("rfilter")
        _note_filter(filters[0].get("type") if filters else None, log)
        for rfilter in filters:
            film.remove(rfilter)
        ElementTree.SubElement(film, "rfilter", type="box")
        if resolution is not None:
            width, height = _resolution(resolution)
            before = (_set_child(film, "integer", "width", str(width)), _set_child(film, "integer", "height", str(height)))
            _note_change("film size", f"{width}x{height}", f"{before[0] or 768}x{before[1] or 576}", log)
    if max_depth is not None:
        if root.find("integrator") is None:  # Mitsuba's default: `path` without a depth limit
            ElementTree.SubElement(root, "integrator", type="path")
        for integrator in root.iter("integrator"):
            if integrator.get("type") == "path":
                depth_before = _set_child(integrator, "integer", "max_depth", str(_max_depth(max_depth)))
                _note_change("maximum path depth", str(_max_depth(max_depth)), depth_before or "-1 (unbounded)", log)


_logger = logging.getLogger("targets.mitsuba")


def _note_filter(kind: str | None, log: Callable[[str], object]) -> None:
    if kind != "box":
        kind = f"{kind}" if kind else "default (gaussian)"
        log(f"the film's {kind} reconstruction filter is replaced by a box filter (each path lands in one pixel)")


def _note_change(what: str, new: str, old: str, log: Callable[[str], object]) -> None:
    if str(new) != str(old):
        log(f"{what} {new} replaces the scene's {old}")
