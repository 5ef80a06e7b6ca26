"""SIGINT and SIGTERM as a ``threading.Event`` set, without the deadlock of setting it in the
handler.

A Python signal handler runs in the main thread between two of its bytecodes, possibly while
that thread holds the event's own lock: inside ``event.wait`` (a loop that waits on its stop
event), or inside the ``set`` of a signal that came just before (Ctrl-C reaches every process
of the terminal's group, and the supervisor then sends its SIGTERM). ``Event.set`` in the
handler then waits for that lock for ever: the service hung until the supervisor killed it.
So the handler only writes a byte into a pipe, and a thread of its own reads it and sets the
event (:class:`SignalRelay`).
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from collections.abc import Callable, Iterable
from types import FrameType

SIGNALS = (signal.SIGINT, signal.SIGTERM)

Handler = Callable[[int, FrameType | None], object] | int | None


class SignalRelay:
    """Sets ``event`` from a thread of its own when :meth:`handler` is called. ``on_signal``:
    also called in the handler, with the signal's number (it must take no lock either)."""

    def __init__(
        self, event: threading.Event, on_signal: Callable[[int], None] | None = None
    ) -> None:
        self.event = event
        self._on_signal = on_signal
        self._read_fd, self._write_fd = os.pipe()
        os.set_blocking(self._write_fd, False)
        self._thread = threading.Thread(target=self._relay, name="signal-relay", daemon=True)
        self._thread.start()

    def handler(self, signum: int, _frame: FrameType | None) -> None:
        """The signal handler: one byte into the pipe, no lock taken."""
        if self._on_signal is not None:
            self._on_signal(signum)
        # A full pipe holds earlier signals' bytes: the event is being set already.
        with contextlib.suppress(BlockingIOError):
            os.write(self._write_fd, b"\0")

    def install(self, signals: Iterable[int] = SIGNALS) -> dict[int, Handler]:
        """:meth:`handler` for ``signals`` (main thread only); the handlers it replaced."""
        return {sig: signal.signal(sig, self.handler) for sig in signals}

    def close(self) -> None:
        """End the relay's thread. Put the previous handlers back first: a signal after this
        would write into whatever file reuses the pipe's descriptor."""
        os.close(self._write_fd)
        self._thread.join(1.0)

    def _relay(self) -> None:
        while os.read(self._read_fd, 64):  # b"": the write end is closed
            self.event.set()
        os.close(self._read_fd)


def stop_on_signals(event: threading.Event, signals: Iterable[int] = SIGNALS) -> SignalRelay:
    """``event`` set by ``signals`` for the rest of the process (main thread only)."""
    relay = SignalRelay(event)
    relay.install(signals)
    return relay
