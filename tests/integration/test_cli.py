"""The command line: help, and a small demo run that prints its table and writes its plot."""

from typer.testing import CliRunner

from restore.cli import app


def test_help_lists_the_demo():
    out = CliRunner().invoke(app, ["--help"])
    assert out.exit_code == 0 and "demo" in out.output


def test_small_demo_prints_the_table_and_writes_the_plot(tmp_path):
    png = tmp_path / "demo.png"
    args = ["demo", "--dim", "3", "--lanes", "32", "--steps", "300", "--no-progress", "--out", str(png)]
    out = CliRunner().invoke(app, args)
    assert out.exit_code == 0, out.output
    assert "Mode weights" in out.output and "RMSE" in out.output and "wall time" in out.output
    assert png.stat().st_size > 10_000
