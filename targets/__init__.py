"""Densities to sample: analytic targets, light transport (`targets.mitsuba`) and NumPyro models (`targets.numpyro`)."""

from . import analytic as analytic
from .analytic import AnalyticImage as AnalyticImage


def __getattr__(name: str):
    """Lazy `targets.mitsuba` and `targets.numpyro` (each needs its optional extra only when used)."""
    if name in ("mitsuba", "numpyro"):
        import importlib

        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
