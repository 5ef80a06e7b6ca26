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
from deploy.launch.run_inprocess import run_scenario_inprocess
from services.controller.arm import ArmReading
from services.controller.clearance import Plane, target_top_plane
from services.controller.forearm import (
    ELBOW_FRAME,
    NEAR_M,
    WRIST_FRAME,
    TopFace,
    distance_to_object,
    forearm_bounds,
    nearest_along,
    point_jacobian,
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
    jp = point_jacobian(kin.frame_transforms(q), forearm_point(q, 0.7))
    for k in range(kin.N_JOINTS):
        dq = np.zeros(kin.N_JOINTS)
        dq[k] = 1e-7
        moved = (forearm_point(q + dq, 0.7) - forearm_point(q - dq, 0.7)) / 2e-7
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
    face = top_face(target_top_plane(square, np.eye(4)), square, 0.075)
    d_min = kin.LIMB_RADIUS_M + controller.config.forearm_clearance_m
    towards = -distance_to_object(wrist, face)[1]  # the wrist straight at the object
    down = ControlOutput(np.concatenate([0.1 * towards, np.zeros(3)]), True, 5.0, False)
    rows, bounds = object_bounds(controller, arm, target_top_plane(square, np.eye(4)), square)
    assert rows.shape == (1, 6) and float(rows[0] @ down.twist_base_ee) < bounds[0]
    out = above_the_target(controller, down, arm)
    assert out.lifted and float(rows[0] @ out.twist_base_ee) >= bounds[0] - 1e-9
    assert distance_to_object(wrist, face)[0] < d_min + 0.03  # near: the bound is on
    controller.config = controller.config.model_copy(update={"keep_forearm_off_object": False})
    assert above_the_target(controller, down, arm) is down
