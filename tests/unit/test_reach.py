"""The corner pairings' goal postures (services/controller/reach.py), and the published campaign
starts where the least turn's goal lies beyond a joint limit: each is the start from
docs/campaign/starts.json run by the campaign's lockstep in-process pipeline, which the
distributed one equals frame for frame (integration/test_pipeline_vs_distributed.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from common import kinematics as kin
from common.camera import CameraIntrinsics, project
from common.marker import Marker
from deploy.launch.run_inprocess import run_scenario_inprocess
from services.controller.pairing import pairing_costs_px2, rolled
from services.controller.reach import (
    goal_poses_ee,
    goal_posture,
    goal_postures,
    rigid_motion,
)
from tests.unit.published_starts import start_scenario

ROOT = Path(__file__).resolve().parents[2]
K = CameraIntrinsics.from_fov(640, 480, 62.0)
SIZE_M = 0.06


def seen(points_cam_m: np.ndarray) -> Marker:
    return Marker.seen_at(points_cam_m, K, np.full(4, 1e-3))


def test_rigid_motion_recovers_a_turn_and_a_shift() -> None:
    rng = np.random.default_rng(3)
    source = rng.normal(size=(4, 3))
    motion = kin.homogeneous(kin.rot_z(0.7) @ kin.rot_x(-1.2), np.array([0.1, -0.3, 0.25]))
    destination = source @ motion[:3, :3].T + motion[:3, 3]
    found = rigid_motion(source, destination)
    assert np.allclose(found, motion, atol=1e-12)
    assert np.linalg.det(found[:3, :3]) == pytest.approx(1.0)


def camera_in_front_of(q_rad: np.ndarray) -> np.ndarray:
    """A camera pose 0.5 m in front of the hand marker at ``q_rad``, looking at it."""
    marker = kin.forward_kinematics(q_rad) @ kin.hand_marker_in_ee()
    z_cam = -marker[:3, 2]  # looking at the marker's face
    x_cam = marker[:3, 0]
    return kin.homogeneous(
        np.column_stack([x_cam, np.cross(z_cam, x_cam), z_cam]), marker[:3, 3] - 0.5 * z_cam
    )


def hand_corners_cam(q_rad: np.ndarray, t_base_cam: np.ndarray) -> np.ndarray:
    marker = kin.forward_kinematics(q_rad) @ kin.hand_marker_in_ee()
    corners = kin.marker_corners(marker, SIZE_M)
    return (np.linalg.inv(t_base_cam) @ np.column_stack([corners, np.ones(4)]).T).T[:, :3]


def test_the_goal_posture_of_the_pairing_that_fits_is_the_arm_s_own() -> None:
    """Hand and goal the same marker at two postures: the pairing that lays corner i on corner
    i is reached at the goal's posture; one that needs the hand turned a half turn more is not
    reached from there within the joint limits."""
    q_start = np.deg2rad([-20.0, 50.0, -70.0, -95.0, -120.0, -60.0])
    q_goal = q_start + np.deg2rad([-8.0, 5.0, 12.0, -10.0, 6.0, -5.0])
    t_base_cam = camera_in_front_of(q_start)
    hand = seen(hand_corners_cam(q_start, t_base_cam))
    goal = seen(hand_corners_cam(q_goal, t_base_cam))
    poses = goal_poses_ee(hand, goal, t_base_cam, kin.forward_kinematics(q_start))
    q, reached = goal_posture(poses[0], q_start)
    assert reached
    assert np.allclose(q, q_goal, atol=1e-4)
    # Corner i on corner i + 2: the hand turned by π about its normal, where no single joint
    # turns it (common/kinematics.py): the inverse kinematics from here stops at the limits.
    postures, reached_each = goal_postures(poses, q_start)
    assert reached_each[0] and not reached_each[2]
    assert np.allclose(postures[0], q_goal, atol=1e-4)


@pytest.mark.parametrize(
    "name",
    [
        "start_0123",  # the least turn's goal puts the forearm twist and wrist past their limits
        "start_0314",  # the least turn's goal puts the shoulder's roll and yaw past their limits
    ],
)
def test_a_goal_beyond_the_joint_limits_is_left_for_a_quarter_turn(name: str) -> None:
    reached = {}
    for choose in (True, False):
        extra = (f"controller.reachable_pairing={str(choose).lower()}", "controller.mode='dynamic'")
        reached[choose] = run_scenario_inprocess(start_scenario(name, *extra))
    assert reached[True].converged, reached[True].detail
    assert reached[True].final_position_error_m < 0.005
    assert not reached[False].converged  # the least turn: against the limit
    assert reached[False].reason != "converged"


def test_the_least_turn_is_kept_when_it_is_reachable() -> None:
    """On a start whose least turn the arm reaches, the controller pairs by the least turn."""
    from common.config import ControllerConfig
    from services.controller.arm import ArmReading
    from services.controller.ibvs import IbvsController

    q_start = np.deg2rad([-20.0, 50.0, -70.0, -95.0, -120.0, -60.0])
    q_goal = q_start + np.deg2rad([-5.0, 4.0, 6.0, -4.0, 3.0, -9.0])
    t_base_cam = camera_in_front_of(q_start)
    hand = seen(hand_corners_cam(q_start, t_base_cam))
    goal = seen(hand_corners_cam(q_goal, t_base_cam))
    ctrl = IbvsController(ControllerConfig(), t_base_cam)
    ctrl.step(hand, goal, K, ArmReading.from_joints(q_start), 0.0)
    least = int(np.argmin(pairing_costs_px2(project(hand.points_m, K), project(goal.points_m, K))))
    assert ctrl.reachable is not None and ctrl.reachable[least]
    assert ctrl.pairing == least


def test_the_pairings_are_checked_again_when_the_goal_moves_and_follow_a_relabelled_hand(
    monkeypatch,
) -> None:
    """Checked on the first frame servoed, not again while the goal stays put (a few
    millimetres of measurement wobble), again once it has moved by REACH_RECHECK_M; carried
    over to the corners' new labels once vision sees the hand again, or labels it afresh (a
    restarted vision); never when turned off."""
    from common.config import ControllerConfig
    from services.controller import ibvs
    from services.controller.arm import ArmReading

    calls = []

    def counted(*args: object) -> tuple[np.ndarray, list[bool]]:
        calls.append(args)
        return goal_postures(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(ibvs, "goal_postures", counted)
    q_start = np.deg2rad([-20.0, 50.0, -70.0, -95.0, -120.0, -60.0])
    t_base_cam = camera_in_front_of(q_start)
    hand = seen(hand_corners_cam(q_start, t_base_cam))
    goal = hand_corners_cam(q_start + np.deg2rad([-5.0, 4.0, 6.0, -4.0, 3.0, -9.0]), t_base_cam)
    ctrl = ibvs.IbvsController(ControllerConfig(), t_base_cam)
    arm = ArmReading.from_joints(q_start)
    for shift_m, checks in [(0.0, 1), (0.005, 1), (0.015, 1), (0.03, 2), (0.035, 2)]:
        ctrl.step(hand, seen(goal + np.array([shift_m, 0.0, 0.0])), K, arm, 0.0)
        assert len(calls) == checks, shift_m
    assert ctrl.reachable is not None and any(ctrl.reachable)
    # Vision loses the hand, then labels its corners afresh (corner i is the old corner i + 1):
    # the verdicts follow the physical pairings to their new indices, with no new check.
    before = list(ctrl.reachable)
    assert ctrl.reach_postures is not None
    postures_before = ctrl.reach_postures.copy()
    there = seen(goal + np.array([0.035, 0.0, 0.0]))
    ctrl.step(Marker.unseen("lost"), there, K, arm, 0.0)
    ctrl.step(rolled(hand, 1), there, K, arm, 0.0)
    assert len(calls) == 2
    assert ctrl.reachable == [before[(k - 1) % 4] for k in range(4)]
    assert ctrl.reachable != before  # one pairing reached: the shift shows
    # The goal postures follow them: the forearm's margin is capped at the pairing's own.
    assert np.array_equal(ctrl.reach_postures, postures_before[[(k - 1) % 4 for k in range(4)]])
    posture = ctrl.goal_posture_rad()
    assert posture is not None and np.array_equal(posture, ctrl.reach_postures[ctrl.pairing])
    # A restarted vision labels it afresh with no loss in between (corner i now the old
    # corner i + 2): the same, the pairing in use with them.
    pairing = ctrl.pairing
    assert pairing is not None
    ctrl.step(rolled(hand, 2), there, K, arm, 0.0)
    assert len(calls) == 2
    assert ctrl.reachable == [before[(k - 2) % 4] for k in range(4)]
    assert ctrl.pairing == (pairing + 1) % 4
    # Turned off: never checked, and the last check no longer narrows the choice.
    ctrl.config = ControllerConfig(reachable_pairing=False)
    assert ctrl.goal_posture_rad() is None  # nor does its posture shape the forearm's margin
    ctrl.reachable = [False, False, True, False]
    away = seen(goal + np.array([0.1, 0.0, 0.0]))
    ctrl.step(hand, away, K, arm, 0.0)
    assert len(calls) == 2
    assert ctrl.pairing == int(np.argmin(pairing_costs_px2(hand.corners_px, away.corners_px)))


def test_the_current_pairing_s_goal_posture_follows_a_moving_goal_and_none_beyond_reach() -> None:
    """Solved again from its last one once the goal has moved 2 mm (the forearm's funnel is
    centred on it), not for a millimetre's wobble; the same posture a check from scratch
    finds. A pairing whose posture is beyond the joint limits gives none."""
    from common.config import ControllerConfig
    from services.controller.arm import ArmReading
    from services.controller.ibvs import POSTURE_RESOLVE_M, IbvsController

    q_start = np.deg2rad([-20.0, 50.0, -70.0, -95.0, -120.0, -60.0])
    q_goal = q_start + np.deg2rad([-5.0, 4.0, 6.0, -4.0, 3.0, -9.0])
    t_base_cam = camera_in_front_of(q_start)
    hand = seen(hand_corners_cam(q_start, t_base_cam))
    goal = hand_corners_cam(q_goal, t_base_cam)
    ctrl = IbvsController(ControllerConfig(), t_base_cam)
    arm = ArmReading.from_joints(q_start)
    ctrl.step(hand, seen(goal), K, arm, 0.0)
    first = ctrl.goal_posture_rad()
    assert first is not None
    first = first.copy()
    ctrl.step(hand, seen(goal + np.array([0.5 * POSTURE_RESOLVE_M, 0.0, 0.0])), K, arm, 0.0)
    assert np.array_equal(ctrl.goal_posture_rad(), first)  # a wobble: not solved again
    moved = seen(goal + np.array([0.004, 0.0, 0.0]))
    ctrl.step(hand, moved, K, arm, 0.0)
    followed = ctrl.goal_posture_rad()
    assert followed is not None and not np.allclose(followed, first, atol=1e-6)
    fresh = IbvsController(ControllerConfig(), t_base_cam)
    fresh.step(hand, moved, K, arm, 0.0)
    assert fresh.pairing == ctrl.pairing
    np.testing.assert_allclose(followed, fresh.goal_posture_rad(), atol=1e-4)
    assert ctrl.reachable is not None and ctrl.pairing is not None
    ctrl.reachable[ctrl.pairing] = False
    assert ctrl.goal_posture_rad() is None


def test_a_relabelled_target_moves_the_verdicts_with_the_pairing_at_once() -> None:
    """Relabelled corners shift the pairings' indices: the pairing in use, its verdicts, goal
    postures and goal orientations move together, in the frame of the relabel (the reach
    check, which would carry them over too, waits while the hand is carried by the encoders,
    and meanwhile the stale verdicts steered the choice)."""
    from common.config import ControllerConfig
    from services.controller.ibvs import IbvsController

    q = np.deg2rad([-20.0, 50.0, -70.0, -95.0, -120.0, -60.0])
    t_base_cam = camera_in_front_of(q)
    hand = seen(hand_corners_cam(q, t_base_cam))
    target = seen(hand_corners_cam(q + np.deg2rad([-5.0, 4.0, 6.0, -4.0, 3.0, -9.0]), t_base_cam))
    ctrl = IbvsController(ControllerConfig(), t_base_cam)
    ctrl._follow_labels(hand, target)  # the first views: nothing to follow yet
    postures, rotations = np.arange(24.0).reshape(4, 6), np.arange(36.0).reshape(4, 3, 3)
    ctrl.pairing, ctrl.reachable = 0, [True, False, False, False]
    ctrl.reach_postures, ctrl.reach_rotations = postures.copy(), rotations.copy()
    ctrl._follow_labels(hand, rolled(target, 1))  # target corner i is its corner i + 1 then
    assert ctrl.pairing == 3 and ctrl.reachable == [False, False, False, True]
    assert np.array_equal(ctrl.reach_postures[3], postures[0])
    assert np.array_equal(ctrl.reach_rotations[3], rotations[0])
    ctrl._follow_labels(rolled(hand, 2), rolled(target, 1))  # and the hand's, by 2
    assert ctrl.pairing == 1 and ctrl.reachable == [False, True, False, False]
    assert np.array_equal(ctrl.reach_postures[1], postures[0])
