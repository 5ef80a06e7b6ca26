"""The view's rate limit per key, as data: messages admitted on a schedule, not by the gap to
the last one.

A gap test (``now − last < period``: drop) drops a good part of a source that comes at the
limit itself, its arrivals jittering around the period. The schedule admits a message once its
due time has come and moves the due time on by one period, from where it was (or from half a
period before now, after a pause): a source at the limit passes whole, a faster one is held to
the limit on average, and no burst exceeds two messages.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass
class RateGate:
    period_s: float
    next_s: float = -math.inf  # when the next message may pass (monotonic s)

    def admit(self, now_s: float) -> bool:
        """Whether a message arriving at ``now_s`` passes; if it does, the next one's due."""
        if now_s < self.next_s:
            return False
        self.next_s = max(self.next_s, now_s - self.period_s / 2.0) + self.period_s
        return True
