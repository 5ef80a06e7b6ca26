"""Where the commands' progress goes: standard error, through rich."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from rich.console import Console

# Wide enough for any progress line: a log keeps each on one line of its own.
LOG_WIDTH = 1000


def progress_console() -> Console:
    """Standard error. In a terminal rich fits lines to its width; elsewhere (a log, a pipe,
    CI) it would wrap them at 80 columns and put the end of a line, a run's phase or its
    time, on a line of its own: there a line is never wrapped."""
    from rich.console import Console  # here: a command that prints no progress skips rich

    console = Console(stderr=True)
    if not console.is_terminal:
        console.width = LOG_WIDTH
    return console
