"""Ctrl-C and SIGTERM as a request to stop, for the commands that run work and must stop it
cleanly (``umay run``, ``compare``, ``campaign``, ``domains``) or run until told to stop
(``record``, ``view``, ``router``). ``umay up`` sets its own (it may run off the main thread,
where handlers cannot be installed)."""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator

from common.stop_signals import SIGNALS, SignalRelay


@contextlib.contextmanager
def stop_requested(second_interrupts: bool = False) -> Iterator[threading.Event]:
    """An event that Ctrl-C and SIGTERM set while the block runs, instead of raising; the
    handlers before it come back when the block is left. Only setting an event is safe: an
    exception raised at an arbitrary point of the main thread (inside
    ``concurrent.futures.wait``, holding a future's lock) could deadlock a pool; and the event
    is set by a thread, not the handler (:class:`~common.stop_signals.SignalRelay`).

    ``second_interrupts``: after the first signal, Ctrl-C raises ``KeyboardInterrupt`` again,
    for a user who does not want to wait for what stopping does (``umay run``'s summary)."""
    stop = threading.Event()

    def again(_signum: int) -> None:
        signal.signal(signal.SIGINT, signal.default_int_handler)

    # The event is set from a thread of the relay's: set in the handler, it could deadlock on
    # its own lock, held by the main thread inside stop.wait() (common/stop_signals.py).
    relay = SignalRelay(stop, again if second_interrupts else None)
    previous = relay.install(SIGNALS)
    try:
        yield stop
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        relay.close()
