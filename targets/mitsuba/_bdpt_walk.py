"""The camera and light subpaths of bidirectional path tracing, from explicit primary samples.

A subpath is a Python list of `Vertex` records, one per possible vertex (the loop is
unrolled to the maximum depth); each lane uses the first `t` (camera) or `s` (light)
of them. Every vertex carries the two area densities that the MIS weights need
(Veach's `p_fwd` and `p_rev`, as in pbrt-v4's BDPT): `fwd`, the density of this vertex
given its predecessors in its own subpath, and `rev`, its density had the *other*
subpath generated it. `rev` of the last two vertices depends on the connection and is
filled by `_bdpt`. Where a delta lobe was sampled, both densities it enters are set to 1
(pbrt's `remap0` convention), consistently for every strategy, so they cancel.

Primary samples, per lane (`M = max_depth`):
- camera: the film position (2), then for each camera bounce `c_i -> c_{i+1}`,
  `i = 1 .. M-1`, the BSDF lobe (1) and direction (2);
- light: the emitter choice (1), the position on it (2), the cosine-weighted direction (2),
  then for each light bounce `l_i -> l_{i+1}`, `i = 1 .. M-2`, lobe (1) and direction (2).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any

FILM_DIMS = 2
EMITTER_DIMS = 5
DIMS_PER_BOUNCE = 3


def light_offset(max_depth: int) -> int:
    """Index of the first light-subpath sample."""
    return FILM_DIMS + DIMS_PER_BOUNCE * (max_depth - 1)


def dimension(max_depth: int) -> int:
    """The number of primary samples one BDPT strategy of at most `max_depth` segments reads."""
    if max_depth < 1:
        raise ValueError(f"max_depth must be >= 1, got {max_depth}")
    return light_offset(max_depth) + EMITTER_DIMS + DIMS_PER_BOUNCE * max(max_depth - 2, 0)


@dataclass
class Vertex:
    """One subpath vertex per lane.

    `si` is a `SurfaceInteraction3f` (for the camera only its position is meaningful; for
    the light vertex it is built from the position sample); `beta` the subpath throughput
    up to (not including) this vertex's own scattering; `exists` whether the lane has it.
    """

    si: Any
    fwd: Any
    rev: Any
    delta: Any
    beta: Any
    exists: Any


def pick(items: Sequence[Any], index: Any) -> Any:
    """`items[index]` per lane for a Python list of Dr.Jit values (0 .. len-1; else `items[0]`)."""
    import drjit as dr

    out = items[0]
    for i in range(1, len(items)):
        out = dr.select(index == i, items[i], out)
    return out


def pick_vertex(vertices: Sequence[Vertex], index: Any) -> Vertex:
    """The per-lane vertex `vertices[index]`, field by field."""
    return Vertex(**{f.name: pick([getattr(v, f.name) for v in vertices], index) for f in fields(Vertex)})


def to_area(pdf_solid_angle: Any, origin: Any, target_si: Any) -> Any:
    """A solid-angle density at `origin` as an area density at `target_si` (geometric normal)."""
    import drjit as dr

    d = target_si.p - origin
    dist2 = dr.squared_norm(d)
    cos = dr.abs(dr.dot(target_si.n, d)) * dr.rsqrt(dist2)
    return dr.select(dist2 > 0, pdf_solid_angle * cos / dist2, 0.0)


def with_wi(si: Any, wi_local: Any) -> Any:
    """A copy of the interaction `si` with the incident direction `wi_local`.

    (Mitsuba's struct fields are references: assigning to `si.wi` in place would also
    change any array previously read from it.)
    """
    import mitsuba as mi

    out = mi.SurfaceInteraction3f(si)
    out.wi = mi.Vector3f(wi_local)
    return out


def reverse_pdf(bsdf: Any, ctx: Any, si: Any, wi_local: Any, active: Any) -> Any:
    """The BSDF's density of sampling the direction `si.wi` when light arrives from `wi_local`."""
    import mitsuba as mi

    return bsdf.pdf(ctx, with_wi(si, wi_local), mi.Vector3f(si.wi), active)


def shading_correction(si: Any, wo_world: Any) -> Any:
    """Veach's factor (thesis 5.3.2) that makes importance transport through shading normals exact."""
    import drjit as dr
    import mitsuba as mi

    wi_world = si.to_world(si.wi)
    num = dr.abs(dr.dot(wi_world, si.n) * mi.Frame3f.cos_theta(si.to_local(wo_world)))
    den = dr.abs(mi.Frame3f.cos_theta(si.wi) * dr.dot(wo_world, si.n))
    return dr.select(den > 0, num / dr.select(den > 0, den, 1.0), 0.0)


def camera_subpath(scene: Any, u: Sequence[Any], t: Any, max_depth: int) -> tuple[list[Vertex], Any]:
    """Vertices `c_0` (the camera) .. `c_M` of the lanes' camera subpaths; lane uses `c_0 .. c_{t-1}`.

    Returns the vertices and the camera ray's origin (the pinhole).
    """
    import drjit as dr
    import mitsuba as mi

    sensor = scene.sensors()[0]
    ray, ray_weight = sensor.sample_ray(
        time=sensor.shutter_open(), sample1=0.5, sample2=mi.Point2f(u[0], u[1]), sample3=mi.Point2f(0.5)
    )
    camera_si = dr.zeros(mi.SurfaceInteraction3f, dr.width(u[0]))
    camera_si.p = ray.o
    one, zero = mi.Float(1.0), mi.Float(0.0)
    vertices = [Vertex(camera_si, one, zero, mi.Bool(False), mi.Color3f(1.0), mi.Bool(True))]
    ctx, ctx_adjoint = mi.BSDFContext(mi.TransportMode.Radiance), mi.BSDFContext(mi.TransportMode.Importance)
    beta = mi.Color3f(ray_weight)
    active = t >= 2
    prev_pdf, prev_delta = mi.Float(0.0), mi.Bool(False)
    for i in range(1, max_depth + 1):
        si = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=mi.Bool(i == 1), active=active)
        active &= si.is_valid()
        if i == 1:
            it = dr.zeros(mi.Interaction3f)
            it.p = si.p
            _, importance = sensor.sample_direction(it, mi.Point2f(0.5), active)
            fwd = importance.x * dr.abs(dr.dot(si.n, ray.d))  # importance / dist^2 * |cos|
        else:
            fwd = dr.select(prev_delta, 1.0, to_area(prev_pdf, ray.o, si))
        vertex = Vertex(si, dr.select(active, fwd, 0.0), mi.Float(0.0), mi.Bool(False), beta, active)
        vertices.append(vertex)
        if i == max_depth:
            break
        scatter = active & (t > i + 1)
        k = FILM_DIMS + DIMS_PER_BOUNCE * (i - 1)
        bsdf = si.bsdf(ray)
        bs, weight = bsdf.sample(ctx, si, u[k], mi.Point2f(u[k + 1], u[k + 2]), scatter)
        delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
        if i >= 2:
            before = vertices[i - 1]
            rev = to_area(reverse_pdf(bsdf, ctx_adjoint, si, bs.wo, scatter & ~delta), si.p, before.si)
            before.rev = dr.select(scatter, dr.select(delta, 1.0, rev), before.rev)
        vertex.delta = scatter & delta
        beta = beta * dr.select(scatter, weight, 0.0)
        prev_pdf, prev_delta = bs.pdf, delta
        ray = si.spawn_ray(si.to_world(bs.wo))
        active = scatter & (bs.pdf > 0) & (dr.max(beta) > 0)
    return vertices, camera_si.p


@dataclass
class LightStart:
    """The light vertex's emitter (per lane) and its area density (emitter choice x position)."""

    emitter: Any
    pdf: Any


def light_subpath(scene: Any, u: Sequence[Any], s: Any, max_depth: int) -> tuple[list[Vertex], LightStart]:
    """Vertices `l_0` (on an area emitter) .. `l_{M-1}`; the lane uses `l_0 .. l_{s-1}`.

    `l_0.beta` is `1 / p(l_0)`; `l_1.beta = Le cos / (p(l_0) p(direction))`.
    """
    import drjit as dr
    import mitsuba as mi

    o = light_offset(max_depth)
    active = s >= 1
    index, choice_weight, _ = scene.sample_emitter(u[o], active)
    emitter = dr.gather(mi.EmitterPtr, scene.emitters_dr(), index, active)
    ps, _ = emitter.sample_position(scene.sensors()[0].shutter_open(), mi.Point2f(u[o + 1], u[o + 2]), active)
    pos_pdf = dr.select(active & (choice_weight > 0), ps.pdf / choice_weight, 0.0)
    si0 = mi.SurfaceInteraction3f(ps, dr.zeros(mi.Color0f))  # type: ignore[call-overload]  # (stubs: Spectrum)
    local = mi.warp.square_to_cosine_hemisphere(mi.Point2f(u[o + 3], u[o + 4]))
    dir_pdf = mi.warp.square_to_cosine_hemisphere_pdf(local)
    radiance = emitter.eval(with_wi(si0, local), active)
    inv_pdf = dr.select(pos_pdf > 0, dr.rcp(pos_pdf), 0.0)
    vertices = [Vertex(si0, pos_pdf, mi.Float(0.0), mi.Bool(False), mi.Color3f(inv_pdf), active & (pos_pdf > 0))]
    ctx, ctx_adjoint = mi.BSDFContext(mi.TransportMode.Importance), mi.BSDFContext(mi.TransportMode.Radiance)
    beta = radiance * inv_pdf * dr.pi  # Le cos / (p_pos cos/pi)
    ray = si0.spawn_ray(si0.to_world(local))
    active = active & (s >= 2) & (dir_pdf > 0) & (dr.max(beta) > 0)
    prev_pdf, prev_delta = dir_pdf, mi.Bool(False)
    for i in range(1, max_depth):
        si = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=mi.Bool(False), active=active)
        active &= si.is_valid()
        fwd = dr.select(prev_delta, 1.0, to_area(prev_pdf, ray.o, si))
        vertex = Vertex(si, dr.select(active, fwd, 0.0), mi.Float(0.0), mi.Bool(False), beta, active)
        vertices.append(vertex)
        if i == max_depth - 1:
            break
        scatter = active & (s > i + 1)
        k = o + EMITTER_DIMS + DIMS_PER_BOUNCE * (i - 1)
        bsdf = si.bsdf(ray)
        bs, weight = bsdf.sample(ctx, si, u[k], mi.Point2f(u[k + 1], u[k + 2]), scatter)
        delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
        wo_world = si.to_world(bs.wo)
        before = vertices[i - 1]
        rev = to_area(reverse_pdf(bsdf, ctx_adjoint, si, bs.wo, scatter & ~delta), si.p, before.si)
        before.rev = dr.select(scatter, dr.select(delta, 1.0, rev), before.rev)
        vertex.delta = scatter & delta
        beta = beta * dr.select(scatter, weight * shading_correction(si, wo_world), 0.0)
        prev_pdf, prev_delta = bs.pdf, delta
        ray = si.spawn_ray(wo_world)
        active = scatter & (bs.pdf > 0) & (dr.max(beta) > 0)
    return vertices, LightStart(emitter, pos_pdf)
