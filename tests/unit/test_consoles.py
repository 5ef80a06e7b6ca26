"""The progress console: in a log a long progress line stays one line."""

from __future__ import annotations

import pytest
from rich.text import Text

from deploy.consoles import progress_console


def test_a_long_progress_line_is_one_line_of_a_log(capsys: pytest.CaptureFixture[str]) -> None:
    line = "frame   135  constant  error    0.560 px  " + "x" * 80 + "  acquiring: target partial"
    console = progress_console()
    assert not console.is_terminal  # standard error is captured here, as in a log
    console.print(Text(line))
    assert capsys.readouterr().err == line + "\n"
