"""Stopping the view does not wait for a client that stopped reading: the SDK's stop is held
by such a client until it goes away, so it runs on a thread that is waited for a while."""

from __future__ import annotations

import threading
import time

import pytest

from deploy.foxglove.node import stop_server


class HeldServer:
    """A server whose stop returns only when ``release`` is set (a stalled client)."""

    def __init__(self) -> None:
        self.release = threading.Event()
        self.stopped = threading.Event()

    def stop(self) -> None:
        self.release.wait()
        self.stopped.set()


def test_stop_gives_up_on_a_held_server_and_says_so(capsys: pytest.CaptureFixture[str]) -> None:
    server = HeldServer()
    started = time.monotonic()
    stop_server(server, timeout_s=0.2)  # type: ignore[arg-type]
    assert time.monotonic() - started < 2.0
    assert "a client still holds the server after 0.2 s" in capsys.readouterr().err
    server.release.set()  # the client goes: the stop it was holding completes
    assert server.stopped.wait(2.0)


def test_a_server_that_stops_at_once_is_stopped_without_a_note(
    capsys: pytest.CaptureFixture[str],
) -> None:
    server = HeldServer()
    server.release.set()
    stop_server(server, timeout_s=5.0)  # type: ignore[arg-type]
    assert server.stopped.is_set() and capsys.readouterr().err == ""
