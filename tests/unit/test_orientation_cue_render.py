"""The orientation cue on rendered images: the simulator draws it (both renderers) and vision's
corner i is the true corner i (ground truth: common.kinematics.marker_corners order) however
the marker is turned; without it a half turn is folded away. Ground truth is used here to
score vision, never fed to it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from common import kinematics as kin
from common.config import Scenario, load_scenario
from deploy.launch.reachability import solve_goal
from services.sim.urdf import robot_urdf
from services.sim.world import World
from services.vision.cue import cue_mask
from services.vision.measurement import measure_markers

MAX_CORNER_ERROR_PX = 0.5  # vision's usual sub-pixel accuracy, with a margin


def scenario(cue: bool, renderer: str = "gl", yaw_rad: float = 0.0) -> Scenario:
    return load_scenario(
        None,
        {
            "marker": {"orientation_cue": cue},
            "sim": {"renderer": renderer},
            "target": {"yaw": yaw_rad},
        },
    )


def labels(measured_px: np.ndarray, truth_px: np.ndarray) -> list[int]:
    """The true corner each measured corner lies on (within MAX_CORNER_ERROR_PX)."""
    d = np.linalg.norm(measured_px[:, None, :] - truth_px[None, :, :], axis=2)
    assert np.all(d.min(axis=1) < MAX_CORNER_ERROR_PX), d
    return d.argmin(axis=1).tolist()


def see(sc: Scenario, q_rad: np.ndarray | None = None) -> tuple[dict, dict, np.ndarray]:
    """Vision's measurements of one render (cue as configured), the true corners, the image."""
    world = World(sc)
    try:
        if q_rad is not None:
            world.reset(q_rad)
        assert all(v.fraction == 1.0 for v in world.marker_visibility().values())
        rgb, depth = world.render()
        truth = world.truth()
        measured = measure_markers(
            rgb, depth, world.intrinsics, sc.vision, orientation_cue=sc.marker.orientation_cue
        )
    finally:
        world.close()
    return measured, {"hand": truth.hand_corners_px, "target": truth.target_corners_px}, rgb


def hand_turned(sc: Scenario, turn_rad: float) -> np.ndarray:
    """Joint angles putting the hand's marker where it starts, turned about the optical axis
    (of the quarter turns, the default start allows 0° and 270°, walked there the long way
    round: at 90° and 180° the wrist's limits or the arm's own links get in the way)."""
    tool = kin.hand_marker_in_ee()
    q = np.array(sc.robot.q0)
    start = kin.forward_kinematics(q) @ tool
    axis = sc.camera.pose()[:3, 2] / np.linalg.norm(sc.camera.pose()[:3, 2])
    s = kin.skew(axis)
    for i in range(1, 21):  # walked there in small steps, on the start's branch
        a = turn_rad * i / 20
        turn = np.eye(3) + math.sin(a) * s + (1 - math.cos(a)) * s @ s
        q, position_error_m, rotation_error_rad = kin.inverse_kinematics(
            kin.homogeneous(turn @ start[:3, :3], start[:3, 3]), q, tool
        )
    assert position_error_m < 1e-5 and rotation_error_rad < 1e-4
    return q


def test_the_cue_is_drawn_inside_both_markers_by_both_renderers_and_only_when_on() -> None:
    blues = {}
    for renderer in ("gl", "tiny"):
        for cue in (True, False):
            measured, _, rgb = see(scenario(cue, renderer))
            blues[renderer, cue] = int(np.count_nonzero(cue_mask(rgb, scenario(cue).vision)))
            assert measured["hand"].visible and measured["target"].visible
    assert blues["gl", False] == blues["tiny", False] == 0
    # two cues of 1/25 of a marker each, the same in both renderers
    assert 100 < blues["gl", True] < 600
    assert abs(blues["gl", True] - blues["tiny", True]) <= 0.05 * blues["gl", True]


@pytest.mark.parametrize("renderer", ["gl", "tiny"])
@pytest.mark.parametrize("turn_deg", [0, 90, 180, 270])
def test_vision_labels_the_target_turned_on_the_table_like_the_truth(
    renderer: str, turn_deg: int
) -> None:
    """The target turned about its normal (its yaw): its image turns through all four
    corners' places, and its cue says which is corner 0."""
    yaw = math.remainder(math.radians(turn_deg), 2 * math.pi)
    measured, truth, _ = see(scenario(True, renderer, yaw))
    for name in ("hand", "target"):
        assert measured[name].visible, measured[name].reason
        assert labels(measured[name].corners_px, truth[name]) == [0, 1, 2, 3]


@pytest.mark.parametrize("turn_deg", [0, 270])
def test_vision_labels_the_hand_turned_about_the_optical_axis_like_the_truth(
    turn_deg: int,
) -> None:
    sc = scenario(True)
    measured, truth, _ = see(sc, hand_turned(sc, math.radians(turn_deg)))
    assert measured["hand"].visible, measured["hand"].reason
    assert labels(measured["hand"].corners_px, truth["hand"]) == [0, 1, 2, 3]


def test_without_the_cue_a_half_turn_rolls_the_labels() -> None:
    """The old behaviour, documented: corners labelled by their place in the image, so the
    target turned by 180° gets its unturned labels, two corners off its physical ones."""
    seen = {}
    for turn_deg in (0, 180):
        measured, truth, _ = see(scenario(False, "gl", math.radians(turn_deg)))
        seen[turn_deg] = labels(measured["target"].corners_px, truth["target"])
    assert seen[180] == [(i + 2) % 4 for i in seen[0]]


def test_cue_off_builds_the_robot_as_before() -> None:
    assert robot_urdf(0.06, orientation_cue=False) == robot_urdf(0.06)
    assert robot_urdf(0.06, orientation_cue=True).count("<visual>") == (
        robot_urdf(0.06).count("<visual>") + 1
    )


def test_with_the_cue_only_the_unturned_goal_counts_before_launch() -> None:
    """A target turned by 180°: without the cue the hand may end on it turned by a half turn
    (the square looks the same); with the cue that is another pose, not the goal."""
    off = solve_goal(scenario(False, yaw_rad=math.pi), seeds=20)
    on = solve_goal(scenario(True, yaw_rad=math.pi), seeds=20)
    assert off is not None and off[1] != 0
    assert on is None or on[1] == 0
    assert solve_goal(scenario(True), seeds=5) is not None  # the default goal, unturned
