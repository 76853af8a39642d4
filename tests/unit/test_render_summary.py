"""What `restore render` reports: paths, paths/s, where the wall time went, tours, `k_hat`, and a verdict.

The rows are built from a `RenderResult` and its renderer alone (no scene is rendered): the
time split must account for the budget and the finishing separately, and the verdict must
follow the renderer's tail statistic across `TAIL_WARNING`.
"""

import dataclasses
import math

import numpy as np
import pytest

from restore.render import ERPTStatistics, PSSMLTStatistics, RenderResult, RestoreStatistics, UniformStatistics
from restore.render._compare import MethodRun, RenderComparison, thin_snapshots
from restore.render._methods import make_renderer
from restore.render._renderer import TAIL_WARNING
from restore.render._summary import native_rows, reliability, render_rows


def record(kind, **values):
    """A statistics record of `kind` with the given fields, NaN elsewhere."""
    return kind(**{**{field.name: math.nan for field in dataclasses.fields(kind)}, **values})


def result(**changes):
    fields = dict(
        image=np.zeros((2, 2, 3), np.float32), evaluations=1_200_000, seconds=10.0, compile_seconds=6.5, steps=100,
        num_lanes=8192, statistics=record(RestoreStatistics, tours_completed=80_000, effective_tours=3_000.0, tour_k_hat=0.3),
        finishing_seconds=2.0,
    )  # fmt: skip
    return RenderResult(**{**fields, **changes})


def test_the_time_split_separates_compile_budget_and_finishing():
    rows = dict(render_rows(result(), make_renderer("restore"), scene_seconds=0.3))
    assert rows["time"] == "0.3 s scene, 6.5 s compile, 8.0 s budget, 2.0 s finishing"
    assert rows["paths"] == "1,200,000" and rows["paths/s"] == "120,000 (budget and finishing)"
    assert rows["tours"] == "80,000 (3,000 effective)"
    assert rows["k_hat"].startswith("0.30 ") and "tour durations" in rows["k_hat"]
    assert rows["reliable"].startswith("yes")


def test_the_verdict_follows_the_tail_statistic():
    assert reliability(TAIL_WARNING - 0.01).startswith("yes")
    assert reliability(TAIL_WARNING + 0.01).startswith("no")
    assert reliability(float("nan")).startswith("unknown")
    heavy = result(statistics=record(PSSMLTStatistics, z_k_hat=1.2), finishing_seconds=0.0)
    rows = dict(render_rows(heavy, make_renderer("pssmlt"), scene_seconds=1.0))
    assert rows["reliable"].startswith("no") and "luminance" in rows["k_hat"]
    assert "tours" not in rows and "finishing" not in rows["time"] and rows["paths/s"] == "120,000 (budget)"


@pytest.mark.parametrize("method, kind", [("uniform", UniformStatistics), ("erpt", ERPTStatistics)])
def test_renderers_without_a_tail_diagnostic_say_so(method, kind):
    rows = dict(render_rows(result(statistics=record(kind), finishing_seconds=0.0), make_renderer(method), scene_seconds=0.0))
    assert "k_hat" not in rows and rows["reliable"].startswith("not checked")


def test_mitsubas_path_tracer_reports_its_samples_per_pixel():
    rows = dict(native_rows(spp=16, pixels=64, seconds=0.5, scene_seconds=0.1))
    assert rows["paths"] == "1,024 (16 spp)" and rows["paths/s"] == "2,048"
    assert rows["time"] == "0.1 s scene, 0.5 s render"


def test_the_comparison_pairs_each_gradient_restore_variant_with_its_counterpart():
    """Relative MSE x seconds of MALA Restore / MALA and H2MC Restore / H2MC, where both ran."""

    def run(method, mse, seconds):
        return MethodRun("door", method, 0, np.zeros((1, 1, 3)), seconds, 1, {"relative_mse": mse}, [])

    runs = [run("mala", 0.004, 10.0), run("mala-restore", 0.002, 16.0), run("h2mc", 0.05, 10.0)]
    comparison = RenderComparison(("door",), ("mala", "mala-restore", "h2mc"), 10.0, 1, (8, 8), 5, {}, runs, {}, {})
    rows = {name: (value, goal) for name, _, value, goal in comparison.ratios()}
    assert rows["relative MSE x time, MALA Restore / MALA"] == (pytest.approx(0.8), "<= 0.8")
    assert not any("H2MC" in name for name in rows)  # H2MC Restore did not run


def test_the_comparison_gives_ratios_of_medians_and_the_variance_across_realisations_over_time():
    """The median ratio follows the typical seed where one bad seed moves the mean; the variance
    over time takes each realisation's last image at or before each time."""
    reference = np.ones((1, 1, 3))

    def run(method, r, mse, seconds, snapshots=()):
        return MethodRun("door", method, r, reference, seconds, 1, {"relative_mse": mse}, [], {}, list(snapshots))

    # mala-restore: 0.5 x mala in two seeds of three, 10 x in the third
    runs = [run("mala", r, 0.01, 10.0) for r in range(3)]
    runs += [run("mala-restore", r, mse, 10.0) for r, mse in enumerate((0.005, 0.005, 0.1))]
    # two realisations of restore whose images differ by 2 at 1 s and by 0.2 (in one channel) at 4 s
    images = {1.0: (np.full((1, 1, 3), 0.0), np.full((1, 1, 3), 2.0)), 4.0: (reference, reference + [0.0, 0.0, 0.2])}
    runs += [run("restore", r, 0.1, 4.0, [(t, images[t][r]) for t in (1.0, 4.0)]) for r in range(2)]
    comparison = RenderComparison(("door",), ("mala", "mala-restore", "restore"), 4.0, 3, (1, 1), 5, {"door": reference}, runs, {}, {})
    rows = {row[0]: row for row in comparison._ratio_rows()}
    assert rows["relative MSE x time, MALA Restore / MALA"][2] == pytest.approx(11 / 3)  # of means
    assert rows["relative MSE x time, MALA Restore / MALA"][4] == pytest.approx(0.5)  # of medians
    curve = comparison.variance_curve("door", "restore", points=3)
    assert [t for t, _ in curve] == pytest.approx([1.0, 2.0, 4.0])
    variance_early = 2.0 / 1.01  # per element (0 - 2)^2 / 2 over (1 + eps)
    variance_late = 0.02 / 1.01 / 3  # one channel of three
    assert [v for _, v in curve] == pytest.approx([variance_early, variance_early, variance_late])
    assert comparison.variance_curve("door", "mala") == []  # no images kept


def test_snapshots_are_thinned_to_log_spaced_times_keeping_the_last():
    snapshots = [(float(t), np.zeros(1)) for t in range(1, 101)]
    kept = thin_snapshots(snapshots, keep=5)
    times = [t for t, _ in kept]
    assert len(kept) <= 5 and times[0] == 1.0 and times[-1] == 100.0
    assert times == sorted(times) and 3.0 <= times[1] <= 4.0  # near 100^(1/4) = 3.2
    assert thin_snapshots(snapshots[:3], keep=5) == snapshots[:3]
