"""One-off notes for the user, printed above the progress bars (the bars themselves: `_driver.Meter`)."""

from __future__ import annotations


def console_note(message: str) -> None:
    """Print a one-off note for the user above the progress bars (dimmed)."""
    from rich.console import Console

    Console(stderr=True).print(f"[dim]{message}[/]", soft_wrap=True)
