"""deploy.interrupts.stop_requested: Ctrl-C and SIGTERM set an event instead of raising, and
the handlers before it come back."""

from __future__ import annotations

import os
import signal

import pytest

from deploy.interrupts import stop_requested


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_sets_the_event_and_the_old_handler_comes_back(sig: signal.Signals) -> None:
    heard: list[int] = []
    before = signal.signal(sig, lambda signum, _frame: heard.append(signum))
    try:
        with stop_requested() as stop:
            assert not stop.is_set()
            os.kill(os.getpid(), sig)
            assert stop.wait(1.0)
        assert heard == []  # the block's handler took it, not the one before
        os.kill(os.getpid(), sig)
        assert heard == [sig]
    finally:
        signal.signal(sig, before)


def test_after_the_first_ctrl_c_a_second_one_interrupts_when_asked() -> None:
    with stop_requested(second_interrupts=True) as stop:
        os.kill(os.getpid(), signal.SIGINT)
        assert stop.wait(1.0)
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
            signal.sigtimedwait([], 0.1)  # a point where Python runs the handler
    with stop_requested() as stop:
        os.kill(os.getpid(), signal.SIGINT)
        os.kill(os.getpid(), signal.SIGINT)  # without it, a second Ctrl-C only asks again
        assert stop.wait(1.0)
