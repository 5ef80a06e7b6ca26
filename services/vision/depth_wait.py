"""When a colour frame is measured: at once, or once the depth image it names has come.

A colour frame names the depth image taken with it (``depth_frame_seq``). The sim publishes
that image first, but in realtime one can come late or not at all, so a frame whose depth image
has not arrived waits for it, at most ``wait_s`` (wall clock) counted from the first frame that
waited: a newer colour frame replaces the waiting one (the older is dropped) without starting
the wait again, so a depth stream that stops cannot hold vision back for ever behind 30 Hz of
colour frames. Once a wait has run out, the depth stream is *overdue*: later frames are measured
at once with the newest depth image there is, until a depth image arrives again.

Pure: the caller gives the clock and measures what is handed back.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Generic, TypeVar

F = TypeVar("F")  # a colour frame


@dataclass
class DepthWait(Generic[F]):
    """The colour frame waiting for its depth image, if any, and whether depth is overdue."""

    wait_s: float
    waiting: F | None = None
    waiting_depth_seq: int = -1  # the depth image it waits for
    since_s: float = 0.0  # when the first frame of this wait began waiting
    overdue: bool = False  # a wait ran out and no depth image has come since
    waits: int = 0  # waits begun (a replaced frame continues its predecessor's)
    missed: int = 0  # frames measured without the depth image they named
    replaced: int = 0  # waiting frames replaced by a newer one (dropped)

    def forget(self) -> None:
        """A new run of the sim: nothing waits and depth is not overdue (the counts stay)."""
        self.waiting, self.overdue = None, False

    def colour(self, frame: F, depth_seq: int, newest_depth_seq: int, now_s: float) -> F | None:
        """A colour frame naming depth image ``depth_seq``: the frame to measure now, or None
        (it waits)."""
        if depth_seq <= newest_depth_seq:
            return frame
        if self.overdue:
            self.missed += 1
            return frame
        if self.waiting is None:
            self.waits += 1
            self.since_s = now_s
        else:
            self.replaced += 1
        self.waiting, self.waiting_depth_seq = frame, depth_seq
        return None

    def depth(self, depth_seq: int) -> F | None:
        """A depth image arrived: depth is no longer overdue; the waiting frame to measure now,
        if this is the image it waits for (or a newer one)."""
        self.overdue = False
        if self.waiting is not None and depth_seq >= self.waiting_depth_seq:
            frame, self.waiting = self.waiting, None
            return frame
        return None

    def idle(self, now_s: float) -> F | None:
        """The waiting frame to measure now without its depth image, once the wait has run out."""
        if self.waiting is None or now_s - self.since_s <= self.wait_s:
            return None
        frame, self.waiting = self.waiting, None
        self.overdue = True
        self.missed += 1
        return frame
