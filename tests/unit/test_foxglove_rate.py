"""The view's rate limit (deploy/foxglove/rate.py): on a schedule, so a source at the limit
passes whole and a faster one is held to it."""

from __future__ import annotations

import numpy as np

from deploy.foxglove.rate import RateGate


def admitted(times_s: np.ndarray, period_s: float) -> int:
    gate = RateGate(period_s)
    return sum(gate.admit(float(t)) for t in times_s)


def test_a_source_at_the_limit_passes_whole_despite_its_jitter() -> None:
    """15 Hz under a 15 Hz limit, arrivals jittered by up to a fifth of a period: a gap test
    (now − last < period: drop) let only part of it through."""
    rng = np.random.default_rng(4)
    period = 1.0 / 15.0
    times = np.arange(150) * period + rng.uniform(-0.2, 0.2, 150) * period
    assert admitted(times, period) == 150


def test_a_faster_source_is_held_to_the_limit() -> None:
    rng = np.random.default_rng(5)
    times = np.arange(300) / 30.0 + rng.uniform(-0.005, 0.005, 300)  # 30 Hz for 10 s
    assert 99 <= admitted(times, 0.1) <= 101  # 10 Hz


def test_no_burst_after_a_pause_beyond_two_messages() -> None:
    gate = RateGate(0.1)
    assert gate.admit(0.0)
    assert [gate.admit(5.0 + dt) for dt in (0.0, 0.001, 0.002, 0.003)] == [
        True,
        False,
        False,
        False,
    ]
