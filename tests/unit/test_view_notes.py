"""What ``umay view`` tells a user about what it hears (pure: no session, no server)."""

from __future__ import annotations

from deploy.foxglove.node import SILENT_AFTER_S, listening_note

WHERE = "tcp/127.0.0.1:7447"


def note(heard: int, listening_s: float, warned: bool = False) -> str | None:
    return listening_note(heard, listening_s, warned, "lab/arm", WHERE)


def test_nothing_heard_for_a_while_says_where_it_listened() -> None:
    assert note(0, SILENT_AFTER_S - 0.5) is None  # a slow start is not yet silence
    said = note(0, SILENT_AFTER_S)
    assert said is not None and f"nothing heard under lab/arm at {WHERE} for 10 s" in said
    assert "--prefix" in said and "--connect" in said


def test_heard_from_the_start_says_nothing_and_after_a_warning_says_it_hears() -> None:
    assert note(5, 2 * SILENT_AFTER_S) is None
    assert note(0, 2 * SILENT_AFTER_S, warned=True) is None  # said once, not every second
    assert note(3, 2 * SILENT_AFTER_S, warned=True) == "hearing lab/arm now"
