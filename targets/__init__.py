"""Densities to sample: analytic targets (and later light transport)."""

from . import analytic as analytic
from .analytic import AnalyticImage as AnalyticImage


def __getattr__(name: str):
    """Lazy `targets.mitsuba` (it needs the optional `mitsuba` extra only when used)."""
    if name == "mitsuba":
        import importlib

        return importlib.import_module(".mitsuba", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
