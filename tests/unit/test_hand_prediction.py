"""A hand marker vision cannot use, carried from its last view along the encoders' motion."""

from __future__ import annotations

import numpy as np
import pytest

from common import kinematics as kin
from common.config import ControllerConfig, load_scenario
from common.marker import Marker
from services.controller.arm import ArmReading
from services.controller.hand import carried_by_encoders
from services.controller.ibvs import IbvsController

SCENARIO = load_scenario(None)
K = SCENARIO.camera.intrinsics()
T_BASE_CAM = SCENARIO.camera.assumed_pose()
# The hand marker on the end effector (its pose in DH frame 6): any rigid mount will do.
MOUNT = kin.homogeneous(np.eye(3), np.array([0.0, 0.06, 0.02]))


def seen_hand(q_rad: np.ndarray) -> tuple[Marker, np.ndarray]:
    """The hand marker as the camera at the assumed pose sees it, and the end effector's pose."""
    t_base_ee = kin.frame_transforms(q_rad)[-1]
    corners_base = kin.marker_corners(t_base_ee @ MOUNT, 0.05)
    corners_cam = (corners_base - T_BASE_CAM[:3, 3]) @ T_BASE_CAM[:3, :3]
    return Marker.seen_at(corners_cam, K), t_base_ee


def test_the_last_view_moves_with_the_end_effector() -> None:
    q0 = np.array(SCENARIO.robot.q0)
    before, t_then = seen_hand(q0)
    after, t_now = seen_hand(q0 + np.array([0.05, -0.04, 0.03, 0.1, -0.08, 0.06]))
    carried = carried_by_encoders(before, t_then, t_now, T_BASE_CAM, K)
    assert carried is not None
    np.testing.assert_allclose(carried.points_m, after.points_m, atol=1e-12)
    np.testing.assert_allclose(carried.corners_px, after.corners_px, atol=1e-9)
    np.testing.assert_allclose(carried.depth_m, after.points_m[:, 2], atol=1e-12)


def test_a_hand_carried_out_of_the_image_is_not_predicted() -> None:
    q0 = np.array(SCENARIO.robot.q0)
    before, t_then = seen_hand(q0)
    far = t_then.copy()
    far[:3, 3] += T_BASE_CAM[:3, :3] @ np.array([2.0, 0.0, 0.0])  # 2 m to the camera's right
    assert carried_by_encoders(before, t_then, far, T_BASE_CAM, K) is None


def controller(predict_hand_s: float = 2.0) -> IbvsController:
    config = ControllerConfig(mode="dynamic", predict_hand_s=predict_hand_s)
    return IbvsController(config, T_BASE_CAM)


def target_marker() -> Marker:
    target, _ = seen_hand(np.array(SCENARIO.robot.q0) + np.array([0.1, 0.1, 0.0, 0.0, 0.0, 0.0]))
    return target


@pytest.mark.parametrize("predict_hand_s", [1.01, 0.0])
def test_the_law_servoes_on_the_carried_hand_for_a_bounded_time(predict_hand_s: float) -> None:
    """Seen, then hidden: the twist goes on (flagged, never converged) for predict_hand_s of
    sim time, then the controller holds and says why; with 0 it holds at once."""
    ctl = controller(predict_hand_s)
    q = np.array(SCENARIO.robot.q0)
    hand, t_ee = seen_hand(q)
    out = ctl.step(hand, target_marker(), K, ArmReading(t_ee[:3, 3], t_base_ee=t_ee), 0.0)
    assert out.valid and not out.hand_predicted
    hidden = Marker.unseen("partial", "occluded", occluded=True)
    for i, t_s in enumerate(np.arange(1, 90) / 30):
        q_now = q + 0.001 * i
        t_now = kin.frame_transforms(q_now)[-1]
        out = ctl.step(hidden, target_marker(), K, ArmReading(t_now[:3, 3], t_base_ee=t_now), t_s)
        if predict_hand_s > 0 and t_s - 1 / 30 <= predict_hand_s:  # from the first hidden frame
            assert out.valid and out.hand_predicted and not out.converged
            assert np.linalg.norm(out.twist_base_ee) > 0.0
        else:
            assert not out.valid and out.hold_reason == "hand partial"
    # Seen again: the prediction ends and may start afresh later.
    out = ctl.step(hand, target_marker(), K, ArmReading(t_ee[:3, 3], t_base_ee=t_ee), 3.0)
    assert out.valid and not out.hand_predicted and ctl.hand_memory.carried_since_s is None


def test_without_the_end_effectors_pose_a_hidden_hand_is_held_on() -> None:
    ctl = controller()
    hand, t_ee = seen_hand(np.array(SCENARIO.robot.q0))
    ctl.step(hand, target_marker(), K, ArmReading(t_ee[:3, 3], t_base_ee=t_ee), 0.0)
    out = ctl.step(Marker.unseen("partial"), target_marker(), K, ArmReading(t_ee[:3, 3]), 0.1)
    assert not out.valid and out.hold_reason == "hand partial"
