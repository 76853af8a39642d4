"""MkDocs hook: the notebooks in `examples/` become pages of the site, executed at build time.

Each notebook runs top to bottom with nbclient in a fresh kernel of the Python that runs
mkdocs (so the project's environment), importing this checkout's packages, with small settings (`RESTORE_NOTEBOOK_SMALL=1`,
unless the environment sets it), XLA's backend optimisation level 0 (small runs spend
most of their time compiling) and a temporary working directory, so that nothing lands
in the repository. The executed copies are handed to mkdocs-jupyter, which renders them;
the stored notebooks stay free of outputs. A cell that raises fails the build with the
cell's source and traceback, and so does a notebook that prints nothing.

`RESTORE_DOCS_EXECUTE=0` renders the notebooks as stored, without running them (quick
previews with `mkdocs serve`). `RESTORE_DOCS_JOBS` sets how many notebooks run at once
(default 2).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from mkdocs.exceptions import PluginError
from mkdocs.plugins import event_priority
from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
#: Where the notebooks appear in the site.
SITE_FOLDER = "examples"
CELL_TIMEOUT = 300  # seconds per cell
KERNEL_NAME = "restore-notebooks"
ANSI = re.compile(r"\x1b\[[0-9;]*m")  # colours in IPython tracebacks

_build_dir: tempfile.TemporaryDirectory | None = None


class NotebookError(RuntimeError):
    """A notebook raised in a cell, timed out, or printed nothing."""


def notebooks() -> list[Path]:
    return sorted(EXAMPLES.glob("*.ipynb"))


def kernel_manager(spec_dir: Path, small: bool = True):
    """A kernel of this very interpreter, whatever kernel specs are installed elsewhere."""
    from jupyter_client.kernelspec import KernelSpecManager
    from jupyter_client.manager import KernelManager

    spec = spec_dir / KERNEL_NAME
    spec.mkdir(parents=True, exist_ok=True)
    env = {"RESTORE_NOTEBOOK_SMALL": os.environ.get("RESTORE_NOTEBOOK_SMALL", "1") if small else "0"}
    # Small notebooks spend most of their time compiling: XLA's backend optimisation level 0
    # compiles them about a third faster, and their short runs barely notice the slower code.
    flags = re.sub(r"--xla_backend_optimization_level=\d+", "", os.environ.get("XLA_FLAGS", ""))
    env["XLA_FLAGS"] = (flags + " --xla_backend_optimization_level=0").strip()
    env["MPLBACKEND"] = "module://matplotlib_inline.backend_inline"  # figures become outputs of their cells
    # The notebooks import this checkout's packages, whichever checkout the environment installed.
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH", "")]))
    kernel = {
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "restore notebooks",
        "language": "python",
        "env": env,
    }
    (spec / "kernel.json").write_text(json.dumps(kernel))
    return KernelManager(kernel_name=KERNEL_NAME, kernel_spec_manager=KernelSpecManager(kernel_dirs=[str(spec_dir)]))


def execute_notebook(path: Path, out: Path, scratch: Path):
    """Run the notebook at `path` and write the executed copy to `out`; raise `NotebookError` on failure."""
    import nbformat
    from nbclient import NotebookClient
    from nbclient.exceptions import CellExecutionError, CellTimeoutError, DeadKernelError

    notebook = nbformat.read(path, as_version=4)
    workdir = scratch / "work"
    workdir.mkdir(parents=True, exist_ok=True)
    client = NotebookClient(
        notebook,
        km=kernel_manager(scratch / "kernels"),
        timeout=CELL_TIMEOUT,
        startup_timeout=120,
        resources={"metadata": {"path": str(workdir)}},
    )
    try:
        client.execute()
    except CellExecutionError as error:  # the failing cell's source and traceback
        raise NotebookError(f"{path.name} failed:\n{ANSI.sub('', str(error))}") from None
    except (CellTimeoutError, DeadKernelError) as error:
        raise NotebookError(f"{path.name} did not finish: {type(error).__name__}: {error}") from None
    printed = [
        o for cell in notebook.cells if cell.cell_type == "code" for o in cell.outputs if o.get("name") == "stdout"
    ]
    if not printed:
        raise NotebookError(f"{path.name} ran but printed nothing")
    nbformat.write(notebook, out)
    return notebook


def _jobs() -> int:
    try:
        return max(1, int(os.environ.get("RESTORE_DOCS_JOBS", "2")))
    except ValueError:
        return 2


def on_config(config):
    global _build_dir
    _build_dir = tempfile.TemporaryDirectory(prefix="restore-docs-")
    return config


@event_priority(100)  # before mkdocs-jupyter's on_files, which turns .ipynb files into pages
def on_files(files, config):
    # The executed copies live in a folder of their own laid out as in the site, so that
    # mkdocs-jupyter reads them as it reads notebooks of the docs folder.
    source = Path(_build_dir.name) / "source"
    out = source / SITE_FOLDER
    out.mkdir(parents=True, exist_ok=True)
    paths = notebooks()
    if os.environ.get("RESTORE_DOCS_EXECUTE", "1") == "0":
        for path in paths:
            shutil.copy(path, out / path.name)
    else:

        def run(path: Path):
            try:
                execute_notebook(path, out / path.name, Path(_build_dir.name) / path.stem)
                return None
            except NotebookError as error:
                return str(error)

        with ThreadPoolExecutor(max_workers=_jobs()) as pool:
            failures = [message for message in pool.map(run, paths) if message]
        if failures:
            raise PluginError("notebooks in examples/ failed:\n\n" + "\n\n".join(failures))
    for path in paths:
        files.append(File(f"{SITE_FOLDER}/{path.name}", str(source), config.site_dir, config.use_directory_urls))
    return files


def on_post_build(config):
    global _build_dir
    if _build_dir is not None:
        _build_dir.cleanup()
        _build_dir = None
