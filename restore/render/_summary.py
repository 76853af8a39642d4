"""What `restore render` reports after a render: the work, where the wall time went, and
whether a few samples decide the image.

A time budget covers the sampling only: loading the scene and compiling come before it,
and Restore's finishing of its open tours after it, so the command takes longer than
`--time`; the report says by how much.
"""

from __future__ import annotations

import math

from ._driver import RenderResult
from ._renderer import TAIL_WARNING, AbstractRenderer
from ._restore_renderer import RestoreStatistics

#: What each renderer's tail statistic is the Pareto shape of.
_TAIL_OF = {"tour_k_hat": "tour durations", "z_k_hat": "luminance behind Z_hat"}


def time_split(parts: dict[str, float]) -> str:
    """`"0.4 s scene, 9.9 s compile, 8.0 s budget"`: the parts of the wall time, in order."""
    return ", ".join(f"{seconds:.1f} s {part}" for part, seconds in parts.items())


def reliability(k_hat: float) -> str:
    """Whether the image can be trusted, from its renderer's tail shape (as `warn_tail` judges)."""
    if not math.isfinite(k_hat):
        return "unknown: too few samples to fit the tail"
    if k_hat > TAIL_WARNING:
        return f"no: k_hat > {TAIL_WARNING}, a few samples decide the image (render longer)"
    return f"yes: k_hat <= {TAIL_WARNING}"


def render_rows(result: RenderResult, renderer: AbstractRenderer, scene_seconds: float) -> list[tuple[str, str]]:
    """The rows of the report of a primary-sample-space render: paths, paths/s (budget and
    finishing), the time split, tours (Restore), the tail shape `k_hat` and the verdict."""
    parts = {"scene": scene_seconds, "compile": result.compile_seconds}
    parts["budget"] = result.seconds - result.finishing_seconds
    if renderer.finishes:
        parts["finishing"] = result.finishing_seconds
    rows = [
        ("paths", f"{result.evaluations:,}"),
        ("paths/s", f"{result.evaluations_per_second:,.0f} (budget{' and finishing' if renderer.finishes else ''})"),
        ("time", time_split(parts)),
    ]
    stats = result.statistics
    if isinstance(stats, RestoreStatistics):
        rows.append(("tours", f"{stats.tours_completed:,.0f} ({stats.effective_tours:,.0f} effective)"))
    name = renderer.tail_statistic
    if name is None:
        rows.append(("reliable", f"not checked: {type(renderer).__name__} has no tail diagnostic"))
    else:
        k_hat = float(getattr(stats, name, math.nan))
        rows.append(("k_hat", f"{k_hat:.2f} (Pareto shape of the {_TAIL_OF.get(name, name)})"))
        rows.append(("reliable", reliability(k_hat)))
    return rows


def native_rows(spp: int, pixels: int, seconds: float, scene_seconds: float) -> list[tuple[str, str]]:
    """The rows of the report of a render with Mitsuba's own path tracer."""
    paths = spp * pixels
    return [
        ("paths", f"{paths:,} ({spp} spp)"),
        ("paths/s", f"{paths / seconds:,.0f}" if seconds > 0 else "-"),
        ("time", time_split({"scene": scene_seconds, "render": seconds})),
        ("reliable", "not checked: Mitsuba's path tracer has no tail diagnostic"),
    ]
