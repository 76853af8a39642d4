"""Warnings that point at the user's line, with advice that fits the call they made.

`warnings.warn`'s `stacklevel` counts frames, and the same check runs at different depths
(`sample` called by the user, or by `autosample`, or an estimate asked of an `AutoResult`),
so a fixed level points into the library half the time. `warn` attributes each warning
to the first frame outside this package (and the `targets` beside it) and the libraries its
calls pass through (Equinox's bound methods, JAX's transformations) instead.

What to do about an unreliable estimate depends on how the run was built: a hand-built
regeneration can be replaced by `autosample`'s, while `autosample`'s own final run needs
other advice. `advice` holds the advice of the call in progress.
"""

from __future__ import annotations

import contextlib
import contextvars
import os
import sys
import warnings
from collections.abc import Iterator
from types import FrameType

import equinox
import jax

_PACKAGE = os.path.dirname(os.path.abspath(__file__))
#: Frames of these folders are the library's: restore and the `targets` shipped beside it, and
#: Equinox and JAX, through which a call of a module's method or a transformed function passes.
_LIBRARY = tuple(os.path.join(os.path.dirname(_PACKAGE), name) + os.sep for name in ("restore", "targets")) + tuple(
    os.path.dirname(os.path.abspath(module.__file__)) + os.sep for module in (equinox, jax) if module.__file__
)

#: What to do about a regeneration far from the target, for a run the user built.
SAMPLE_ADVICE = (
    "use a regeneration distribution closer to the target (restore.autosample builds one in stages), or run longer"
)
#: The same for `autosample`'s final run, whose regeneration the stages built.
AUTOSAMPLE_ADVICE = (
    "autosample's stages did not reach healthy tours (see the result's stages): give it more stages "
    "(max_stages) or steps (stage_steps, num_steps), a tighter box, scale or prior, or a local kernel "
    "suited to the target's geometry (local=)"
)

_advice: contextvars.ContextVar[str] = contextvars.ContextVar("restore_advice", default=SAMPLE_ADVICE)


def advice() -> str:
    """The advice for a regeneration far from the target, in the call in progress."""
    return _advice.get()


@contextlib.contextmanager
def advising(text: str) -> Iterator[None]:
    """Give `text` as the advice of the runs started within."""
    token = _advice.set(text)
    try:
        yield
    finally:
        _advice.reset(token)


def warn(message: str, category: type[Warning] = UserWarning) -> None:
    """`warnings.warn`, attributed to the first caller outside restore, `targets`, Equinox and JAX (the user's line)."""
    caller: FrameType | None = sys._getframe(1)
    level = 2
    while caller is not None and caller.f_code.co_filename.startswith(_LIBRARY):
        caller, level = caller.f_back, level + 1
    warnings.warn(message, category, stacklevel=level - 1 if caller is None else level)
