"""The evidence benchmark: problems with an exact log Z, honest evaluation counts, a tiny run of the suite, the CLI."""

import csv
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.scipy.special import logsumexp
from typer.testing import CliRunner

from restore.bench import (
    EVIDENCE_PROBLEMS,
    CountedDensity,
    EvidenceConfig,
    EvidenceOutput,
    EvidenceProblem,
    EvidenceRunner,
    NUTSRunner,
    TemperedSMCRunner,
    get_evidence_problem,
    run_evidence,
)
from restore.bench._evidence import score_evidence
from restore.cli import app


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """The 2-d 40-mode mixture, every method with a tiny budget, one seed."""
    out = tmp_path_factory.mktemp("evidence")
    return run_evidence(EvidenceConfig.tiny(), out, progress=False), out


class _Counted(EvidenceProblem):
    """A problem whose log density counts its evaluations."""

    @functools.cached_property
    def logdensity(self):
        return CountedDensity(super().logdensity)


def _counted(name: str) -> _Counted:
    p = get_evidence_problem(name)
    return _Counted(f"{name}-counted", p.title, p.make_target, p.offset, p.half_widths, p.hmc_steps)


# ------------------------------------------------------------------------------------------ problems


@pytest.mark.parametrize("name", sorted(EVIDENCE_PROBLEMS))
def test_problem_density_and_truth_carry_the_same_offset(name):
    problem = get_evidence_problem(name)
    x = problem.target.sample(jax.random.key(0), 5)
    shift = jax.vmap(problem.logdensity)(x) - jax.vmap(problem.target.logdensity)(x)
    np.testing.assert_allclose(shift, problem.offset, atol=1e-12)
    assert problem.log_normalising_constant == pytest.approx(problem.target.log_normalising_constant + problem.offset)
    assert abs(problem.log_normalising_constant) > 1.0  # nobody can guess it
    lower, upper = problem.box
    assert lower.shape == upper.shape == (problem.dim,) and np.all(lower < upper)


def test_truth_matches_an_independent_estimate_and_a_wrong_offset_is_detected():
    """log Z of the 2-d mixture problem by plain Monte Carlo over its box: a truth off by 0.1 nats fails."""
    problem = get_evidence_problem("gmm40")
    x = problem.uniform_points(jax.random.key(7), 2**18)  # relative se 0.009: the 0.1 offset is 11 se away
    log_p = jax.jit(jax.vmap(problem.logdensity))(x)
    n = log_p.shape[0]
    log_mean = float(logsumexp(log_p) - math.log(n))
    relative_se = float(jnp.std(jnp.exp(log_p - log_mean)) / math.sqrt(n))
    estimate = log_mean + problem.log_box_volume
    assert relative_se < 0.02
    assert abs(estimate - problem.log_normalising_constant) < 4 * relative_se
    assert abs(estimate - (problem.log_normalising_constant + 0.1)) > 4 * relative_se


def test_reference_is_exact_and_box_holds_the_mass():
    ref = get_evidence_problem("manywell32").reference(jax.random.key(1), 4096)
    assert ref.log_z == pytest.approx(164.6957, abs=1e-4)
    assert ref.positive_probability == pytest.approx(0.8443, abs=1e-4)
    assert ref.outside_share == 0.0
    np.testing.assert_allclose(ref.second_moment[1::2], 1.0)
    assert get_evidence_problem("gmm40").reference(jax.random.key(1), 4096).positive_probability is None


def test_score_signs_and_z_scores():
    ref = get_evidence_problem("gmm40").reference(jax.random.key(1), 256)
    out = EvidenceOutput(
        log_z=ref.log_z + 0.2, log_z_se=0.1, mean=ref.mean + 0.3 * ref.sd, mean_se=np.full(2, 0.1 * ref.sd[0]),
        second_moment=ref.second_moment, second_moment_se=np.ones(2), positive=math.nan, positive_se=math.nan,
        evaluations=10, wall_time=1.0, compile_time=0.25,
    )
    row = score_evidence(out, ref)
    assert row["log_z_error"] == pytest.approx(0.2) and row["abs_log_z_error"] == pytest.approx(0.2)
    assert row["log_z_z"] == pytest.approx(2.0)
    assert row["mean_error"] == pytest.approx(0.3)
    assert row["max_z_mean"] == pytest.approx(3.0 * ref.sd.max() / ref.sd[0])
    assert row["max_z_second"] == pytest.approx(0.0) and row["second_moment_error"] == pytest.approx(0.0)
    assert math.isnan(row["positive_error"])
    assert out.run_time == pytest.approx(0.75)


# ------------------------------------------------------------------------------- evaluation counts


@pytest.mark.parametrize("dense", [False, True])
def test_smc_counts_every_evaluation(dense):
    problem = _counted("gmm40")
    out = TemperedSMCRunner(particles=16, mcmc_steps=2, dense=dense).run(problem, jax.random.key(0))
    assert out.evaluations == problem.logdensity.count > 0
    assert out.status == "ok" and math.isfinite(out.log_z)


def _gaussian_problem(means, half_width: float) -> EvidenceProblem:
    """A small problem of equal-weight unit Gaussians at `means` (one mean: a Gaussian)."""
    from targets.analytic import GaussianMixture

    means = np.asarray(means, np.float64)
    return EvidenceProblem(f"gaussians{len(means)}", "unit Gaussians", lambda: GaussianMixture(means, 1.0), 1.5, (half_width,))


def test_nuts_gives_moments_with_honest_errors_and_its_users_verdict():
    """On a 3-d Gaussian NUTS's means are within 5 of ArviZ's standard errors and the run passes
    Stan's R-hat and ESS rule; its evaluations are its gradients."""
    problem = _gaussian_problem([[1.0, -2.0, 0.5]], 5.0)
    out = NUTSRunner(chains=4, warmup=300, kept=300).run(problem, jax.random.key(1))
    assert math.isnan(out.log_z) and out.status == "ok"
    z = (out.mean - problem.target.mean) / out.mean_se
    assert np.all(np.abs(z) < 5), z
    assert out.reliable is True and "R-hat" in out.notes
    assert out.evaluations >= 4 * 600  # at least one gradient per step


def test_nuts_chains_in_separate_modes_are_marked_unreliable():
    """The control: two modes 20 apart, chains that start in both and never cross, so R-hat is far above 1.01."""
    problem = _gaussian_problem([[-10.0, 0.0], [10.0, 0.0]], 15.0)
    out = NUTSRunner(chains=4, warmup=200, kept=200).run(problem, jax.random.key(0))
    assert out.reliable is False, out.notes


# ---------------------------------------------------------------------------------------- the suite


def test_files_are_written(tiny):
    result, out = tiny
    text = (out / "evidence.md").read_text()
    assert "## Methods" in text and "## Machine" in text and "Exact log Z" in text and "dynesty" in text
    with open(out / "evidence.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(result.rows) == 6
    assert {r["method"] for r in rows} == {"restore-laplace", "restore-autosample", "smc-hmc", "smc-hmc-dense", "dynesty", "nuts"}


def test_numbers_are_finite(tiny):
    result, _ = tiny
    for r in result.rows:
        assert r["log_z_true"] == get_evidence_problem(r["problem"]).log_normalising_constant
        if r["status"] in ("ok", "capped"):
            assert math.isfinite(r["log_z"]) != (r["family"] == "mcmc") and r["evaluations"] > 0, r  # NUTS gives no log Z
            assert 0 <= r["run_time"] <= r["wall_time"], r
            assert math.isfinite(r["mean_error"]) and math.isfinite(r["second_moment_error"]), r
    done = {(r["problem"], r["method"]) for r in result.rows if r["status"] in ("ok", "capped")}
    assert {("gmm40", "restore-laplace"), ("gmm40", "smc-hmc"), ("gmm40", "dynesty")} <= done
    restore_row = next(r for r in result.rows if r["problem"] == "gmm40" and r["method"] == "restore-laplace")
    assert restore_row["log_z_se"] > 0 and math.isfinite(restore_row["max_z_mean"])


def test_laplace_recipe_failure_on_the_funnel_is_a_row(tmp_path):
    """The funnel has no mode: the hand-built recipe fails, and the failure is a row of the report."""
    config = EvidenceConfig.tiny().replace(problems=("funnel10",), samplers=("restore-laplace",), reference_draws=64)
    result = run_evidence(config, tmp_path, progress=False)
    out = tmp_path
    row = next(r for r in result.rows if r["problem"] == "funnel10" and r["method"] == "restore-laplace")
    assert row["status"] == "failed" and row["notes"].startswith("ValueError")
    assert "failed" in (out / "evidence.md").read_text()


def test_autosample_runs_and_reports_its_diagnostics(tiny):
    """The one-call path's rows carry k_hat and reliability, right within 5 standard errors or flagged (its
    false flags are bounded where runs are right: tests/statistical/test_autosample*.py)."""
    result, out = tiny
    rows = [r for r in result.rows if r["method"] == "restore-autosample"]
    assert {r["problem"] for r in rows} == {"gmm40"}
    for r in rows:
        assert r["status"] == "ok" and math.isfinite(r["log_z"]) and r["evaluations"] > 0, r
        assert math.isfinite(r["k_hat"]) and r["reliable"] in ("True", "False"), r
        assert abs(r["log_z"] - r["log_z_true"]) < 5 * r["log_z_se"] or r["reliable"] == "False", r
    assert "restore-autosample" in (out / "evidence.md").read_text()


class _Fake(EvidenceRunner):
    family = "fake"

    def __init__(self, name: str, interrupt: bool = False):
        self.name, self.interrupt = name, interrupt

    def run(self, problem, key):
        if self.interrupt:
            raise KeyboardInterrupt
        return EvidenceOutput(problem.log_normalising_constant, 0.1, None, None, None, None, math.nan, math.nan, 5, 0.5, 0.0)


def test_ctrl_c_keeps_and_writes_the_finished_runs(tmp_path, monkeypatch):
    monkeypatch.setattr(EvidenceConfig, "runners", lambda self: [_Fake("first"), _Fake("second", interrupt=True)])
    result = run_evidence(EvidenceConfig.tiny().replace(problems=("gmm40",), reference_draws=64), tmp_path, progress=False)
    assert result.interrupted and [r["method"] for r in result.rows] == ["first"]
    assert result.rows[0]["abs_log_z_error"] == 0.0
    assert "Interrupted" in (tmp_path / "evidence.md").read_text()


def test_cli_runs_the_evidence_benchmark(tmp_path, monkeypatch):
    small = EvidenceConfig.tiny().replace(problems=("gmm40",), samplers=("dynesty",), reference_draws=64)
    monkeypatch.setattr(EvidenceConfig, "quick", classmethod(lambda cls: small))
    outcome = CliRunner().invoke(app, ["bench", "--evidence", "--quick", "--out", str(tmp_path), "--no-progress"])
    assert outcome.exit_code == 0, outcome.output
    assert "log Z error" in outcome.output and (tmp_path / "evidence.csv").exists()
    bad = CliRunner().invoke(app, ["bench", "--evidence", "--medium"])
    assert bad.exit_code == 1 and "--medium" in bad.output
    unknown = CliRunner().invoke(app, ["bench", "--evidence", "--problems", "nope"])
    assert unknown.exit_code == 1 and "unknown evidence problem" in unknown.output


def test_config_errors():
    with pytest.raises(ValueError, match="unknown evidence problem"):
        EvidenceConfig("x", problems=("gmm2",))
    with pytest.raises(ValueError, match="seeds"):
        EvidenceConfig("x", seeds=0)
    assert [r.name for r in EvidenceConfig.tiny().replace(samplers=("smc", "dyn")).runners()] == ["smc-hmc", "smc-hmc-dense", "dynesty"]
