"""Pair two streams by camera frame: a message waits (bounded) for its partner's frame_seq."""

from __future__ import annotations

from collections import OrderedDict
from typing import Generic, TypeVar

A = TypeVar("A")
B = TypeVar("B")


class FramePairer(Generic[A, B]):
    """Keeps the last ``capacity`` messages of each stream by frame_seq and returns a pair as
    soon as both sides of one frame are present. Older frames are forgotten, never paired late,
    and a frame is paired once only: a re-published frame (lockstep resend) is ignored, so
    stateful consumers stay deterministic.
    """

    def __init__(self, capacity: int = 8) -> None:
        self.capacity = capacity
        self._a: OrderedDict[int, A] = OrderedDict()
        self._b: OrderedDict[int, B] = OrderedDict()
        self.last_paired = -2  # frame_seq -1 means "no frame"; pair those too

    def _stale(self, seq: int) -> bool:
        if seq < self.last_paired - self.capacity:  # far behind: the source restarted
            self.last_paired = -2
            self._a.clear()
            self._b.clear()
            return False
        return 0 <= seq <= self.last_paired

    def _paired(self, seq: int, a: A, b: B) -> tuple[A, B]:
        self.last_paired = seq
        return a, b

    def _push(self, store: OrderedDict, seq: int, item: object) -> None:
        store[seq] = item
        while len(store) > self.capacity:
            store.popitem(last=False)

    def add(self, first: bool, seq: int, item: A | B) -> tuple[A, B] | None:
        """``add_a`` when ``first`` else ``add_b``."""
        return self.add_a(seq, item) if first else self.add_b(seq, item)  # type: ignore[arg-type]

    def add_a(self, seq: int, item: A) -> tuple[A, B] | None:
        if self._stale(seq):
            return None
        if seq in self._b:
            return self._paired(seq, item, self._b.pop(seq))
        self._push(self._a, seq, item)
        return None

    def add_b(self, seq: int, item: B) -> tuple[A, B] | None:
        if self._stale(seq):
            return None
        if seq in self._a:
            return self._paired(seq, self._a.pop(seq), item)
        self._push(self._b, seq, item)
        return None
