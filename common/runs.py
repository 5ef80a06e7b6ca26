"""Which run of the sim a message belongs to. Pure.

The sim draws a number when it starts (:func:`new_run`) and stamps it on every message it
publishes (``Header.run``); vision, the controller and actuation copy their input's into what
they derive from it. A restarted sim begins a new run: frame numbers and sim time start again
from 0 and the arm from its start posture, so what a service keeps for a run (messages waiting
for their partner frame, vision's tracking, the controller's memory, the limiter's last
command) belongs to a run that is over. :class:`RunWatch` tells, message by message, whether it
belongs to the run in progress, begins a new one, or is left over from an earlier one (in
flight when the sim restarted: to be dropped, since its frame numbers mean other frames now);
a run taken for over that keeps coming with nothing of the run in progress between is the live
one after all (a stray message had taken its place) and takes it back.
Run 0 is a run like any other: the messages of recordings made before runs were stamped, and
of sources that do not draw one (the bench's synthetic frames, the in-process pipeline).
"""

from __future__ import annotations

import secrets
from collections import deque
from collections.abc import Callable
from enum import Enum

RUN_BITS = 62  # fits msgpack's and JSON's integers, and Header.run's range


def new_run() -> int:
    """A run number for a sim starting now: random, so a restart never repeats its last."""
    return secrets.randbits(RUN_BITS) or 1  # 0 is left to the unstamped


class RunVerdict(Enum):
    SAME = "same"  # the run in progress
    NEW = "new"  # a run not seen before: it replaces the one in progress
    OVER = "over"  # a run that was replaced: its messages are left over


# Messages of one run taken for over, in a row with none of the run in progress between: that
# run is the live one after all. A stray message of a run never seen (sent long before, or by
# a process that was frozen) otherwise took the live run's place for good; a backlog of a run
# that did end is shorter (a frame's messages in lockstep) and is interleaved with the new one.
REVIVE_AFTER = 10


class RunWatch:
    """The run in progress, from the runs of the messages as they come, and the last
    ``remembered`` runs it replaced."""

    def __init__(self, remembered: int = 8, revive_after: int = REVIVE_AFTER) -> None:
        self.current: int | None = None
        self._over: deque[int] = deque(maxlen=remembered)
        self.revive_after = revive_after
        self._streak: tuple[int | None, int] = (None, 0)  # an over run heard in a row, how often

    def see(self, run: int) -> RunVerdict:
        """What a message of ``run`` is; a new run becomes the one in progress, and so does an
        over one heard :data:`REVIVE_AFTER` times in a row."""
        if run == self.current:
            self._streak = (None, 0)
            return RunVerdict.SAME
        if run in self._over:
            heard, times = self._streak
            times = times + 1 if heard == run else 1
            self._streak = (run, times)
            if times < self.revive_after:
                return RunVerdict.OVER
            self._over.remove(run)  # the live one: it takes the place back
        self._streak = (None, 0)
        if self.current is not None:
            self._over.append(self.current)
        self.current = run
        return RunVerdict.NEW

    def admit(self, run: int, on_new: Callable[[], None]) -> bool:
        """Whether a message of ``run`` is to be used, i.e. not left over from a run that is
        over (the caller counts it dropped); ``on_new`` is called first when it begins a new
        run, for the service to start it afresh."""
        verdict = self.see(run)
        if verdict is RunVerdict.NEW:
            on_new()
        return verdict is not RunVerdict.OVER
