"""The example notebooks: stored without outputs, run by the documentation build, listed in its navigation.

The strict documentation build (`tests/test_docs.py`) executes every notebook in
`examples/` with small settings through the hook `docs/hooks/notebooks.py` and fails on a
cell that raises, so the notebooks are run once per test session, there. The tests here
check the hook's executor itself (a broken cell fails, the kernel is this Python) on tiny
notebooks, and what needs no kernel.
"""

import importlib.util
import sys
from pathlib import Path

import nbformat
import pytest

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
NOTEBOOKS = sorted(EXAMPLES.glob("*.ipynb"))


def _hook():
    spec = importlib.util.spec_from_file_location("restore_docs_notebooks", ROOT / "docs" / "hooks" / "notebooks.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _notebook(*sources, tmp_path):
    path = tmp_path / "tiny.ipynb"
    nbformat.write(nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(s) for s in sources]), path)
    return path


def test_there_are_notebooks():
    assert NOTEBOOKS, f"no notebooks in {EXAMPLES}"
    assert [p.name for p in _hook().notebooks()] == [p.name for p in NOTEBOOKS]


def test_every_notebook_is_in_the_navigation():
    nav = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    missing = [p.name for p in NOTEBOOKS if f"examples/{p.name}" not in nav]
    assert not missing, f"notebooks missing from the nav of mkdocs.yml: {missing}"


def test_the_executor_runs_this_python_in_small_mode(tmp_path):
    path = _notebook(
        "import os, sys; print(sys.executable); print(sys.prefix); print(os.environ['RESTORE_NOTEBOOK_SMALL'])",
        tmp_path=tmp_path,
    )
    notebook = _hook().execute_notebook(path, tmp_path / "out.ipynb", tmp_path / "scratch")
    executable, prefix, small = notebook.cells[0].outputs[0]["text"].splitlines()
    assert (executable, prefix, small) == (sys.executable, sys.prefix, "1")
    assert nbformat.read(tmp_path / "out.ipynb", as_version=4).cells[0].outputs  # the executed copy


def test_a_broken_cell_fails_with_its_error(tmp_path):
    hook = _hook()
    path = _notebook("print('first cell runs')", "x = 1 / 0", tmp_path=tmp_path)
    with pytest.raises(hook.NotebookError, match="ZeroDivisionError"):
        hook.execute_notebook(path, tmp_path / "out.ipynb", tmp_path / "scratch")
    assert not (tmp_path / "out.ipynb").exists()


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_is_stored_without_outputs(path):
    notebook = nbformat.read(path, as_version=4)
    nbformat.validate(notebook)
    dirty = [
        i
        for i, cell in enumerate(notebook.cells)
        if cell.cell_type == "code" and (cell.get("outputs") or cell.get("execution_count") is not None)
    ]
    assert not dirty, f"{path.name}: cells {dirty} have outputs or execution counts; clear them before committing"
