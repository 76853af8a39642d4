"""Whether the `mitsuba` extra is installed, found without importing Mitsuba or Dr.Jit.

Importing Dr.Jit before `targets.mitsuba.load_mitsuba` has chosen its libLLVM would pin
the wrong one, so the Mitsuba test modules check with `find_spec` only.
"""

import importlib.util


def mitsuba_extra_installed() -> bool:
    try:
        return all(importlib.util.find_spec(name) is not None for name in ("mitsuba", "drjit"))
    except (ImportError, ValueError):
        return False
