"""SIGINT/SIGTERM set a stop event through a relay thread, never in the handler: a handler runs
in the main thread, which may hold the event's own lock at that moment (common/stop_signals.py).
"""

from __future__ import annotations

import os
import signal
import threading

from common.stop_signals import SignalRelay, stop_on_signals


def call_holding_the_events_lock(event: threading.Event, handler) -> bool:
    """Call ``handler`` as a signal would, while this thread holds ``event``'s lock (as the
    main thread does inside ``event.wait``, or inside the ``set`` of a signal just before);
    whether it returned within a second. (``_cond`` is CPython's Event lock, the one
    ``set`` takes.)"""
    returned = threading.Event()

    def call() -> None:
        with event._cond:  # the lock the deadlock is about
            handler(signal.SIGTERM, None)
            returned.set()

    worker = threading.Thread(target=call, daemon=True)
    worker.start()
    return returned.wait(1.0)


def test_the_handler_returns_while_the_events_lock_is_held_and_the_event_is_set_after() -> None:
    stop = threading.Event()
    relay = SignalRelay(stop)
    try:
        assert call_holding_the_events_lock(stop, relay.handler)
        assert stop.wait(2.0)  # set by the relay once the lock is free
    finally:
        relay.close()


def test_setting_the_event_in_the_handler_is_the_deadlock_the_relay_avoids() -> None:
    """The check above can fail: the handler the services had (``lambda *_: stop.set()``)
    does not return while the lock is held."""
    stop = threading.Event()
    assert not call_holding_the_events_lock(stop, lambda *_: stop.set())
    # The stuck thread holds the lock; set() may never be called on this event again.


def test_a_real_sigterm_sets_the_event_and_the_handlers_come_back() -> None:
    stop = threading.Event()
    relay = SignalRelay(stop)
    previous = relay.install([signal.SIGUSR1])
    try:
        os.kill(os.getpid(), signal.SIGUSR1)
        assert stop.wait(2.0)
    finally:
        signal.signal(signal.SIGUSR1, previous[signal.SIGUSR1])
        relay.close()
    assert not relay._thread.is_alive()  # closed: its thread has ended


def test_on_signal_is_called_with_the_signal_number_and_many_signals_set_it_once() -> None:
    stop = threading.Event()
    seen: list[int] = []
    relay = SignalRelay(stop, seen.append)
    try:
        for _ in range(100_000):  # more bytes than the pipe holds: the handler never blocks
            relay.handler(signal.SIGINT, None)
        assert stop.wait(2.0) and seen[:1] == [signal.SIGINT] and len(seen) == 100_000
    finally:
        relay.close()


def test_stop_on_signals_installs_the_relay_for_sigint_and_sigterm() -> None:
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    stop = threading.Event()
    relay = stop_on_signals(stop)
    try:
        assert signal.getsignal(signal.SIGTERM) == relay.handler
        assert signal.getsignal(signal.SIGINT) == relay.handler
    finally:
        for sig, handler in before.items():
            signal.signal(sig, handler)
        relay.close()
