"""Ctrl-C and SIGTERM as a request to stop, for the commands that run work and must stop it
cleanly (``umay run``, ``compare``, ``campaign``, ``domains``) or run until told to stop
(``record``, ``view``, ``router``). ``umay up`` sets its own (it may run off the main thread,
where handlers cannot be installed)."""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator

SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def stop_requested(second_interrupts: bool = False) -> Iterator[threading.Event]:
    """An event that Ctrl-C and SIGTERM set while the block runs, instead of raising; the
    handlers before it come back when the block is left. Only setting an event is safe: an
    exception raised at an arbitrary point of the main thread (inside
    ``concurrent.futures.wait``, holding a future's lock) could deadlock a pool.

    ``second_interrupts``: after the first signal, Ctrl-C raises ``KeyboardInterrupt`` again,
    for a user who does not want to wait for what stopping does (``umay run``'s summary)."""
    stop = threading.Event()

    def request(_signum: int, _frame: object) -> None:
        stop.set()
        if second_interrupts:
            signal.signal(signal.SIGINT, signal.default_int_handler)

    previous = {sig: signal.signal(sig, request) for sig in SIGNALS}
    try:
        yield stop
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
