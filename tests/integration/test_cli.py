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


def test_compiled_programs_are_cached_in_the_user_cache_unless_turned_off(tmp_path, monkeypatch):
    import jax

    before = jax.config.jax_compilation_cache_dir
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    try:
        jax.config.update("jax_compilation_cache_dir", None)
        assert CliRunner().invoke(app, ["--no-cache", "demo", "--help"]).exit_code == 0
        assert jax.config.jax_compilation_cache_dir is None
        assert CliRunner().invoke(app, ["demo", "--help"]).exit_code == 0
        assert jax.config.jax_compilation_cache_dir == str(tmp_path / "restore" / "xla")
        monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", str(tmp_path / "mine"))
        assert CliRunner().invoke(app, ["demo", "--help"]).exit_code == 0
        assert jax.config.jax_compilation_cache_dir == str(tmp_path / "mine")
    finally:
        jax.config.update("jax_compilation_cache_dir", before)


def test_warnings_of_a_command_show_their_kind_and_message_without_a_library_frame():
    """A command has no line of the user's: its warnings are shown without the file and line of the
    frame they were attributed to (typer's, once the library's frames are skipped)."""
    import io
    import warnings

    from restore import UnreliableEstimateWarning
    from restore.cli import _show_warning

    printed = io.StringIO()
    with warnings.catch_warnings():
        assert CliRunner().invoke(app, ["--no-cache", "demo", "--help"]).exit_code == 0
        assert warnings.showwarning is _show_warning
        _show_warning(UnreliableEstimateWarning("log Z: the standard error cannot be trusted"), UnreliableEstimateWarning, "/x/typer/main.py", 1445, printed)
    assert printed.getvalue() == "UnreliableEstimateWarning: log Z: the standard error cannot be trusted\n"
