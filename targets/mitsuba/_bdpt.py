"""Bidirectional path tracing in primary sample space, one strategy per lane.

`trace_strategies(scene, k, s, u)` evaluates, for each lane, the path of `k` segments
(`1 <= k <= max_depth`) built by strategy `s` (`0 <= s <= k`): `s` light-subpath
vertices and `t = k + 1 - s` camera-subpath vertices (the camera included), from the
explicit primary samples `u` (layout in `_bdpt_walk`). It returns the MIS-weighted
contribution `w_s(u) C_s(u)`, its luminance and its pixel:

- `s = 0`: the camera subpath hits an area emitter;
- `s = 1`: its last vertex is connected to a point on an emitter (next-event estimation);
- `s >= 2, t >= 2`: a light and a camera subpath joined by a visibility-tested edge;
- `t = 1`: a light subpath connected to the pinhole (light tracing); the pixel is where
  the connecting edge crosses the film, not `u[0:2]`.

For each fixed `k`, `sum_s W H E_u[w_s C_s 1{pixel = j}]` is the depth-`k` image of
Mitsuba's `path` integrator, so the sum over depths is its image with `max_depth`
(`W H E_u[f 1{pixel = j}]`, the convention of `PrimarySampleSpace`). Sensor importance
is normalised over the whole film: a camera ray from a uniform film point has weight 1.

Supported scenes (`check_bdpt_support`): a pinhole perspective camera with a box filter
and no crop, area emitters only (sampled uniformly), no participating media. Delta
BSDFs are fine: no connection is made through a delta vertex and the MIS weights leave
out the strategies that would need one. No Russian roulette.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from ._bdpt_mis import DEFECTIVE_WEIGHTS, HEURISTICS, mis_weight
from ._bdpt_walk import (
    Vertex,
    camera_subpath,
    dimension,
    light_subpath,
    pick_vertex,
    reverse_pdf,
    shading_correction,
    to_area,
    with_wi,
)
from ._path_tracer import pixel_of

#: The fraction of the connecting edge, between the two ends offset off their surfaces,
#: that the shadow ray leaves untested at its far end.
SHADOW_TAIL = 1e-5

__all__ = ["dimension", "make_bdpt_tracer", "trace_strategies"]


def trace_strategies(
    scene: Any,
    k: Any,
    s: Any,
    u: Sequence[Any],
    *,
    max_depth: int,
    heuristic: str = "balance",
    drop_strategy: int | None = None,
) -> tuple[Any, Any, Any]:
    """`(rgb, luminance, pixel)` of strategy `s` for paths of `k` segments, per lane.

    Arguments:
        scene: an `mi.Scene` accepted by `check_bdpt_support`.
        k, s: `mi.Int32` arrays; lanes with `k` outside `1..max_depth` or `s` outside
            `0..k` contribute 0.
        u: `dimension(max_depth)` `mi.Float` arrays in `[0, 1)`.
        max_depth: the most segments of a path.
        heuristic: `"balance"` (pbrt's) or `"power"`. The names in
            `_bdpt_mis.DEFECTIVE_WEIGHTS` give deliberately wrong weights (tests only).
        drop_strategy: tests only: strategy `s` contributes 0 where `s == drop_strategy`
            (`-1`: where `t == 1`, light tracing), so its share of every path is lost.
    """
    import drjit as dr
    import mitsuba as mi

    if heuristic not in HEURISTICS and heuristic not in DEFECTIVE_WEIGHTS:
        raise ValueError(f"heuristic must be one of {sorted(HEURISTICS)}, got {heuristic!r}")
    if len(u) != dimension(max_depth):
        raise ValueError(f"expected {dimension(max_depth)} sample arrays for max_depth={max_depth}, got {len(u)}")
    k, s = mi.Int32(k), mi.Int32(s)
    t = k + 1 - s
    valid = (k >= 1) & (k <= max_depth) & (s >= 0) & (t >= 1)
    cam, camera_p = camera_subpath(scene, u, dr.select(valid, t, 0), max_depth)
    light, start = light_subpath(scene, u, dr.select(valid, s, 0), max_depth)
    sensor = scene.sensors()[0]
    width, height = (int(v) for v in sensor.film().crop_size())

    end_e = pick_vertex(cam, t - 1)
    end_l = pick_vertex(light, s - 1)
    from_light, to_camera = s == 0, t == 1
    through_light, through_camera = s >= 2, t >= 2
    ctx, ctx_adjoint = mi.BSDFContext(mi.TransportMode.Radiance), mi.BSDFContext(mi.TransportMode.Importance)

    # The connecting edge, from the light end to the camera end (unused where s = 0).
    end_e_p = dr.select(to_camera, camera_p, end_e.si.p)
    edge = end_e_p - end_l.si.p
    dist2 = dr.squared_norm(edge)
    d = edge * dr.rsqrt(dist2)
    cos_l = dr.abs(dr.dot(end_l.si.n, d))
    connect = valid & ~from_light & end_l.exists & end_e.exists & (dist2 > 0)

    # Light end: Le (s = 1) or the BSDF of l_{s-1} towards the camera end, cosine included.
    si_l = end_l.si
    local_l = si_l.to_local(d)
    emitted = start.emitter.eval(with_wi(si_l, local_l), connect & ~through_light)
    bsdf_l = si_l.bsdf()
    on_surface = connect & through_light
    f_l = bsdf_l.eval(ctx_adjoint, si_l, local_l, on_surface) * shading_correction(si_l, d)
    a_l = end_l.beta * dr.select(through_light, f_l, emitted * cos_l)
    pdf_l_out = dr.select(
        through_light,
        bsdf_l.pdf(ctx_adjoint, si_l, local_l, on_surface),
        mi.warp.square_to_cosine_hemisphere_pdf(local_l),
    )
    pdf_l_back = reverse_pdf(bsdf_l, ctx, si_l, local_l, on_surface & (s >= 2))

    # Camera end: sensor importance (t = 1) or the BSDF of c_{t-1} towards the light end.
    it = dr.zeros(mi.Interaction3f)
    it.p = end_l.si.p
    sensor_ds, importance = sensor.sample_direction(it, mi.Point2f(0.5), connect & to_camera)
    si_e = end_e.si
    local_e = si_e.to_local(-d)
    bsdf_e = si_e.bsdf()
    f_e = bsdf_e.eval(ctx, si_e, local_e, connect & through_camera)
    a_e = dr.select(to_camera, importance.x, end_e.beta * f_e / dist2)
    pdf_e_out = dr.select(to_camera, importance.x * dist2, bsdf_e.pdf(ctx, si_e, local_e, connect & through_camera))
    pdf_e_back = reverse_pdf(bsdf_e, ctx_adjoint, si_e, local_e, connect & (t >= 3))

    # The shadow ray runs between the two ends, each first offset off its surface towards
    # the other, and stops a hair (`SHADOW_TAIL`) short of the far one. Not `spawn_ray_to`:
    # it offsets only the origin and stops a fraction `ShadowEpsilon` (~1e-3) of the edge
    # short, so an occluder within millimetres of the camera end was missed, and light
    # leaked through a thin wall onto the strips of floor and walls that meet it behind.
    near = dr.select(to_camera, camera_p, si_e.spawn_ray(-d).o)
    seg = si_l.spawn_ray(d).o - near
    seg_len = dr.norm(seg)
    shadow = mi.Ray3f(near, seg / dr.select(seg_len > 0, seg_len, 1.0))
    shadow.maxt = seg_len * (1.0 - SHADOW_TAIL)
    visible = connect & ~scene.ray_test(shadow, connect)
    contribution = dr.select(visible, a_l * a_e, 0.0)

    # s = 0: the camera subpath's last vertex is on an emitter.
    hit_emitter = valid & from_light & end_e.exists
    emitter_e = si_e.emitter(scene, hit_emitter)
    contribution = dr.select(from_light, end_e.beta * emitter_e.eval(si_e, hit_emitter), contribution)
    cos_hit = mi.Frame3f.cos_theta(si_e.wi)
    emitter_pos_pdf = _emitter_position_pdf(scene, si_e, hit_emitter)
    emitter_dir_pdf = dr.select(cos_hit > 0, cos_hit * dr.inv_pi, 0.0)

    # Densities of the endpoints and their predecessors as generated from the other side.
    for i, vertex in enumerate(light):
        at_end = to_area(pdf_e_out, end_e_p, vertex.si)
        back = to_area(pdf_l_back, end_l.si.p, vertex.si)
        vertex.rev = dr.select(i == s - 1, at_end, dr.select(i == s - 2, back, vertex.rev))
    for i, vertex in enumerate(cam):
        at_end = dr.select(from_light, emitter_pos_pdf, to_area(pdf_l_out, end_l.si.p, vertex.si))
        back = dr.select(from_light, emitter_dir_pdf, pdf_e_back)
        vertex.rev = dr.select(i == t - 1, at_end, dr.select(i == t - 2, to_area(back, end_e.si.p, vertex.si), vertex.rev))

    p_light, p_camera, delta = _path_densities(light, cam, k, s, max_depth)
    weight = mis_weight(p_light, p_camera, delta, k, s, heuristic)
    if drop_strategy is not None:
        weight = dr.select(to_camera if drop_strategy == -1 else s == drop_strategy, 0.0, weight)
    rgb = dr.select(valid, contribution * weight, 0.0)
    lum = mi.luminance(rgb)
    ok = dr.isfinite(lum)
    rgb = dr.select(ok, rgb, 0.0)
    lum = dr.select(ok, dr.maximum(lum, 0.0), 0.0)
    film_x = dr.select(to_camera, sensor_ds.uv.x / width, u[0])
    film_y = dr.select(to_camera, sensor_ds.uv.y / height, u[1])
    return rgb, lum, pixel_of(film_x, film_y, width, height)


def _emitter_position_pdf(scene: Any, si: Any, active: Any) -> Any:
    """Area density with which the light subpath would start at `si` (emitter choice x position)."""
    import drjit as dr
    import mitsuba as mi

    ps = mi.PositionSample3f(si)
    return dr.select(active, si.shape.pdf_position(ps, active) * scene.pdf_emitter(mi.UInt32(0), active), 0.0)


def _path_densities(
    light: Sequence[Vertex], cam: Sequence[Vertex], k: Any, s: Any, max_depth: int
) -> tuple[list[Any], list[Any], list[Any]]:
    """`pL_j`, `pE_j` and the delta flags along the path `x_0 .. x_{M-1}` (light to camera)."""
    import drjit as dr

    p_light, p_camera, delta = [], [], []
    for j in range(max_depth):
        c = pick_vertex(cam, k - j)
        on_light = j < s
        p_light.append(dr.select(on_light, light[j].fwd, c.rev))
        p_camera.append(dr.select(on_light, light[j].rev, c.fwd))
        delta.append(dr.select(on_light, light[j].delta, c.delta))
    return p_light, p_camera, delta


def make_bdpt_tracer(max_depth: int, heuristic: str = "balance", drop_strategy: int | None = None) -> Callable[..., Any]:
    """The frozen batch function `evaluate(scene, k, s, u) -> (rgb, luminance, pixel)`."""
    import drjit as dr

    def evaluate(scene: Any, k: Any, s: Any, u: list[Any]) -> tuple[Any, Any, Any]:
        return trace_strategies(scene, k, s, u, max_depth=max_depth, heuristic=heuristic, drop_strategy=drop_strategy)

    return dr.freeze(evaluate)

