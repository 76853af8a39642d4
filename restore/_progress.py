"""A progress bar for long runs, advanced between jitted chunks (never inside the loop)."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator


@contextlib.contextmanager
def progress_bar(total: int, description: str, enabled: bool = True, completed: int = 0) -> Iterator[Callable[[int], None]]:
    """Yield a function that advances a rich progress bar by a number of steps."""
    if not enabled:
        yield lambda n: None
        return
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    columns = (
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("steps"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    )
    with Progress(*columns, transient=False) as bar:
        task = bar.add_task(description, total=total, completed=completed)
        yield lambda n: bar.advance(task, n)


def console_note(message: str) -> None:
    """Print a one-off note for the user above the progress bars (dimmed)."""
    from rich.console import Console

    Console(stderr=True).print(f"[dim]{message}[/]", soft_wrap=True)
