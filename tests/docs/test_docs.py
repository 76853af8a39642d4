"""The documentation site builds with no warnings, and its API reference names every public object.

The build needs the `[docs]` extra (mkdocs-material, mkdocstrings[python], mkdocs-jupyter,
nbclient); without it these tests fail rather than skip, so that a missing extra is noticed.
The build executes every notebook in `examples/` with small settings (docs/hooks/notebooks.py)
and fails on a cell that raises: this is where the notebooks run in the test suite.
"""

import ast
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
API = ROOT / "docs" / "api"

#: The packages whose public names the API reference must cover.
PACKAGES = (
    "restore",
    "restore.local",
    "restore.dynamics",
    "restore.regeneration",
    "restore.transfer",
    "restore.testing",
    "restore.render",
    "restore.bench",
    "restore.plot",
    "targets.analytic",
    "targets.mitsuba",
    "targets.numpyro",
)

#: `::: identifier` lines of mkdocstrings, which render one object (and its members).
DIRECTIVE = re.compile(r"^:::\s+([\w.]+)\s*$", re.MULTILINE)


def exported_names(package: str) -> list[str]:
    """The public names of `package`, read from its `__init__.py` without importing it.

    `__all__` when the package defines it; otherwise every name re-exported with the
    explicit `from .module import name as name` form. Submodules (`from . import x as x`)
    have their own pages and are not counted here.
    """
    init = ROOT.joinpath(*package.split("."), "__init__.py")
    tree = ast.parse(init.read_text(encoding="utf-8"))
    names: list[str] = []
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets):
            return [ast.literal_eval(element) for element in node.value.elts]
        if isinstance(node, ast.ImportFrom) and node.module is not None:
            names += [alias.name for alias in node.names if alias.asname == alias.name]
    return [name for name in names if not name.startswith("_")]


def documented_identifiers() -> set[str]:
    return {match for page in API.glob("*.md") for match in DIRECTIVE.findall(page.read_text(encoding="utf-8"))}


def test_every_public_name_has_an_api_entry():
    documented = documented_identifiers()
    missing = [f"{package}.{name}" for package in PACKAGES for name in exported_names(package)]
    missing = [identifier for identifier in missing if identifier not in documented]
    assert not missing, (
        "public names without a `::: package.name` entry in docs/api/*.md: " + ", ".join(missing)
    )


def test_api_entries_name_public_objects():
    # Every entry names a public object of one of the packages (no stale or private entries).
    public = {f"{package}.{name}" for package in PACKAGES for name in exported_names(package)}
    stray = sorted(identifier for identifier in documented_identifiers() if identifier not in public)
    assert not stray, "docs/api/*.md documents names that are not exported: " + ", ".join(stray)


def test_every_package_is_scanned():
    for package in PACKAGES:
        assert exported_names(package), f"found no public names in {package}/__init__.py"


@pytest.mark.slow
def test_site_builds_strictly(tmp_path):
    env = dict(os.environ, NO_MKDOCS_2_WARNING="1")
    command = [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")]
    done = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, (
        f"`{' '.join(command[1:])}` failed with code {done.returncode} (is the [docs] extra installed?)\n"
        f"--- stdout ---\n{done.stdout}\n--- stderr ---\n{done.stderr}"
    )
    assert (tmp_path / "site" / "api" / "restore" / "index.html").is_file()
    for notebook in sorted((ROOT / "examples").glob("*.ipynb")):  # executed: its pages show outputs
        page = (tmp_path / "site" / "examples" / notebook.stem / "index.html").read_text(encoding="utf-8")
        assert "jp-OutputArea-output" in page, f"{notebook.name} was rendered without outputs"
    quick_start = (tmp_path / "site" / "examples" / "quick_start" / "index.html").read_text(encoding="utf-8")
    assert "data:image/png;base64" in quick_start, "the quick-start notebook's figures are missing"
