"""Pair two streams by camera frame: a message waits (bounded) for its partner's frame_seq."""

from __future__ import annotations

from collections import OrderedDict
from typing import Generic, TypeVar

A = TypeVar("A")
B = TypeVar("B")


class FramePairer(Generic[A, B]):
    """Keeps the last ``capacity`` messages of each stream by frame_seq and returns a pair as
    soon as both sides of one frame are present. Older frames are forgotten, never paired late.
    """

    def __init__(self, capacity: int = 8) -> None:
        self.capacity = capacity
        self._a: OrderedDict[int, A] = OrderedDict()
        self._b: OrderedDict[int, B] = OrderedDict()

    def _push(self, store: OrderedDict, seq: int, item: object) -> None:
        store[seq] = item
        while len(store) > self.capacity:
            store.popitem(last=False)

    def add_a(self, seq: int, item: A) -> tuple[A, B] | None:
        if seq in self._b:
            return item, self._b.pop(seq)
        self._push(self._a, seq, item)
        return None

    def add_b(self, seq: int, item: B) -> tuple[A, B] | None:
        if seq in self._a:
            return self._a.pop(seq), item
        self._push(self._b, seq, item)
        return None
