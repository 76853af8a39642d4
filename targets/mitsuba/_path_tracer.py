"""A path tracer in primary sample space: Mitsuba's `path` integrator driven by explicit numbers.

`trace_paths` reproduces Mitsuba's `path` integrator (next-event estimation, BSDF
sampling, MIS with the power heuristic, Russian roulette) but reads every random number
from `D = 2 + 6 (max_depth - 1)` arrays, in Mitsuba's own order: the film position
(2 numbers), then per bounce the emitter sample (2), the BSDF lobe (1), the BSDF
direction (2) and the Russian-roulette number (1). A path is thus a deterministic
function `f(u)` of a point `u` of the unit hypercube, the primary sample space.

The bounce loop is unrolled in Python (fixed `max_depth`) so that reverse-mode AD works
through it; the MIS weights are written here, not taken from Mitsuba (whose weights are
detached). `make_tracers` wraps the batch functions in `dr.freeze`, which removes the
per-call tracing cost after the first call.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

FILM_DIMS = 2
DIMS_PER_BOUNCE = 6
DEFAULT_RR_DEPTH = 5


def dimension(max_depth: int) -> int:
    """The number of primary samples a path of at most `max_depth` segments reads."""
    return FILM_DIMS + DIMS_PER_BOUNCE * (max_depth - 1)


def trace_paths(
    scene: Any,
    u: Sequence[Any],
    *,
    max_depth: int,
    rr_depth: int = DEFAULT_RR_DEPTH,
    russian_roulette: bool = True,
    differentiable: bool = False,
) -> tuple[Any, Any, Any]:
    """Trace one camera path per lane from the primary samples `u`.

    Arguments:
        scene: an `mi.Scene` with one sensor whose film uses a box filter.
        u: `dimension(max_depth)` `mi.Float` arrays of equal width, each in `[0, 1)`.
        max_depth: Mitsuba's maximum path depth (1: only directly visible emitters).
        rr_depth: the depth from which Russian roulette may stop a path (as Mitsuba's).
        russian_roulette: `False` never stops paths early (fewer discontinuities in `f`,
            for gradient-based methods); the roulette numbers are then unused.
        differentiable: make derivatives with respect to `u` exact (see
            `_exact_sample_gradients`); values are unchanged. Costs one more BSDF
            evaluation per bounce.

    Returns:
        `(rgb, luminance, pixel)`: the path's contribution (`mi.Color3f`), its luminance
        (`mi.Float`, non-negative; 0 for a non-finite contribution) and its pixel index
        `y * W + x` with `x = floor(u0 W)`, `y = floor(u1 H)` (`mi.UInt32`).
    """
    import drjit as dr
    import mitsuba as mi

    if len(u) != dimension(max_depth):
        raise ValueError(f"expected {dimension(max_depth)} sample arrays for max_depth={max_depth}, got {len(u)}")
    sensor = scene.sensors()[0]
    width, height = (int(v) for v in sensor.film().crop_size())
    film_pos = mi.Point2f(u[0], u[1])
    ray, ray_weight = sensor.sample_ray(
        time=sensor.shutter_open(), sample1=0.5, sample2=film_pos, sample3=mi.Point2f(0.5)
    )

    ctx = mi.BSDFContext()
    result = mi.Color3f(0.0)
    throughput = mi.Color3f(1.0)
    eta = mi.Float(1.0)
    active = mi.Bool(True)
    valid_ray = mi.Bool(scene.environment() is not None)
    prev_si = dr.zeros(mi.Interaction3f)
    prev_pdf = mi.Float(1.0)
    prev_delta = mi.Bool(True)

    for depth in range(max_depth):
        si = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=mi.Bool(depth == 0), active=active)

        # Emitter hit by the previous BSDF sample (or directly visible): MIS against NEE.
        ds = mi.DirectionSample3f(scene, si=si, ref=prev_si)
        if depth == 0:
            mis_hit = mi.Float(1.0)
        else:
            em_pdf = scene.pdf_emitter_direction(prev_si, ds, active & ~prev_delta)
            mis_hit = power_heuristic(prev_pdf, dr.select(prev_delta, 0.0, em_pdf))
        emitted = ds.emitter.eval(si, active & (prev_pdf > 0))
        result += dr.select(active, throughput * emitted * mis_hit, 0.0)

        if depth + 1 == max_depth:
            valid_ray |= active & si.is_valid()
            break
        active_next = active & si.is_valid()
        k = FILM_DIMS + DIMS_PER_BOUNCE * depth
        bsdf = si.bsdf(ray)

        # Next-event estimation.
        active_em = active_next & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
        ds_em, em_weight = scene.sample_emitter_direction(si, mi.Point2f(u[k], u[k + 1]), True, active_em)
        active_em &= ds_em.pdf != 0.0
        wo = si.to_local(ds_em.d)
        bsdf_val, bsdf_pdf = bsdf.eval_pdf(ctx, si, wo, active_em)
        mis_em = dr.select(ds_em.delta, 1.0, power_heuristic(ds_em.pdf, bsdf_pdf))
        result += dr.select(active_em, throughput * bsdf_val * em_weight * mis_em, 0.0)

        # BSDF sampling.
        bs, bsdf_weight = bsdf.sample(ctx, si, u[k + 2], mi.Point2f(u[k + 3], u[k + 4]), active_next)
        sampled_delta = _sampled_delta(bs)
        prev_pdf = bs.pdf
        if differentiable:
            bsdf_weight, prev_pdf = _exact_sample_gradients(bsdf, ctx, si, bs, bsdf_weight, active_next)
        ray = si.spawn_ray(si.to_world(bs.wo))
        throughput *= dr.select(active_next, bsdf_weight, 0.0)
        eta *= dr.select(active_next, bs.eta, 1.0)
        valid_ray |= active_next & ~mi.has_flag(bs.sampled_type, mi.BSDFFlags.Null)
        prev_si = si
        prev_delta = sampled_delta

        # Russian roulette, as in Mitsuba: the depth counted after this bounce.
        throughput_max = dr.max(throughput)
        active = active_next & (throughput_max != 0.0)
        if russian_roulette and depth + 1 >= rr_depth:
            rr_prob = dr.minimum(throughput_max * dr.square(eta), 0.95)
            throughput *= dr.rcp(rr_prob)  # not detached: f(u) is differentiated exactly
            active &= u[k + 5] < rr_prob

    rgb = dr.select(valid_ray, result, 0.0)
    lum = mi.luminance(rgb)
    ok = dr.isfinite(lum)
    rgb = dr.select(ok, rgb, 0.0)
    lum = dr.select(ok, dr.maximum(lum, 0.0), 0.0)
    return rgb, lum, pixel_of(u[0], u[1], width, height)


def _exact_sample_gradients(bsdf: Any, ctx: Any, si: Any, bs: Any, weight: Any, active: Any) -> tuple[Any, Any]:
    """The BSDF sample weight and pdf with the derivatives of the deterministic map `u -> f(u)`.

    Mitsuba's sampling routines attach gradients meant for *parameter* derivatives in
    expectation (e.g. the dielectric's weight `1` carries the gradient of `F / detach(F)`),
    which are wrong for derivatives of one path with respect to its primary samples.
    Values are kept; gradients are replaced: for a smooth lobe by those of
    `eval(wo) / pdf(wo)` and `pdf(wo)` at the sampled direction (which depends on `u`),
    for a delta lobe by zero: its weight is locally constant in `u`, which is exact for
    dielectrics, thin dielectrics and ideal mirrors (and neglects the angular dependence
    of a conductor's Fresnel term).
    """
    import drjit as dr

    delta = _sampled_delta(bs)
    value, pdf = bsdf.eval_pdf(ctx, si, bs.wo, active & ~delta)
    smooth_weight = dr.select(pdf > 0, value / dr.select(pdf > 0, pdf, 1.0), 0.0)
    weight = dr.replace_grad(weight, dr.select(delta, dr.detach(weight), smooth_weight))  # type: ignore[func-returns-value]
    pdf = dr.replace_grad(bs.pdf, dr.select(delta, dr.detach(bs.pdf), pdf))  # type: ignore[func-returns-value]
    return weight, pdf


def _sampled_delta(bs: Any) -> Any:
    """Whether a BSDF sample picked a delta (specular) lobe, per lane."""
    import mitsuba as mi

    return mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)


def power_heuristic(pdf_a: Any, pdf_b: Any) -> Any:
    """`pdf_a^2 / (pdf_a^2 + pdf_b^2)`, 0 where undefined; differentiable (unlike Mitsuba's)."""
    import drjit as dr

    a2, b2 = dr.square(pdf_a), dr.square(pdf_b)
    denom = a2 + b2
    ok = dr.isfinite(denom) & (denom > 0)
    return dr.select(ok, a2 / dr.select(ok, denom, 1.0), 0.0)


def pixel_of(u0: Any, u1: Any, width: int, height: int) -> Any:
    """`y * W + x` with `x = floor(u0 W)`, `y = floor(u1 H)` clamped to the film (float32 arithmetic)."""
    import drjit as dr
    import mitsuba as mi

    x = dr.minimum(mi.UInt32(dr.floor(u0 * width)), width - 1)
    y = dr.minimum(mi.UInt32(dr.floor(u1 * height)), height - 1)
    return y * width + x


def make_tracers(
    max_depth: int, rr_depth: int = DEFAULT_RR_DEPTH, russian_roulette: bool = True
) -> tuple[Callable[..., Any], Callable[..., Any]]:
    """Frozen batch functions `(evaluate, evaluate_with_grad)` for one path configuration.

    `evaluate(scene, u)` returns `(rgb, luminance, pixel)`; `evaluate_with_grad(scene, u)`
    also returns the `D` arrays of `d log(luminance) / d u_i` (0 where the luminance is 0),
    computed in reverse mode. Both trace the same function `f(u)` (same Russian-roulette
    setting), so their values agree; for gradient-based methods use
    `russian_roulette=False`, which removes the roulette's discontinuities. `u` is a list
    of `D` `mi.Float`. The scene and samples are arguments, never captured: a frozen
    function replays its recorded kernels on whatever inputs it is given.
    """
    import drjit as dr

    def evaluate(scene: Any, u: list[Any]) -> tuple[Any, Any, Any]:
        return trace_paths(scene, u, max_depth=max_depth, rr_depth=rr_depth, russian_roulette=russian_roulette)

    def evaluate_with_grad(scene: Any, u: list[Any]) -> tuple[Any, Any, Any, list[Any]]:
        u = [dr.detach(x) for x in u]
        dr.enable_grad(u)
        rgb, lum, pixel = trace_paths(
            scene, u, max_depth=max_depth, rr_depth=rr_depth, russian_roulette=russian_roulette, differentiable=True
        )
        positive = lum > 0
        dr.backward(dr.log(dr.select(positive, lum, 1.0)))
        grads = [dr.select(positive, dr.grad(x), 0.0) for x in u]
        return dr.detach(rgb), dr.detach(lum), pixel, grads

    return dr.freeze(evaluate), dr.freeze(evaluate_with_grad)
