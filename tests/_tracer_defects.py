"""Defects planted in the PSS path tracer, for negative controls that an image comparison must fail.

Each replaces `power_heuristic` in `targets.mitsuba._path_tracer` through `monkeypatch`, so
the library is unchanged; targets built while it is active trace the defect (each
`PrimarySampleSpace` freezes its own tracer when it is built and first called).
"""

from __future__ import annotations

import itertools

from targets.mitsuba import _path_tracer


def unbalanced_mis(monkeypatch) -> None:
    """MIS weights that do not sum to one: each strategy is weighed against twice the other's pdf."""
    right = _path_tracer.power_heuristic
    monkeypatch.setattr(_path_tracer, "power_heuristic", lambda a, b: right(a, 2.0 * b))


def dropped_next_event(monkeypatch) -> None:
    """Next-event estimates weighed zero while emitter hits keep their MIS weight.

    `trace_paths` asks for the weight of a next-event estimate at bounce 0, then for an
    emitter hit and a next-event estimate at each later bounce: the even calls are the
    next-event estimates, in every path configuration.
    """
    right, calls = _path_tracer.power_heuristic, itertools.count()
    monkeypatch.setattr(_path_tracer, "power_heuristic", lambda a, b: right(a, b) * float(next(calls) % 2))
