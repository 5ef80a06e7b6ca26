"""The progress console: in a log a long progress line stays one line."""

from __future__ import annotations

import io

import pytest
from rich.text import Text

from deploy.consoles import LineProgress, progress_bar, progress_console


def test_a_long_progress_line_is_one_line_of_a_log(capsys: pytest.CaptureFixture[str]) -> None:
    line = "frame   135  constant  error    0.560 px  " + "x" * 80 + "  acquiring: target partial"
    console = progress_console()
    assert not console.is_terminal  # standard error is captured here, as in a log
    console.print(Text(line))
    assert capsys.readouterr().err == line + "\n"


def test_progress_in_a_log_is_a_line_per_tenth_of_the_task(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """rich draws a bar only on a terminal (and a transient one not even at its end): in a log
    minutes of drawing starts would show nothing. There it is a line per tenth done."""
    console = progress_console()
    with progress_bar(console, transient=True) as bar:
        assert isinstance(bar, LineProgress)
        task = bar.add_task("drawing starts", total=20)
        for _ in range(20):
            bar.advance(task)
        runs = bar.add_task("runs", total=3)
        bar.update(runs, advance=1, description="1 converged, 0 failed")
        bar.update(runs, completed=3, description="2 converged, 1 failed")
        unsized = bar.add_task("waiting")  # no total: nothing to say
        bar.advance(unsized)
    lines = capsys.readouterr().err.splitlines()
    drawing = [line for line in lines if line.startswith("drawing starts: ")]
    assert [line.split(" (")[0] for line in drawing] == [
        f"drawing starts: {n}/20" for n in range(2, 21, 2)
    ]
    assert drawing[-1].startswith("drawing starts: 20/20 (100%), ")
    assert lines[len(drawing) :][0].startswith("1 converged, 0 failed: 1/3 (33%), ")
    assert lines[len(drawing) :][1].startswith("2 converged, 1 failed: 3/3 (100%), ")
    assert len(lines) == len(drawing) + 2


def test_progress_on_a_terminal_is_richs_bar() -> None:
    from rich.console import Console
    from rich.progress import Progress

    terminal = Console(force_terminal=True, file=io.StringIO())
    assert isinstance(progress_bar(terminal), Progress)
