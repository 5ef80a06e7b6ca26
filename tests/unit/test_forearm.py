"""The forearm kept off the object (services/controller/forearm.py): the distance to the object,
the forearm's nearest point, its Jacobian and the bound on the twist; and published campaign
starts whose forearm pressed on the object on the way, run by the campaign's lockstep
in-process pipeline with the setting on and off."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from common import kinematics as kin
from common.config import ControllerConfig, load_scenario
from common.marker import Marker
from common.runtime import parse_overrides
from deploy.launch.run_inprocess import run_scenario_inprocess
from services.controller.arm import ArmReading
from services.controller.clearance import Plane, plane_of_corners
from services.controller.forearm import (
    ELBOW_FRAME,
    FUNNEL_RADIUS_M,
    GOAL_SLACK_M,
    NEAR_M,
    WRIST_FRAME,
    TopFace,
    distance_to_object,
    forearm_bounds,
    forearm_distance_m,
    funnel_radius_m,
    margin_near_goal,
    nearest_along,
    point_jacobians,
    top_face,
)
from services.controller.ibvs import ControlOutput, IbvsController
from services.controller.step import above_the_target, object_bounds
from tests.unit.published_starts import start_scenario

ROOT = Path(__file__).resolve().parents[2]
UP = np.array([0.0, 1.0, 0.0])
# A 75 mm face 0.3 m ahead of the shoulder, level, its sides along x and z.
FACE = TopFace(np.array([0.3, -0.3, 0.1]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, -1.0]),
               UP, 0.0375)  # fmt: skip


def test_the_distance_is_to_the_face_above_it_to_a_side_beside_it_and_to_an_edge_between() -> None:
    above = FACE.centre_m + np.array([0.01, 0.05, 0.0])
    assert distance_to_object(above, FACE)[0] == pytest.approx(0.05)
    np.testing.assert_allclose(distance_to_object(above, FACE)[1], UP)
    beside = FACE.centre_m + np.array([0.0475, -0.2, 0.0])  # below the face, 1 cm off its side
    dist, g = distance_to_object(beside, FACE)
    assert dist == pytest.approx(0.01)
    np.testing.assert_allclose(g, [1.0, 0.0, 0.0], atol=1e-12)
    edge = FACE.centre_m + np.array([0.0375 + 0.003, 0.004, 0.0])  # 3 mm out, 4 mm up
    dist, g = distance_to_object(edge, FACE)
    assert dist == pytest.approx(0.005)
    np.testing.assert_allclose(g, [0.6, 0.8, 0.0], atol=1e-12)
    inside = FACE.centre_m - np.array([0.0, 0.01, 0.0])
    assert distance_to_object(inside, FACE)[0] == 0.0


def test_the_face_lies_on_the_marker_s_plane_along_its_sides() -> None:
    corners = FACE.centre_m + np.array([[-1, 0, 1], [1, 0, 1], [1, 0, -1], [-1, 0, -1]]) * 0.03
    face = top_face(Plane(FACE.centre_m, UP), corners, 0.075)
    np.testing.assert_allclose(face.u, [1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(face.w, [0.0, 0.0, -1.0], atol=1e-12)
    assert face.half_side_m == pytest.approx(0.0375)


def test_the_nearest_point_of_a_segment_is_found_as_a_dense_search_finds_it() -> None:
    """Within a 20th of a millimetre, and given up on a segment seen to lie farther."""
    rng = np.random.default_rng(7)
    for _ in range(50):
        a, b = FACE.centre_m + rng.uniform(-0.15, 0.15, size=(2, 3))
        t, near = nearest_along(a, b, FACE)
        dense = min(distance_to_object(a + s * (b - a), FACE)[0] for s in np.linspace(0, 1, 4001))
        assert near == pytest.approx(distance_to_object(a + t * (b - a), FACE)[0], abs=1e-15)
        assert near <= dense + 1e-5  # within a 20th of a millimetre of the least
        if dense > 0.05:
            assert nearest_along(a, b, FACE, beyond_m=dense - 0.01)[1] == np.inf


def forearm_point(q: np.ndarray, t: float) -> np.ndarray:
    frames = kin.frame_transforms(q)
    elbow, wrist = frames[ELBOW_FRAME][:3, 3], frames[WRIST_FRAME][:3, 3]
    return elbow + t * (wrist - elbow)


def test_a_forearm_point_s_jacobian_is_its_motion_under_each_joint() -> None:
    q = np.array(load_scenario(None).robot.q0)
    shares = (0.0, 0.7, 1.0)
    points = np.array([forearm_point(q, t) for t in shares])
    jps = point_jacobians(kin.frame_transforms(q), points)
    for jp, t in zip(jps, shares, strict=True):
        for k in range(kin.N_JOINTS):
            dq = np.zeros(kin.N_JOINTS)
            dq[k] = 1e-7
            moved = (forearm_point(q + dq, t) - forearm_point(q - dq, t)) / 2e-7
            np.testing.assert_allclose(jp[:, k], moved, atol=1e-6)


@pytest.mark.parametrize(
    "face_from_wrist_m",
    [
        (0.0, -0.05, 0.0),  # the face 5 cm under the wrist: its nearest point is on the face
        (0.05, 0.03, 0.0),  # the wrist 2 cm off a side, 3 cm below the face: on the side
        (0.04, -0.01, 0.0),  # the wrist 1 cm off a side, 1 cm above the face: on the edge
    ],
)
def test_the_bound_is_the_nearest_point_s_rate_under_the_twist_and_none_far_off(
    face_from_wrist_m: tuple[float, float, float],
) -> None:
    """Near the object: ``rows · V`` is the rate of the forearm's distance to it when the joints
    turn as actuation makes them (``q̇ = J⁺ V``), and ``b = −rate · (d − d_min)``; whether the
    nearest point of the object is on its top face, on a side or on an edge between them."""
    q = np.array(load_scenario(None).robot.q0)
    frames = kin.frame_transforms(q)
    elbow, wrist = frames[ELBOW_FRAME][:3, 3], frames[WRIST_FRAME][:3, 3]
    centre = wrist + np.array(face_from_wrist_m)
    face = TopFace(centre, np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, -1.0]), UP, 0.03)

    def nearest_distance(q_rad: np.ndarray) -> float:
        fr = kin.frame_transforms(q_rad)
        a, b = fr[ELBOW_FRAME][:3, 3], fr[WRIST_FRAME][:3, 3]
        return nearest_along(a, b, face)[1]

    d = nearest_distance(q)
    rows, bounds = forearm_bounds(kin.frame_transforms(q), face, 0.024, 3.0)
    assert rows.shape == (1, 6) and bounds == pytest.approx([-3.0 * (d - 0.024)])
    twist = np.array([0.02, -0.05, 0.01, 0.2, -0.1, 0.3])
    qdot = np.linalg.pinv(kin.geometric_jacobian(q)) @ twist
    rate = (nearest_distance(q + 1e-6 * qdot) - nearest_distance(q - 1e-6 * qdot)) / 2e-6
    assert float(rows[0] @ twist) == pytest.approx(rate, rel=1e-4)
    far = TopFace(elbow + np.array([0.0, -(0.024 + NEAR_M + 0.3), 0.0]), face.u, face.w, UP, 0.03)
    rows, bounds = forearm_bounds(kin.frame_transforms(q), far, 0.024, 3.0)
    assert rows.shape == (0, 6) and bounds.shape == (0,)


@pytest.mark.parametrize("name", ["start_0048", "start_0209"])  # forearm on the block's top edge
def test_a_forearm_that_pressed_on_the_object_on_the_way_now_keeps_off_it(name: str) -> None:
    runs = {}
    for keep in (True, False):
        extra = (f"controller.keep_forearm_off_object={str(keep).lower()}", "controller.mode='pmj'")
        runs[keep] = run_scenario_inprocess(start_scenario(name, *extra))
    assert runs[True].converged and runs[True].final_position_error_m < 0.005, runs[True].detail
    assert runs[True].first_contact_s is None
    assert runs[False].first_contact_s is not None and runs[False].contact_with == "object"


def test_the_controller_keeps_the_forearm_off_the_object_it_last_saw() -> None:
    """Through the controller's step: a twist that would carry the forearm onto the object is
    corrected to meet the forearm's bound, and flagged; with the setting off it is not."""
    q = np.array(load_scenario(None).robot.q0)
    arm = ArmReading.from_joints(q)
    wrist = arm.frames[WRIST_FRAME][:3, 3]
    # A 75 mm object whose top edge is 1 cm out from the wrist and 2.6 cm under it, level; its
    # red square (60 mm) centred on it; the camera at the base, so its frame is the base's.
    centre = wrist + np.array([0.0375 + 0.01, -0.026, 0.0])
    square = centre + np.array([[-1, 0, 1], [1, 0, 1], [1, 0, -1], [-1, 0, -1]]) * 0.03
    controller = IbvsController(ControllerConfig(keep_above_target=False), np.eye(4))
    controller.object_side_m = 0.075
    controller.target_memory.last = Marker.seen_at(square, load_scenario(None).camera.intrinsics())
    face = top_face(plane_of_corners(square, np.zeros(3)), square, 0.075)
    d_min = kin.LIMB_RADIUS_M + controller.config.forearm_clearance_m
    towards = -distance_to_object(wrist, face)[1]  # the wrist straight at the object
    down = ControlOutput(np.concatenate([0.1 * towards, np.zeros(3)]), True, 5.0, False)
    rows, bounds = object_bounds(controller, arm, plane_of_corners(square, np.zeros(3)), square)
    assert rows.shape == (1, 6) and float(rows[0] @ down.twist_base_ee) < bounds[0]
    out = above_the_target(controller, down, arm)
    assert out.lifted and float(rows[0] @ out.twist_base_ee) >= bounds[0] - 1e-9
    assert distance_to_object(wrist, face)[0] < d_min + 0.03  # near: the bound is on
    controller.config = controller.config.model_copy(update={"keep_forearm_off_object": False})
    assert above_the_target(controller, down, arm) is down


def test_a_twist_not_the_law_s_is_kept_off_the_object_where_rising_does_not_help() -> None:
    """The wrist level with the object's top face, 1 cm beside it (inside the margin): rising
    moves it along the object's side and gains nothing, so a twist the law did not make (an
    acquisition's, ``control_matrix`` None) is moved to the nearest one that meets the bound."""
    q = np.array(load_scenario(None).robot.q0)
    arm = ArmReading.from_joints(q)
    wrist = arm.frames[WRIST_FRAME][:3, 3]
    centre = wrist + np.array([0.0375 + 0.01, 0.0, 0.0])
    square = centre + np.array([[-1, 0, 1], [1, 0, 1], [1, 0, -1], [-1, 0, -1]]) * 0.03
    controller = IbvsController(ControllerConfig(keep_above_target=False), np.eye(4))
    controller.object_side_m = 0.075
    controller.target_memory.last = Marker.seen_at(square, load_scenario(None).camera.intrinsics())
    plane = plane_of_corners(square, np.zeros(3))
    rows, bounds = object_bounds(controller, arm, plane, square)
    assert rows.shape == (1, 6) and bounds[0] > 0.0  # inside the margin: it must move out
    assert float(rows[0, :3] @ plane.normal) == pytest.approx(0.0, abs=1e-9)
    still = ControlOutput(np.zeros(6), True, 5.0, False)
    out = above_the_target(controller, still, arm)
    assert out.lifted and float(rows[0] @ out.twist_base_ee) >= bounds[0] - 1e-9


@pytest.mark.parametrize("gap_m", [0.0005, 0.001, 0.0027, 0.02])
def test_the_bound_never_holds_the_arm_off_its_own_goal(gap_m: float) -> None:
    """The object beside the wrist, ``gap_m`` from the forearm's surface: at the goal posture
    the capped bound still lets the forearm come nearer (``b < 0``), by the slack at least,
    where the uncapped one (the goal within the 2 mm margin) pushes it away; a goal outside
    the margin leaves the bound as it was."""
    q = np.array(load_scenario(None).robot.q0)
    frames = kin.frame_transforms(q)
    elbow, wrist = frames[ELBOW_FRAME][:3, 3], frames[WRIST_FRAME][:3, 3]
    side = np.cross(wrist - elbow, UP)
    side /= np.linalg.norm(side)  # level, square to the forearm: the wrist end is nearest
    u = np.cross(UP, side)
    half = 0.03
    centre = wrist + (half + kin.LIMB_RADIUS_M + gap_m) * side + np.array([0.0, 0.02, 0.0])
    face = TopFace(centre, side, u, UP, half)
    d_goal = forearm_distance_m(frames, face)
    assert d_goal == pytest.approx(kin.LIMB_RADIUS_M + gap_m, abs=1e-6)
    d_min, rate = kin.LIMB_RADIUS_M + 0.002, 3.0
    _, capped = forearm_bounds(frames, face, d_min, rate, goal_q_rad=q)
    _, plain = forearm_bounds(frames, face, d_min, rate)
    assert capped[0] == pytest.approx(-rate * max(d_goal - d_min, GOAL_SLACK_M))
    assert plain[0] == pytest.approx(-rate * (d_goal - d_min))
    if gap_m < 0.002:
        assert plain[0] > 0.0 > capped[0]
    else:
        assert capped[0] == plain[0]


def test_near_its_goal_the_margin_is_a_funnel_and_the_bound_its_gap_s_rate() -> None:
    """The goal within the margin: 1.5 mm from the wrist's place at the goal the margin is the
    goal's clearance less the slack, raised by 1.5 mm's share of the funnel; ``rows · V`` is
    the rate of the gap ``d − margin`` under ``q̇ = J⁺ V`` (the margin moves with the wrist);
    far from the goal the margin is the whole ``d_min``."""
    q_goal = np.array(load_scenario(None).robot.q0)
    goal_frames = kin.frame_transforms(q_goal)
    elbow, wrist = goal_frames[ELBOW_FRAME][:3, 3], goal_frames[WRIST_FRAME][:3, 3]
    side = np.cross(wrist - elbow, UP)
    side /= np.linalg.norm(side)
    centre = wrist + (0.03 + kin.LIMB_RADIUS_M + 0.0005) * side + np.array([0.0, 0.02, 0.0])
    face = TopFace(centre, side, np.cross(UP, side), UP, 0.03)
    d_min, rate = kin.LIMB_RADIUS_M + 0.002, 3.0
    at_goal = forearm_distance_m(goal_frames, face) - GOAL_SLACK_M

    def wrist_off(q_rad: np.ndarray) -> float:
        return float(np.linalg.norm(kin.frame_transforms(q_rad)[WRIST_FRAME][:3, 3] - wrist))

    direction = np.array([0.3, -0.2, 0.5, 0.4, 0.0, 0.0])
    q = q_goal + direction * 0.0015 / (wrist_off(q_goal + direction * 1e-3) * 1e3)  # ~1.5 mm
    off = wrist_off(q)
    assert 0.001 < off < 0.002
    margin, gradient = margin_near_goal(d_min, kin.frame_transforms(q), q_goal, face)
    slope = (d_min - at_goal) / FUNNEL_RADIUS_M
    assert margin == pytest.approx(at_goal + slope * off) and margin < d_min
    assert np.linalg.norm(gradient) == pytest.approx(slope)

    def gap(q_rad: np.ndarray) -> float:
        frames = kin.frame_transforms(q_rad)
        return forearm_distance_m(frames, face) - margin_near_goal(d_min, frames, q_goal, face)[0]

    rows, bounds = forearm_bounds(kin.frame_transforms(q), face, d_min, rate, goal_q_rad=q_goal)
    assert bounds[0] == pytest.approx(-rate * gap(q))
    twist = np.array([0.02, -0.05, 0.01, 0.2, -0.1, 0.3])
    qdot = np.linalg.pinv(kin.geometric_jacobian(q)) @ twist
    fd = (gap(q + 1e-7 * qdot) - gap(q - 1e-7 * qdot)) / 2e-7
    assert float(rows[0] @ twist) == pytest.approx(fd, rel=1e-4)
    far = q_goal + np.deg2rad([10.0, 0.0, 0.0, -10.0, 0.0, 0.0])
    assert margin_near_goal(d_min, kin.frame_transforms(far), q_goal, face) == (
        d_min,
        pytest.approx(np.zeros(3)),
    )


def test_a_calibration_error_no_longer_stops_the_hand_short_of_its_goal() -> None:
    """The camera believed 5 mm off along -x: the object seen nearer the forearm puts the goal
    inside the forearm's 2 mm margin, but not its surface into the object. From this campaign
    start the hand ended 2.4 mm from its goal with the margin whole; with the funnel it
    reaches it, touching nothing."""
    scenario = start_scenario(
        "start_0003",
        "camera.calibration_error.position_m=[-0.005,0,0]",
        "controller.mode='dynamic'",
    )
    result = run_scenario_inprocess(scenario)
    assert result.converged and result.final_position_error_m < 0.001, result.detail
    assert result.first_contact_s is None


def test_a_goal_seen_with_the_forearm_in_the_object_is_not_trusted_that_far() -> None:
    """The suite's calibration scenario with a smaller error (5 mm and half a degree): the goal
    as seen puts the forearm's surface 3 mm into the object. The funnel stops at the limb's
    radius, so the hand is held short by about that overlap: on its goal (it ended 5.1 mm off
    with the margin whole), touching nothing."""
    overrides = [
        "camera.calibration_error.position_m=[-0.00265, 0.00424, -3e-05]",
        "camera.calibration_error.rotation_deg=[-0.4365, 0.2187, 0.1079]",
        "controller.mode='dynamic'",
    ]
    scenario = load_scenario(
        ROOT / "deploy/scenarios/suite/10_calibration_error.toml", parse_overrides(overrides)
    )
    result = run_scenario_inprocess(scenario)
    assert result.converged and 0.002 < result.final_position_error_m < 0.004, result.detail
    assert result.first_contact_s is None


def test_the_funnel_stops_at_the_limb_s_radius_and_never_rises_faster_than_half_the_wrist() -> None:
    """A goal posture whose forearm axis lies 1 mm from the object (its surface inside it):
    at the goal the margin is the limb's radius, not less. With a 3 cm clearance the funnel
    widens so that its wall rises at half the wrist's motion."""
    q = np.array(load_scenario(None).robot.q0)
    frames = kin.frame_transforms(q)
    elbow, wrist = frames[ELBOW_FRAME][:3, 3], frames[WRIST_FRAME][:3, 3]
    side = np.cross(wrist - elbow, UP)
    side /= np.linalg.norm(side)
    centre = wrist + (0.03 + 0.001) * side + np.array([0.0, 0.02, 0.0])
    face = TopFace(centre, side, np.cross(UP, side), UP, 0.03)
    assert forearm_distance_m(frames, face) == pytest.approx(0.001, abs=1e-6)
    d_min = kin.LIMB_RADIUS_M + 0.002
    assert margin_near_goal(d_min, frames, q, face)[0] == pytest.approx(kin.LIMB_RADIUS_M)
    wide = kin.LIMB_RADIUS_M + 0.03
    assert funnel_radius_m(wide) == pytest.approx(0.06)
    assert funnel_radius_m(d_min) == FUNNEL_RADIUS_M
    nudged = q + np.deg2rad([0.5, 0.0, 0.0, 0.0, 0.0, 0.0])
    margin, gradient = margin_near_goal(wide, kin.frame_transforms(nudged), q, face)
    assert kin.LIMB_RADIUS_M < margin < wide
    assert np.linalg.norm(gradient) == pytest.approx(0.5)
