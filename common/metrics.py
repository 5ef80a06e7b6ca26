"""Counters a service reports in its status: message rates, ages, processing-time percentiles."""

from __future__ import annotations

import math
import threading
import time
from collections import deque

import numpy as np

from common.messages import TopicStats

RATE_WINDOW_S = 5.0


class TopicMeter:
    """Message count, rate over a sliding window, and age of the last message on one key."""

    def __init__(self, window_s: float = RATE_WINDOW_S) -> None:
        self.window_s = window_s
        self.count = 0
        self.dropped = 0
        # Camera frames only: by reference (a view of the publisher's shared-memory ring) or
        # whole, by copy; of the latter, fetched from the publisher (the ring was unreachable).
        self.by_ref = 0
        self.by_copy = 0
        self.fetched = 0
        self._times: deque[float] = deque()
        self._lock = threading.Lock()

    def tick(self, now_s: float | None = None) -> None:
        now = time.monotonic() if now_s is None else now_s
        with self._lock:
            self.count += 1
            self._times.append(now)
            while self._times and now - self._times[0] > self.window_s:
                self._times.popleft()

    def stats(self, now_s: float | None = None) -> TopicStats:
        now = time.monotonic() if now_s is None else now_s
        with self._lock:
            times = [t for t in self._times if now - t <= self.window_s]
            last = self._times[-1] if self._times else None
        rate = (len(times) - 1) / (times[-1] - times[0]) if len(times) >= 2 else 0.0
        if times and rate > 0:
            # A stream that stopped must not keep showing its old rate.
            rate = min(rate, len(times) / max(now - times[0], 1e-9))
        return TopicStats(
            count=self.count,
            rate_hz=rate if times else 0.0,
            age_s=None if last is None else now - last,
            dropped=self.dropped,
            by_ref=self.by_ref,
            by_copy=self.by_copy,
            fetched=self.fetched,
        )


def percentile(values: np.ndarray, q: float) -> float:
    """``np.percentile(values, q)`` (its default linear interpolation, same result to the bit)
    by partial sorting. np.percentile goes through np.unique, whose first call imports
    numpy.ma: a long pause once, in the middle of whichever frame needs it first."""
    if not 0.0 <= q <= 100.0 or len(values) == 0:
        raise ValueError(f"percentile {q} of {len(values)} values")
    position = q / 100.0 * (len(values) - 1)
    below = math.floor(position)
    above = min(below + 1, len(values) - 1)
    part = np.partition(values, [below, above])
    a, b, t = float(part[below]), float(part[above]), position - below
    # numpy's lerp: from the nearer end, so that t = 0 and t = 1 give a and b exactly
    return b - (b - a) * (1.0 - t) if t >= 0.5 else a + (b - a) * t


class DurationMeter:
    """The last ``size`` processing times (ms), as p50 / p99."""

    def __init__(self, size: int = 1000) -> None:
        self._values: deque[float] = deque(maxlen=size)

    def add(self, ms: float) -> None:
        self._values.append(ms)

    def percentiles(self) -> tuple[float | None, float | None]:
        if not self._values:
            return None, None
        values = np.fromiter(self._values, float)
        return percentile(values, 50.0), percentile(values, 99.0)
