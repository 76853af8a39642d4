"""Statistical checks run in float64 with fixed keys: they are deterministic.

The tests are arranged by kind, one folder each, and every test is marked with its
folder's kind, so `pytest -m unit` (or `-m "not docs"`, ...) selects by kind.
"""

import os

# The suite checks correctness, not speed. XLA's CPU compilation dominates its run time, and
# backend optimisation level 1 compiles about 40% faster for about 15% slower execution.
os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_backend_optimization_level=1").strip()

from pathlib import Path  # noqa: E402

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)


KINDS = ("unit", "statistical", "properties", "integration", "docs")


def pytest_collection_modifyitems(config, items):
    """Mark each test with the kind of the folder it is in."""
    for item in items:
        kind = Path(str(item.path)).parent.name
        if kind in KINDS:
            item.add_marker(getattr(pytest.mark, kind))
