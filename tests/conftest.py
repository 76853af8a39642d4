"""Statistical checks run in float64 with fixed keys: they are deterministic.

The tests are arranged by kind, one folder each, and every test is marked with its
folder's kind, so `pytest -m unit` (or `-m "not docs"`, ...) selects by kind.
"""

import os

# The suite checks correctness, not speed. XLA's CPU compilation dominates its run time:
# backend optimisation level 1 compiles about 40% faster for about 15% slower execution, and
# XLA's older CPU kernel emitters cut the suite's compile time by another quarter (every
# program but the renderer's, which keeps the newer ones: `restore/_compile.py`).
os.environ["XLA_FLAGS"] = (
    os.environ.get("XLA_FLAGS", "") + " --xla_backend_optimization_level=1 --xla_cpu_use_fusion_emitters=false"
).strip()

from pathlib import Path  # noqa: E402

# Compiled programs are cached on disk and shared by the two test workers and by every
# process they start (the CLI, checkpoint resumes, the notebooks of the docs build): a
# program compiled once is loaded, not compiled, wherever it comes again. Minimum compile
# time 0: most of the suite's programs compile in well under JAX's default of 1 s.
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(Path(__file__).resolve().parents[1] / ".jax-cache"))
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)
jax.devices()  # XLA reads XLA_FLAGS once, when the backend starts: start it now, not in a test that changes them


KINDS = ("unit", "statistical", "properties", "integration", "docs")


def pytest_collection_modifyitems(config, items):
    """Mark each test with the kind of the folder it is in."""
    for item in items:
        kind = Path(str(item.path)).parent.name
        if kind in KINDS:
            item.add_marker(getattr(pytest.mark, kind))
