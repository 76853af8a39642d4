"""Smoke test of the comparison suite: a tiny configuration through the real code path, and the CLI."""

import csv
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from restore.bench import Budget, SuiteConfig, mmd, run_suite
from restore.cli import app


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """One problem (2-d mixture), jump Restore RW, MH RW, emcee stretch (8 walkers) and exact draws, one seed."""
    out = tmp_path_factory.mktemp("bench")
    return run_suite(SuiteConfig.tiny(), out, progress=False), out


def test_files_are_written(tiny):
    result, out = tiny
    for name in ("results.csv", "results.md", "curves-gmm2.png", "ratios.png"):
        assert (out / name).stat().st_size > 1000, name
    text = (out / "results.md").read_text()
    assert "Recorded ratios" in text and "## Machine" in text and "curves-gmm2.png" in text
    with open(out / "results.csv") as f:
        rows = list(csv.DictReader(f))
    # 4 samplers x 2 budget points, plus the equal-time runs of MH and emcee.
    assert len(rows) == len(result.rows) == 10
    assert {r["sampler"] for r in rows} == {"restore-rw", "mh-rw", "emcee-stretch-8", "exact"}


def test_numbers_are_finite_and_sane(tiny):
    result, _ = tiny
    for r in result.rows:
        assert r["evaluations"] > 0 and 0 <= r["run_time"] <= r["wall_time"] + 1e-9, r
        for key in ("mode_rmse", "mean_error", "second_moment_error", "mmd", "evals_per_s"):
            assert math.isfinite(r[key]) and r[key] >= 0, (key, r)
        assert r["mode_rmse"] < 0.3, r  # every sampler started with all three modes found
        assert r["modes_found"] == 3


def test_equal_evaluation_runs_used_equal_evaluations(tiny):
    """Within one step of all lanes or walkers: |difference| <= max(lanes, walkers) = 32, under 1% here."""
    result, _ = tiny
    restore = {r["fraction"]: r["evaluations"] for r in result.rows if r["sampler"] == "restore-rw"}
    for r in result.rows:
        if r["budget"] == "evaluations" and r["sampler"] != "restore-rw":
            assert r["asked"] == restore[r["fraction"]]
            assert abs(r["evaluations"] - r["asked"]) <= 32, r
            assert abs(r["evaluations"] - r["asked"]) / r["asked"] < 0.01


def test_time_budgets_follow_jump_restore(tiny):
    result, _ = tiny
    ours = next(r for r in result.rows if r["sampler"] == "restore-rw" and r["fraction"] == 1.0)
    timed = [r for r in result.rows if r["budget"] == "time"]
    assert {r["sampler"] for r in timed} == {"mh-rw", "emcee-stretch-8"}
    for r in timed:
        assert r["asked"] == pytest.approx(ours["run_time"])


def test_exact_draws_score_near_zero(tiny):
    """The ideal sampler's errors are sampling noise only; a broken metric or reference would show here."""
    result, _ = tiny
    for r in (r for r in result.rows if r["sampler"] == "exact"):
        assert r["mode_rmse"] < 0.03 and r["mean_error"] < 0.08 and r["second_moment_error"] < 0.08, r
        assert r["mmd"] < 0.08, r


def test_recorded_ratios(tiny):
    result, _ = tiny
    names = {r.name for r in result.ratios}
    assert any(n.startswith("error / best emcee") for n in names)
    assert any(n.startswith("error / MH (rw)") for n in names)
    assert any("fastest emcee" in n for n in names) and any("raw jit" in n for n in names)
    for r in result.ratios:
        assert math.isfinite(r.value) and r.value > 0, r


def test_mmd_separates_laws():
    rng = np.random.default_rng(0)
    x, y, z = rng.normal(size=(400, 2)), rng.normal(size=(400, 2)), rng.normal(size=(400, 2)) + 1.0
    w = np.ones(400) / 400
    assert mmd(x, w, y, 1.0) < 0.08 < mmd(z, w, y, 1.0)


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="unknown problem"):
        SuiteConfig.tiny().replace(problems=("nope",))
    with pytest.raises(ValueError, match="fractions"):
        SuiteConfig.tiny().replace(fractions=(0.5,))
    with pytest.raises(ValueError, match="time budget"):
        Budget.seconds(-1.0)


def test_cli_bench_help():
    out = CliRunner().invoke(app, ["bench", "--help"])
    assert out.exit_code == 0, out.output
    for flag in ("--quick", "--out", "--seeds", "--no-progress"):
        assert flag in out.output


def test_ctrl_c_keeps_and_writes_the_finished_runs(tmp_path):
    def interrupt_after_two_runs(line, seen=[]):  # noqa: B006 - counts calls
        seen.append(line)
        if len(seen) == 2:
            raise KeyboardInterrupt

    config = SuiteConfig.tiny().replace(samplers=("restore",))
    result = run_suite(config, tmp_path, progress=False, log=interrupt_after_two_runs)
    assert result.interrupted and len(result.rows) == 2
    assert "Interrupted" in (tmp_path / "results.md").read_text()
    assert len((tmp_path / "results.csv").read_text().splitlines()) == 3
