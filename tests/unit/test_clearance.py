"""The hand box is kept above the object's top face: the barrier on its corners' heights."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from common import kinematics as kin
from common.config import ControllerConfig, load_scenario
from common.marker import Marker
from common.messages import MAX_ANGULAR_RAD_S, MAX_LINEAR_M_S, Header
from services.controller.arm import ArmReading
from services.controller.clearance import (
    Plane,
    clearance_bounds,
    hand_box_corners_ee,
    heights_m,
    lift_short,
    lift_then_nearest,
    plane_of_corners,
)
from services.controller.forearm import top_face
from services.controller.ibvs import ControlOutput, IbvsController
from services.controller.step import above_the_target, twist_message
from services.controller.twist import camera_points_to_base, twist_matrix_base_ee_to_cam

FLOOR = Plane(np.zeros(3), np.array([0.0, 1.0, 0.0]))  # y up, as the arm's base frame
# A hand box lying flat, its lowest face 10 mm above the floor; the end-effector origin above it.
BOX = np.array([[x, y, z] for x in (-0.04, 0.04) for y in (0.01, 0.035) for z in (-0.045, 0.045)])
EE = np.array([0.0, 0.05, 0.0])


def test_the_box_has_the_robot_models_size() -> None:
    corners = hand_box_corners_ee()
    assert corners.shape == (8, 3)
    np.testing.assert_allclose(
        np.ptp(corners, axis=0), [kin.HAND_THICKNESS_M, kin.HAND_LENGTH_M, kin.HAND_WIDTH_M]
    )


def keep_above(
    twist: np.ndarray, corners: np.ndarray, ee: np.ndarray, plane: Plane, h_min: float, rate: float
) -> tuple[np.ndarray, bool]:
    """The clearance's lift on its own: every corner's bound met by the least upward velocity."""
    return lift_short(twist, *clearance_bounds(corners, ee, plane, h_min, rate), plane.normal)


def test_a_fall_onto_the_face_slows_to_the_margins_rate_and_other_motion_is_kept() -> None:
    down = np.array([0.02, -0.5, 0.0, 0.0, 0.0, 0.0])
    twist, corrected = keep_above(down, BOX, EE, FLOOR, 0.002, 3.0)
    assert corrected
    assert twist[1] == pytest.approx(-3.0 * (0.01 - 0.002))  # the lowest corners' bound
    assert twist[0] == pytest.approx(0.02) and np.allclose(twist[3:], 0.0)
    sideways = np.array([0.1, 0.0, -0.05, 0.0, 0.0, 0.0])
    assert keep_above(sideways, BOX, EE, FLOOR, 0.002, 3.0) == (pytest.approx(sideways), False)


def test_a_turn_that_dips_an_edge_is_corrected_and_every_corner_meets_its_bound() -> None:
    tilt = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 2.0])  # about z: one x edge goes down
    twist, corrected = keep_above(tilt, BOX, EE, FLOOR, 0.002, 3.0)
    rates = twist[:3] + np.cross(twist[3:], BOX - EE)
    assert corrected
    assert np.all(rates @ FLOOR.normal >= -3.0 * (heights_m(BOX, FLOOR) - 0.002) - 1e-9)


def test_a_corner_below_the_margin_is_lifted() -> None:
    low = BOX - np.array([0.0, 0.009, 0.0])  # lowest face 1 mm up, under a 2 mm margin
    twist, corrected = keep_above(np.zeros(6), low, EE, FLOOR, 0.002, 3.0)
    assert corrected and twist[1] == pytest.approx(3.0 * 0.001)


def test_a_bound_rising_does_not_help_is_met_by_the_nearest_twist() -> None:
    """The hand box's corners and a bound that only a sideways motion meets (the forearm beside
    the object, its distance growing with x): lifting alone leaves it short; lifted, then
    moved to the nearest twist, every bound holds, and the sideways part is the least that
    meets it."""
    corners_rows, corners_bounds = clearance_bounds(BOX, EE, FLOOR, 0.002, 3.0)
    sideways = np.array([[1.0, 0.0, 0.0, 0.0, 0.0, 0.0]])
    rows = np.vstack([corners_rows, sideways])
    bounds = np.concatenate([corners_bounds, [0.05]])
    down = np.array([0.0, -0.5, 0.0, 0.0, 0.0, 0.0])
    lifted, _ = lift_short(down, rows, bounds, FLOOR.normal)
    assert float(sideways[0] @ lifted) < 0.05  # rising did not help it
    out, corrected = lift_then_nearest(down, rows, bounds, FLOOR.normal)
    assert corrected and np.all(rows @ out >= bounds - 1e-9)
    assert out[0] == pytest.approx(0.05)
    np.testing.assert_allclose(out[1:], lifted[1:], atol=1e-9)
    within = np.array([0.1, 0.2, 0.0, 0.0, 0.0, 0.0])
    assert lift_then_nearest(within, rows, bounds, FLOOR.normal) == (pytest.approx(within), False)


def test_after_the_nearest_twist_the_hand_box_s_corners_stay_met() -> None:
    """Random boxes, planes and a bound rising may hurt or help: every twist that broke a
    bound is flagged, and whatever the nearest twist's sweeps leave short, the hand box's
    corners (which rising always helps) end met; never a NaN."""
    rng = np.random.default_rng(2)
    for _ in range(3000):
        turn = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        ee = rng.normal(size=3) * 0.01
        corners = hand_box_corners_ee() @ turn.T + ee
        plane = Plane(np.array([0.0, 0.0, rng.uniform(-0.12, 0.02)]), np.array([0.0, 0.0, 1.0]))
        rows, bounds = clearance_bounds(corners, ee, plane, 0.002, 3.0)
        other = rng.normal(size=6) * np.array([1.0, 1.0, 1.0, 0.2, 0.2, 0.2])
        rows = np.vstack([rows, other])
        bounds = np.concatenate([bounds, [rng.uniform(-0.05, 0.05)]])
        twist = rng.normal(size=6) * np.array([0.1, 0.1, 0.1, 0.5, 0.5, 0.5])
        out, corrected = lift_then_nearest(twist, rows, bounds, plane.normal)
        assert np.all(np.isfinite(out))
        assert corrected == bool(np.any(rows @ twist < bounds))
        assert np.all(rows[:8] @ out >= bounds[:8] - 1e-9)


def test_the_top_face_plane_comes_from_the_marker_corners_and_faces_the_camera() -> None:
    t_base_cam = kin.homogeneous(np.eye(3), np.array([0.0, 0.5, 0.0]))
    square = np.array([[0.1, -0.2, 0.3], [0.2, -0.2, 0.3], [0.2, -0.2, 0.4], [0.1, -0.2, 0.4]])
    for corners in (square, square[::-1]):
        plane = plane_of_corners(camera_points_to_base(corners, t_base_cam), t_base_cam[:3, 3])
        np.testing.assert_allclose(plane.normal, [0.0, 1.0, 0.0], atol=1e-12)
        np.testing.assert_allclose(plane.point_m, [0.15, 0.3, 0.35])


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("merged", [(1, 0), (3, 0), (1, 3)], ids=["1=0", "3=0", "0,1,3 in a line"])
def test_the_plane_and_face_of_a_square_with_corners_merged_are_still_the_square_s(
    merged: tuple[int, int],
) -> None:
    """Corners the wire lets through (its check is that the diagonals cross) with corner 1 or 3
    on corner 0, or 0, 1 and 3 in a line: the plane's normal and the face's axes come from the
    diagonals, finite and the square's own, not 0/0 (a NaN twist the wire then refused)."""
    square = np.array([[0.1, -0.2, 0.3], [0.2, -0.2, 0.3], [0.2, -0.2, 0.4], [0.1, -0.2, 0.4]])
    bent = square.copy()
    i, j = merged
    bent[i] = square[j] if merged != (1, 3) else (square[0] + square[3]) / 2 - [0.0, 0.0, 0.2]
    plane = plane_of_corners(bent, np.array([0.0, 0.5, 0.0]))
    np.testing.assert_allclose(plane.normal, [0.0, 1.0, 0.0], atol=1e-12)
    face = top_face(plane, bent, 0.075)
    side = [1.0, 0.0, 0.0] if merged != (1, 3) else [0.0, 0.0, 1.0]  # along a side of it
    np.testing.assert_allclose(np.abs(face.u), side, atol=1e-12)


@pytest.mark.parametrize("offset_m", [1e-8, 1e-4, 1e-3])
def test_a_corner_nearly_on_another_leaves_the_face_s_axes_the_square_s(offset_m: float) -> None:
    """Corner 1 a hair off corner 0: the edge between them is noise, not a side, so the
    face's first axis comes from the diagonals, along the square's side to 1e-2 at worst."""
    square = np.array([[0.1, -0.2, 0.3], [0.2, -0.2, 0.3], [0.2, -0.2, 0.4], [0.1, -0.2, 0.4]])
    bent = square.copy()
    bent[1] = square[0] + [0.0, 0.0, offset_m]  # off towards corner 3, not corner 1
    plane = plane_of_corners(bent, np.array([0.0, 0.5, 0.0]))
    np.testing.assert_allclose(plane.normal, [0.0, 1.0, 0.0], atol=1e-12)
    face = top_face(plane, bent, 0.075)
    np.testing.assert_allclose(np.abs(face.u), [1.0, 0.0, 0.0], atol=1e-2)


def arm_at(t_ee: np.ndarray) -> ArmReading:
    """An encoders' reading with the end effector's pose alone (no joint angles: the forearm
    is not bounded)."""
    return ArmReading(t_ee[:3, 3], t_ee)


def above_a_square() -> tuple[IbvsController, np.ndarray, np.ndarray, np.ndarray]:
    """A controller that last saw a red square 3 mm under the hand box's lowest corner, the arm
    at the default start (camera at the base, so its frame is the base's): the controller, the
    end effector's pose, the box's corners and the square (base frame)."""
    q = np.array(load_scenario(None).robot.q0)
    t_ee = kin.frame_transforms(q)[-1]
    corners = hand_box_corners_ee() @ t_ee[:3, :3].T + t_ee[:3, 3]
    floor_y = corners[:, 1].min() - 0.003
    assert floor_y < 0.0  # below the camera, so the plane's normal (towards it) is up
    x, z = corners[:, 0].mean(), corners[:, 2].mean()
    square = np.array([[x - 0.03, floor_y, z - 0.03], [x + 0.03, floor_y, z - 0.03],
                       [x + 0.03, floor_y, z + 0.03], [x - 0.03, floor_y, z + 0.03]])  # fmt: skip
    controller = IbvsController(ControllerConfig(), np.eye(4))
    controller.target_memory.last = Marker.seen_at(square, load_scenario(None).camera.intrinsics())
    return controller, t_ee, corners, square


def test_the_controllers_twist_is_lifted_over_the_last_seen_target_and_flagged() -> None:
    """``above_the_target`` on a real arm posture: the red square 3 mm under the hand box's
    lowest corner (camera at the base, so its frame is the base's); a twist pressing down is
    lifted to the barrier's rate and flagged, a hold or the switch off leaves it as it was."""
    controller, t_ee, _, _ = above_a_square()
    down = ControlOutput(np.array([0.0, -0.1, 0.0, 0.0, 0.0, 0.0]), True, 5.0, False)
    out = above_the_target(controller, down, arm_at(t_ee))
    assert out.lifted and out.twist_base_ee[1] == pytest.approx(-3.0 * (0.003 - 0.002))
    header = Header(seq=0, sim_time_s=0.0, send_time_s=0.0, frame_seq=0)
    assert twist_message(out, header, "dynamic").lifted  # the run's end reads it
    assert not twist_message(down, header, "dynamic").lifted
    held = replace(down, valid=False)
    assert above_the_target(controller, held, arm_at(t_ee)) is held
    controller.config = ControllerConfig(keep_above_target=False)
    assert above_the_target(controller, down, arm_at(t_ee)) is down


def test_the_laws_twist_is_changed_where_its_features_notice_it_least() -> None:
    """With the law's model of the features' rate (``W = M⁺``, M its ``control_matrix``) the
    correction meets every corner's bound and changes the image motion less than the straight
    lift does."""
    controller, t_ee, corners, square = above_a_square()
    w_cam = np.random.default_rng(3).normal(size=(8, 6))
    down = ControlOutput(np.array([0.005, -0.05, 0.0, 0.1, 0.0, 0.05]), True, 5.0, False)
    lifted = above_the_target(controller, down, arm_at(t_ee))
    law = above_the_target(
        controller, replace(down, control_matrix=np.linalg.pinv(w_cam)), arm_at(t_ee)
    )
    assert law.lifted and lifted.lifted
    plane = plane_of_corners(square, np.zeros(3))
    rows, bounds = clearance_bounds(corners, t_ee[:3, 3], plane, 0.002, 3.0)
    assert np.all(rows @ law.twist_base_ee >= bounds - 1e-9)
    w_base = w_cam @ twist_matrix_base_ee_to_cam(np.eye(4), t_ee[:3, 3])
    change = np.linalg.norm(w_base @ (law.twist_base_ee - down.twist_base_ee))
    assert change < np.linalg.norm(w_base @ (lifted.twist_base_ee - down.twist_base_ee))


@pytest.mark.parametrize("law", [False, True], ids=["lift", "least_feature_change"])
def test_the_lifted_twist_never_exceeds_the_clamp_and_keeps_its_direction(law: bool) -> None:
    """The hand box 1 mm over the red square, inside its 2 mm margin, and the law's twist
    sliding sideways at the 1 cm/s clamp: the correction (the straight lift, or the law's
    least feature change) adds an upward motion that, with the widest clamp the wire allows,
    takes the twist over 1 cm/s; clamped again it is within both norms, at the linear one,
    along the same direction, so the hand still rises off the face. Without that second
    clamp the clearance would send the arm faster than the controller's limit."""
    controller, t_ee, _, square = above_a_square()
    k = load_scenario(None).camera.intrinsics()
    raised = square + np.array([0.0, 0.002, 0.0])  # from 3 mm under the box's lowest corner to 1
    controller.target_memory.last = Marker.seen_at(raised, k)
    m = np.linalg.pinv(np.random.default_rng(3).normal(size=(8, 6))) if law else None
    max_linear, max_angular = 0.01, 0.05
    sliding = ControlOutput(np.array([max_linear, 0.0, 0.0, 0.0, 0.0, 0.0]), True, 5.0, False)
    sliding = replace(sliding, control_matrix=m)

    def corrected(max_linear_m_s: float, max_angular_rad_s: float) -> ControlOutput:
        controller.config = ControllerConfig(
            max_linear_m_s=max_linear_m_s, max_angular_rad_s=max_angular_rad_s
        )
        return above_the_target(controller, sliding, arm_at(t_ee))

    wide = corrected(MAX_LINEAR_M_S, MAX_ANGULAR_RAD_S)
    small = corrected(max_linear, max_angular)
    assert wide.lifted and small.lifted
    lifted = wide.twist_base_ee
    assert lifted[1] > 0.0  # the correction raises the hand
    assert np.linalg.norm(lifted[:3]) > 1.02 * max_linear, "the lift must take it over the clamp"
    twist = small.twist_base_ee
    lin, ang = np.linalg.norm(twist[:3]), np.linalg.norm(twist[3:])
    print(
        f"lifted |v| {np.linalg.norm(lifted[:3]):.4f} m/s; clamped {lin:.4f} m/s, {ang:.4f} rad/s"
    )
    assert lin == pytest.approx(max_linear) and lin <= max_linear * (1 + 1e-12)
    assert ang <= max_angular * (1 + 1e-12)
    np.testing.assert_allclose(twist / np.linalg.norm(twist), lifted / np.linalg.norm(lifted))
    assert twist[1] > 0.0
