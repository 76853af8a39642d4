"""Statistical checks run in float64 with fixed keys: they are deterministic.

The tests are arranged by kind, one folder each, and every test is marked with its
folder's kind, so `pytest -m unit` (or `-m "not docs"`, ...) selects by kind.
"""

import os

# The suite checks correctness, not speed. XLA's CPU compilation dominates its run time, and
# backend optimisation level 1 compiles about 40% faster for about 15% slower execution.
os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_backend_optimization_level=1").strip()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)


KINDS = ("unit", "statistical", "properties", "integration", "docs")


def pytest_collection_modifyitems(config, items):
    """Mark each test with the kind of the folder it is in.

    Tests that use a module-scoped fixture (a benchmark run, a shared sample) are also put
    in one `xdist_group` per module, so that with `--dist loadgroup` the fixture is
    computed by one worker only, while all other tests are spread one by one.
    """
    from pathlib import Path

    import pytest

    for item in items:
        kind = Path(str(item.path)).parent.name
        if kind in KINDS:
            item.add_marker(getattr(pytest.mark, kind))
        fixtures = getattr(item, "_fixtureinfo", None)
        definitions = fixtures.name2fixturedefs.values() if fixtures is not None else ()
        if any(defs and defs[-1].scope == "module" for defs in definitions):
            item.add_marker(pytest.mark.xdist_group(name=str(item.path)))
