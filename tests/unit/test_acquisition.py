"""Target acquisition: the hand moves its image off a target it hides, then the servo resumes."""

from __future__ import annotations

import numpy as np
import pytest

from common.camera import CameraIntrinsics, project
from common.config import ControllerConfig
from common.marker import Marker
from services.controller import acquisition as acq
from services.controller.arm import ArmReading
from services.controller.ibvs import ACQUISITION_FAILED, IbvsController
from services.controller.twist import clamp_twist
from tests.unit.test_ibvs import moved, not_seen, observe, square_points

K = CameraIntrinsics.from_fov(640, 480, 57.0)
DT_S = 1 / 30


def test_directions_go_across_the_forearm_rising_side_first_downward_last() -> None:
    hand, elbow = np.array([300.0, 200.0]), np.array([400.0, 250.0])  # forearm to the right
    up = np.array([0.0, -1.0])  # the world's vertical points up in the image
    dirs = acq.uncover_directions(hand, elbow, up)
    back = np.array([2.0, 1.0]) / np.sqrt(5)
    across_rising = np.array([1.0, -2.0]) / np.sqrt(5)
    diagonals = [np.array([1.0, -1.0]) / np.sqrt(2), np.array([-1.0, -1.0]) / np.sqrt(2)]
    # across the other way goes mostly down (onto the table): left out; back, towards the
    # elbow, goes down a little (towards what the hand hides): last
    expected = [across_rising, up, -back, *diagonals, back]
    assert len(dirs) == len(expected)
    for d, e in zip(dirs, expected, strict=True):
        np.testing.assert_allclose(d, e, atol=1e-12)
    # The elbow straight above: away from it is straight down (left out), back is up (once).
    dirs = acq.uncover_directions(hand, np.array([300.0, 50.0]), up)
    assert all(d @ up >= -acq.DOWN_LIMIT for d in dirs) and len(dirs) == 5
    assert len(acq.uncover_directions(hand, None)) == 3  # no elbow, no up: up, left, right


def test_goal_slides_the_square_and_stays_inside_the_image() -> None:
    corners = np.array([[300.0, 200.0], [340.0, 200.0], [340.0, 240.0], [300.0, 240.0]])
    goal = acq.goal_corners(corners, np.array([1.0, 0.0]), 100.0, K)
    np.testing.assert_allclose(goal - corners, np.tile([100.0, 0.0], (4, 1)))
    # Towards the top border, 200 px away: only 200 px less the margin are allowed.
    up = acq.goal_corners(corners, np.array([0.0, -1.0]), 250.0, K)
    assert up is not None and np.isclose(up[:, 1].min(), acq.image_margin_px(K))
    # Less than MIN_SHARE of the clearance left: that direction is skipped.
    assert acq.goal_corners(corners, np.array([0.0, -1.0]), 700.0, K) is None


def test_a_goal_beside_the_border_keeps_the_room_the_other_axis_has() -> None:
    """Asked up and to the right with the right border near, the hand goes straight up:
    the border cuts the slide's rightward share only; a direction the border bends by more
    than 45° is skipped."""
    margin = acq.image_margin_px(K)
    right = K.width_px - 1 - margin
    corners = np.array([[560.0, 300.0], [600.0, 300.0], [600.0, 340.0], [560.0, 340.0]])
    up_right = np.array([0.38, -0.92])
    goal = acq.goal_corners(corners, up_right, 150.0, K)
    assert goal is not None
    np.testing.assert_allclose(goal[:, 0].max(), right)  # cut at the margin
    np.testing.assert_allclose(goal[:, 1] - corners[:, 1], -0.92 * 150.0)  # up in full
    # Mostly to the right: the border leaves the upward share alone, bent by over 45°.
    assert acq.goal_corners(corners, np.array([0.92, -0.38]), 150.0, K) is None


def test_the_law_slides_the_hand_image_to_its_goal_without_turning_it() -> None:
    """Kinematic loop, the hand's points moved by the commanded twist (eye-to-hand)."""
    points = square_points(np.array([0.02, 0.03, 0.5]))
    corners = project(points, K)
    goal = corners + np.array([-120.0, 40.0])
    for _ in range(200):
        obs = observe(points)
        twist = acq.acquisition_twist_cam(obs.corners_px, obs.depth_m, goal, K, gain=1.0)
        points = moved(points, twist, DT_S)
    np.testing.assert_allclose(project(points, K), goal, atol=0.5)
    assert np.ptp(points[:, 2]) < 1e-3  # still facing the camera as before


def seconds_to_reach(gain: float, cfg: ControllerConfig) -> float:
    """Kinematic loop: one attempt's slide of CLEARANCE_DIAGONALS diagonals, the twist
    clamped as the controller clamps it; sim s until every corner is within REACHED_PX."""
    points = square_points(np.array([0.0, 0.02, 0.45]))
    corners = project(points, K)
    goal = acq.goal_corners(corners, np.array([-1.0, 0.0]), 1.6 * acq.diagonal_px(corners), K)
    assert goal is not None
    for step in range(int(cfg.acquire_attempt_s / DT_S)):
        now = project(points, K)
        if np.all(np.linalg.norm(now - goal, axis=1) < acq.REACHED_PX):
            return step * DT_S
        twist = acq.acquisition_twist_cam(now, points[:, 2], goal, K, gain)
        points = moved(points, clamp_twist(twist, cfg.acquire_max_linear_m_s, 1.0), DT_S)
    return cfg.acquire_attempt_s


def test_an_attempt_slides_at_its_clamp_and_reaches_its_goal_in_time() -> None:
    """With the acquisition's own gain an attempt reaches its goal within its time, most of
    the way at the clamp's speed; at the servo's gain it creeps up to it and runs out of
    time first (the next attempt would start short of this one's goal)."""
    cfg = ControllerConfig()
    at_clamp_s = 1.6 * 0.06 * np.sqrt(2) / cfg.acquire_max_linear_m_s  # the slide, in metres
    assert seconds_to_reach(cfg.acquire_gain, cfg) < at_clamp_s + 0.5
    assert seconds_to_reach(cfg.gain, cfg) >= cfg.acquire_attempt_s


def test_a_hand_near_the_border_is_pulled_back_in_by_a_slide_never_a_turn() -> None:
    """A hand marker inside the image's margin band, its goal to the side: the twist has no
    turn (a turn would swing the outer corners further out), the square's image slides along
    its goal and away from the border at once."""
    margin = acq.image_margin_px(K)
    points = square_points(np.array([0.0, -0.157, 0.5]))  # its top edge near the image's top
    corners = project(points, K)
    assert 0 < corners[:, 1].min() < margin  # in the band
    push = acq.border_push(corners, K)
    assert np.all(push[:, 1] <= 0) and push[:, 1].min() < 0 and np.all(push[:, 0] == 0)
    goal = acq.goal_corners(corners, np.array([-1.0, 0.0]), 120.0, K)
    assert goal is not None
    twist = acq.acquisition_twist_cam(corners, points[:, 2], goal, K, gain=1.0)
    np.testing.assert_array_equal(twist[3:], 0.0)
    first = project(moved(points, twist, DT_S), K)
    assert np.all(first[:, 1] > corners[:, 1])  # down, away from the top border
    assert np.all(first[:, 0] < corners[:, 0])  # and towards its goal
    for _ in range(300):
        obs = observe(points)
        points = moved(
            points, acq.acquisition_twist_cam(obs.corners_px, obs.depth_m, goal, K, 1.0), DT_S
        )
    end = project(points, K)
    # Slid to its goal along the border, held further from it than it started (the goal,
    # moved sideways only, is itself in the band: the pull and the goal balance there).
    assert end[:, 0].mean() == pytest.approx(goal[:, 0].mean(), abs=0.5)
    assert end[:, 1].min() > corners[:, 1].min() + 5.0


def start_covering(config: ControllerConfig) -> tuple[IbvsController, Marker]:
    hand = observe(square_points(np.array([0.0, 0.05, 0.45])))
    return IbvsController(config, np.eye(4)), hand


def test_hold_then_acquire_then_servo_once_the_target_is_seen() -> None:
    cfg = ControllerConfig(acquire_after_s=0.5)
    ctrl, hand = start_covering(cfg)
    hidden = not_seen("partial", occluded=True)
    t = 0.0
    out = ctrl.step(hand, hidden, K, ArmReading(np.zeros(3)), t)
    assert not out.valid and out.phase == "holding" and out.hold_reason == "target partial"
    for _ in range(16):  # holds 0.5 s, then acquires
        t += DT_S
        out = ctrl.step(hand, hidden, K, ArmReading(np.zeros(3)), t)
    assert out.valid and out.phase == "acquiring", out
    assert out.hold_reason == "acquiring: target partial, attempt 1/4"
    assert out.status.startswith("acquiring: target partial")
    assert 0 < np.linalg.norm(out.twist_base_ee[:3]) <= cfg.acquire_max_linear_m_s + 1e-12
    target = observe(square_points(np.array([0.0, 0.07, 0.55])))
    out = ctrl.step(hand, target, K, ArmReading(np.zeros(3)), t + DT_S)  # uncovered: servo on it
    assert out.valid and out.phase == "servoing" and out.error_px_rms > 1.0
    assert ctrl.acquisition is None and ctrl.hold_since_s is None


def test_acquisition_is_bounded_and_then_holds_naming_the_failure() -> None:
    cfg = ControllerConfig(acquire_after_s=0.2, acquire_attempts=2, acquire_attempt_s=1.0)
    ctrl, hand = start_covering(cfg)  # the hand never moves: no attempt reaches its goal
    hidden = not_seen("lost", occluded=True)
    phases = []
    t = 0.0
    while t < 5.0:
        out = ctrl.step(hand, hidden, K, ArmReading(np.zeros(3)), t)
        phases.append(out.phase)
        t += DT_S
    assert "acquiring" in phases and phases[-1] == "holding"
    assert out.hold_reason.startswith(f"{ACQUISITION_FAILED}: target lost after 2 attempt(s)")
    acquiring_s = DT_S * phases.count("acquiring")
    assert acquiring_s == pytest.approx(2 * cfg.acquire_attempt_s, abs=2 * DT_S)
    assert not np.any(out.twist_base_ee) and out.hold_since_s is not None


def test_a_target_gone_with_nothing_in_front_is_not_acquired() -> None:
    ctrl, hand = start_covering(ControllerConfig(acquire_after_s=0.1))
    target = observe(square_points(np.array([0.1, 0.07, 0.55])))
    assert ctrl.step(hand, target, K, ArmReading(np.zeros(3)), 0.0).phase == "servoing"
    for i in range(1, 30):
        out = ctrl.step(hand, not_seen("lost"), K, ArmReading(np.zeros(3)), i * DT_S)
    assert out.phase == "holding" and out.hold_reason == "target lost"
    assert out.hold_since_s == DT_S


def test_a_target_never_seen_at_all_is_acquired() -> None:
    """The pre-launch check puts the target in the image: unseen from the start, something
    (the arm) is in front of it."""
    ctrl, hand = start_covering(ControllerConfig(acquire_after_s=0.1))
    for i in range(30):
        out = ctrl.step(hand, not_seen("lost"), K, ArmReading(np.zeros(3)), i * DT_S)
    assert out.phase == "acquiring" and out.hold_reason.startswith("acquiring: target lost")


def test_acquisition_can_be_switched_off() -> None:
    ctrl, hand = start_covering(ControllerConfig(acquire=False))
    for i in range(60):
        out = ctrl.step(
            hand, not_seen("partial", occluded=True), K, ArmReading(np.zeros(3)), i * DT_S
        )
    assert out.phase == "holding" and out.hold_since_s == 0.0
