"""The example notebooks run top to bottom with small settings, and are stored without outputs.

Each notebook in `examples/` is executed with nbclient in a fresh kernel of this Python
(`sys.executable`), with `RESTORE_NOTEBOOK_SMALL=1` (small settings), `MPLBACKEND=Agg` and
this process's `XLA_FLAGS` at optimisation level 0, in a temporary working directory so that nothing lands in the
repository. A cell that raises fails the test with that cell's error.
"""

import json
import os
import re
import sys
from pathlib import Path

import nbformat
import pytest
from jupyter_client.kernelspec import KernelSpecManager
from jupyter_client.manager import KernelManager
from nbclient import NotebookClient
from nbclient.exceptions import CellExecutionError, CellTimeoutError, DeadKernelError

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
NOTEBOOKS = sorted(EXAMPLES.glob("*.ipynb"))
CELL_TIMEOUT = 300  # seconds per cell
KERNEL_NAME = "restore-notebooks"
ANSI = re.compile(r"\x1b\[[0-9;]*m")  # colours in IPython tracebacks


def _kernel_manager(spec_dir: Path) -> KernelManager:
    """A kernel of this very interpreter, whatever kernel specs are installed elsewhere."""
    spec = spec_dir / KERNEL_NAME
    spec.mkdir(parents=True)
    env = {"RESTORE_NOTEBOOK_SMALL": "1", "MPLBACKEND": "Agg"}
    # Small notebooks spend most of their time compiling: XLA's backend optimisation level 0
    # compiles them about a third faster, and their short runs barely notice the slower code.
    flags = re.sub(r"--xla_backend_optimization_level=\d+", "", os.environ.get("XLA_FLAGS", ""))
    env["XLA_FLAGS"] = (flags + " --xla_backend_optimization_level=0").strip()
    kernel = {
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "restore notebooks",
        "language": "python",
        "env": env,
    }
    (spec / "kernel.json").write_text(json.dumps(kernel))
    return KernelManager(kernel_name=KERNEL_NAME, kernel_spec_manager=KernelSpecManager(kernel_dirs=[str(spec_dir)]))


def test_there_are_notebooks():
    assert NOTEBOOKS, f"no notebooks in {EXAMPLES}"


@pytest.mark.slow
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_runs(path, tmp_path):
    notebook = nbformat.read(path, as_version=4)
    workdir = tmp_path / "work"
    workdir.mkdir()
    client = NotebookClient(
        notebook,
        km=_kernel_manager(tmp_path / "kernels"),
        timeout=CELL_TIMEOUT,
        startup_timeout=120,
        resources={"metadata": {"path": str(workdir)}},
    )
    try:
        client.execute()
    except CellExecutionError as error:  # the failing cell's source and traceback
        pytest.fail(f"{path.name} failed:\n{ANSI.sub('', str(error))}", pytrace=False)
    except (CellTimeoutError, DeadKernelError) as error:
        pytest.fail(f"{path.name} did not finish: {type(error).__name__}: {error}", pytrace=False)
    printed = [o for cell in notebook.cells if cell.cell_type == "code" for o in cell.outputs if o.get("name") == "stdout"]
    assert printed, f"{path.name} ran but printed nothing"


def test_the_kernel_is_this_python(tmp_path):
    """The kernel runs this interpreter in this environment (the virtual environment's packages)."""
    notebook = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell("import sys; print(sys.executable); print(sys.prefix)")])
    NotebookClient(notebook, km=_kernel_manager(tmp_path / "kernels"), timeout=60, startup_timeout=120).execute()
    executable, prefix = notebook.cells[0].outputs[0]["text"].splitlines()
    assert (executable, prefix) == (sys.executable, sys.prefix)


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
