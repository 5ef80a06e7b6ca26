"""The target's last view and motion (services/controller/goal.py, TargetMemory): kept while
seen, carried along its motion where the hand hides it, and said to be seen again."""

from __future__ import annotations

import numpy as np

from common.marker import Marker
from services.controller.goal import TargetMemory
from tests.unit.test_ibvs import K, observe, square_points


def square(centre: tuple[float, float, float]) -> np.ndarray:
    return square_points(np.array(centre))


def test_a_hidden_target_moving_is_carried_and_when_seen_again_said_so() -> None:
    memory = TargetMemory()
    hand_near = observe(square((0.0, 0.0, 0.48)))
    hidden = Marker.unseen("lost", occluded=True)
    for i in range(10):  # sliding along x at 2 cm/s, seen at 30 Hz
        t = i / 30
        target, remembered, again = memory.now(
            observe(square((0.02 * t, 0.0, 0.5))), hand_near, K, t
        )
        assert not remembered and not again and memory.last is target
    t = 1.0
    target, remembered, again = memory.now(hidden, hand_near, K, t)
    assert remembered and not again and memory.predicted
    # carried along its velocity since the last view (at 9/30 s)
    expected_x = 0.02 * (9 / 30) + 0.02 * (t - 9 / 30)
    assert np.allclose(target.points_m.mean(axis=0), [expected_x, 0.0, 0.5], atol=1e-4)
    back = observe(square((0.02 * 1.1, 0.0, 0.5)))
    target, remembered, again = memory.now(back, hand_near, K, 1.1)
    assert target is back and not remembered and again and not memory.predicted
    assert not memory.now(back, hand_near, K, 1.15)[2]  # said once


def test_a_target_gone_without_the_hand_in_front_is_not_remembered() -> None:
    memory = TargetMemory()
    memory.now(observe(square((0.0, 0.0, 0.5))), observe(square((0.2, 0.1, 0.45))), K, 0.0)
    hand_far = observe(square((0.2, 0.1, 0.45)))
    lost = Marker.unseen("lost", occluded=True)
    target, remembered, _ = memory.now(lost, hand_far, K, 0.1)
    assert target is lost and not remembered  # the hand is not what hides it
    gone = Marker.unseen("lost")  # nothing in front of it: gone, not hidden
    target, remembered, _ = memory.now(gone, observe(square((0.0, 0.0, 0.48))), K, 0.2)
    assert target is gone and not remembered and not memory.predicted


def test_a_target_vision_cannot_tell_about_is_remembered_where_the_hand_is() -> None:
    """A restarted vision reports the target lost with ``occluded`` None (no view of it to
    look in front of): where the hand is over its last view it is remembered, as a hidden one
    would be; away from the hand it is not."""
    memory = TargetMemory()
    seen = observe(square((0.0, 0.0, 0.5)))
    memory.now(seen, observe(square((0.2, 0.1, 0.45))), K, 0.0)
    unknown = Marker.unseen("lost", occluded=None)
    target, remembered, _ = memory.now(unknown, observe(square((0.0, 0.0, 0.48))), K, 0.1)
    assert remembered and np.array_equal(target.corners_px, seen.corners_px)
    target, remembered, _ = memory.now(unknown, observe(square((0.2, 0.1, 0.45))), K, 0.2)
    assert target is unknown and not remembered
