"""Where the commands' progress goes: standard error, through rich."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from rich.console import Console
    from rich.progress import Progress, ProgressColumn

# Wide enough for any progress line: a log keeps each on one line of its own.
LOG_WIDTH = 1000
# A task's progress in a log: a line each time another tenth of it is done.
LOG_STEPS = 10


def progress_console() -> Console:
    """Standard error. In a terminal rich fits lines to its width; elsewhere (a log, a pipe,
    CI) it would wrap them at 80 columns and put the end of a line, a run's phase or its
    time, on a line of its own: there a line is never wrapped."""
    from rich.console import Console  # here: a command that prints no progress skips rich

    console = Console(stderr=True)
    if not console.is_terminal:
        console.width = LOG_WIDTH
    return console


def progress_bar(
    console: Console, *columns: str | ProgressColumn, transient: bool = False
) -> Progress | LineProgress:
    """rich's progress bar on a terminal. Elsewhere rich draws nothing until the bar ends
    (and nothing at all when ``transient``), so minutes of drawing starts or running a study
    look like a hang in a log: there a :class:`LineProgress` writes a line per tenth."""
    if not console.is_terminal:
        return LineProgress(console)
    from rich.progress import Progress

    return Progress(*columns, console=console, transient=transient)


@dataclass
class _Task:
    description: str
    total: float | None
    completed: float = 0.0
    said_steps: int = 0  # tenths of the task already written


@dataclass
class LineProgress:
    """The part of ``rich.progress.Progress`` the commands use (``add_task``, ``advance``,
    ``update``, ``console``) as lines of a log: ``drawing starts: 150/500 (30%), 42 s``, each
    time another tenth of a task is done."""

    console: Console
    steps: int = LOG_STEPS
    tasks: list[_Task] = field(default_factory=list)
    started_s: float = field(default_factory=time.monotonic)

    def __enter__(self) -> LineProgress:
        return self

    def __exit__(self, *_exc: object) -> None:  # nothing to take down: no live display
        return None

    def add_task(self, description: str, total: float | None = None, **_fields: Any) -> int:
        self.tasks.append(_Task(description, total))
        return len(self.tasks) - 1

    def advance(self, task_id: int, advance: float = 1.0) -> None:
        self.update(task_id, advance=advance)

    def update(
        self,
        task_id: int,
        *,
        advance: float | None = None,
        completed: float | None = None,
        description: str | None = None,
        **_fields: Any,
    ) -> None:
        task = self.tasks[task_id]
        if description is not None:
            task.description = description
        if completed is not None:
            task.completed = completed
        if advance is not None:
            task.completed += advance
        if not task.total:
            return
        step = min(self.steps, int(self.steps * task.completed / task.total))
        if step > task.said_steps:
            task.said_steps = step
            share = 100.0 * task.completed / task.total
            self.console.print(
                f"{task.description}: {task.completed:g}/{task.total:g} ({share:.0f}%), "
                f"{time.monotonic() - self.started_s:.0f} s",
                markup=False,
                highlight=False,
            )
