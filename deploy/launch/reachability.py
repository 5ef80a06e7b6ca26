"""Pre-launch check: can the hand put its green marker on the red target, seen by the camera?

It refuses only what no motion of the loop can fix, each with its reason: a joint outside its
limits, the target not wholly in the image, the hand marker not wholly in the image or facing
away from the camera, the arm inside the object or the table, a goal out of reach. A hand that
hides the target is not refused: the controller uncovers it (services/controller/acquisition.py).
"""

from __future__ import annotations

import numpy as np

from common import kinematics as kin
from common.camera import project
from common.config import Scenario, ScenarioError
from services.sim.urdf import TABLE_TOP_Y_M

IMAGE_MARGIN_PX = 8.0
# Seen more obliquely than this, the hand's square is too thin for vision to fit its corners
# (a 6 cm square at 0.45 m is under a third of its width across): no motion of the servo can
# start without features, so such a start is refused.
MAX_VIEW_ANGLE_DEG = 70.0
# A line of sight is checked up to this fraction short of the marker: the forearm ends at the
# wrist, under the hand box the marker lies on.
SIGHT_CLEARANCE_FRACTION = 0.08
# IK starts tried before a goal is called out of reach: with 12, a third of the goals of random
# targets at any yaw were refused though reachable (the damped iteration stalls at joint
# limits from most seeds when the wrist must turn ~45°); 80 found all but one of them.
GOAL_SEEDS = 80
# Deeper than this into the scenery, a start posture is refused (below it: pybullet's rounding of
# surfaces that touch).
PENETRATION_TOLERANCE_M = 1e-4


class ArmInsideScenery(ScenarioError):
    """The start posture puts the arm inside the object, the table or the floor (a sampler
    draws such a start again rather than refusing it: it is no posture at all)."""


def camera_points(points_base: np.ndarray, scenario: Scenario) -> np.ndarray:
    """Base-frame points (N×3) in the optical frame of the camera's true mount (N×3)."""
    homogeneous = np.column_stack([points_base, np.ones(len(points_base))])
    return (np.linalg.inv(scenario.camera.pose()) @ homogeneous.T).T[:, :3]


def marker_in_image(corners_base: np.ndarray, scenario: Scenario) -> bool:
    cam = scenario.camera
    cam_pts = camera_points(corners_base, scenario)
    if np.any(cam_pts[:, 2] <= cam.near_m):
        return False
    k = cam.intrinsics()
    uv = project(cam_pts, k)
    return bool(
        np.all(uv >= IMAGE_MARGIN_PX)
        and np.all(uv[:, 0] <= k.width_px - 1 - IMAGE_MARGIN_PX)
        and np.all(uv[:, 1] <= k.height_px - 1 - IMAGE_MARGIN_PX)
    )


def view_angle_deg(marker_pose: np.ndarray, scenario: Scenario) -> float:
    """Angle between a marker's outward normal and its line of sight to the camera (0: facing
    the camera squarely; beyond 90°: its back is turned)."""
    to_camera = scenario.camera.pose()[:3, 3] - marker_pose[:3, 3]
    cosine = marker_pose[:3, 2] @ to_camera / np.linalg.norm(to_camera)
    return float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))


def segment_distance_m(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray) -> float:
    """Least distance between the segments p0-p1 and q0-q1 (closest points, clamped)."""
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a, e, f = d1 @ d1, d2 @ d2, d2 @ r
    c, b = d1 @ r, d1 @ d2
    denom = a * e - b * b
    s = float(np.clip((b * f - c * e) / denom, 0.0, 1.0)) if denom > 1e-12 else 0.0
    t = (b * s + f) / e
    if t < 0.0:
        t, s = 0.0, float(np.clip(-c / a, 0.0, 1.0))
    elif t > 1.0:
        t, s = 1.0, float(np.clip((b - c) / a, 0.0, 1.0))
    return float(np.linalg.norm(p0 + s * d1 - (q0 + t * d2)))


def arm_hides_hand_marker(q_rad: np.ndarray, scenario: Scenario) -> bool:
    """Whether the upper arm or the forearm (cylinders of
    :data:`common.kinematics.LIMB_RADIUS_M` between their joints, as the sim draws them) comes
    between the camera and a corner or the centre of the hand marker: vision cannot measure a
    marker the robot's own arm hides."""
    frames = kin.frame_transforms(np.asarray(q_rad, dtype=float))
    marker = frames[-1] @ kin.hand_marker_in_ee()
    points = np.vstack([kin.marker_corners(marker, scenario.marker.size_m), marker[:3, 3]])
    camera = scenario.camera.pose()[:3, 3]
    limbs = [(frames[1][:3, 3], frames[2][:3, 3]), (frames[3][:3, 3], frames[4][:3, 3])]
    for p in points:
        end = camera + (1.0 - SIGHT_CLEARANCE_FRACTION) * (p - camera)  # short of the marker
        for a, b in limbs:
            if segment_distance_m(camera, end, a, b) < kin.LIMB_RADIUS_M:
                return True
    return False


def goal_pose(scenario: Scenario) -> np.ndarray:
    """Where the hand's marker must end (base frame): above the target by the approach height."""
    target = kin.target_marker_pose(np.array(scenario.target.position), scenario.target.yaw)
    return kin.goal_marker_pose(target, scenario.target.approach_height_m)


def square_turns(pose: np.ndarray) -> list[np.ndarray]:
    """``pose`` and its turns by 90°, 180° and 270° about the marker's normal: the square looks
    the same in all four, so the hand may end in any of them."""
    return [pose @ kin.homogeneous(kin.rot_z(k * np.pi / 2), np.zeros(3)) for k in range(4)]


def check_scenario(scenario: Scenario, seeds: int | None = None) -> np.ndarray:
    """Raise :class:`ScenarioError` naming the field if the scenario cannot work; return a joint
    configuration that reaches the target (``seeds``: IK starts, default :data:`GOAL_SEEDS`)."""
    q0 = np.array(scenario.robot.q0)
    outside = np.flatnonzero((q0 < kin.JOINT_LOWER_RAD) | (q0 > kin.JOINT_UPPER_RAD))
    if outside.size:
        joints = ", ".join(f"joint_{i + 1}" for i in outside)
        raise ScenarioError(f"robot.q0: {joints} outside the joint limits")
    size = scenario.marker.size_m
    if scenario.target.position[1] <= TABLE_TOP_Y_M:
        raise ScenarioError(
            f"target.position: y {scenario.target.position[1]:g} m is not above the table's top "
            f"(y {TABLE_TOP_Y_M:g} m): the red marker lies on an object on the table"
        )
    target = kin.target_marker_pose(np.array(scenario.target.position), scenario.target.yaw)
    if not marker_in_image(kin.marker_corners(target, size), scenario):
        raise ScenarioError("target.position: the target marker is not fully in the camera image")
    if not marker_in_image(kin.marker_corners(goal_pose(scenario), size), scenario):
        raise ScenarioError(
            "target.approach_height_m: the hand marker's goal, above the target by it, is not "
            "fully in the camera image"
        )
    start = kin.forward_kinematics(q0) @ kin.hand_marker_in_ee()
    if not marker_in_image(kin.marker_corners(start, size), scenario):
        raise ScenarioError("robot.q0: the hand marker is not fully in the camera image at start")
    if arm_hides_hand_marker(q0, scenario):
        raise ScenarioError("robot.q0: the robot's own arm hides the hand marker from the camera")
    angle = view_angle_deg(start, scenario)
    if angle > MAX_VIEW_ANGLE_DEG:
        raise ScenarioError(
            f"robot.q0: the hand marker faces away from the camera at start ({angle:.0f}° "
            f"from its line of sight; vision measures a square up to {MAX_VIEW_ANGLE_DEG:.0f}°)"
        )
    depth_m, into = arm_penetration(scenario)
    if depth_m > PENETRATION_TOLERANCE_M:
        raise ArmInsideScenery(
            f"robot.q0: the arm is {1000.0 * depth_m:.1f} mm inside the {into} at start "
            "(a posture the simulator cannot start from)"
        )
    solved = solve_goal(scenario, GOAL_SEEDS if seeds is None else seeds)
    if solved is None:
        raise ScenarioError(
            "target.position: the hand cannot place its marker on the target "
            "(out of reach or beyond the joint limits)"
        )
    return solved[0]


def arm_penetration(scenario: Scenario) -> tuple[float, str]:
    """How deep (m) the arm in its start posture ``robot.q0`` reaches into the object, the
    table or the floor, and into which (0.0 and "" when clear): the scenario's own pybullet
    scene, built without a camera (:meth:`services.sim.world.World.arm_penetration`)."""
    from services.sim.world import World  # pybullet: only when a check gets this far

    tiny = scenario.model_copy(update={"sim": scenario.sim.model_copy(update={"renderer": "tiny"})})
    world = World(tiny, clip_scenery=False)
    try:
        return world.arm_penetration()
    finally:
        world.close()


def solve_goal(scenario: Scenario, seeds: int = GOAL_SEEDS) -> tuple[np.ndarray, int] | None:
    """Joint angles putting the hand marker on its goal, and which of the goal's four 90°
    turns they reach (see :func:`square_turns`); None when no seed gets there. Seeds: the
    start posture, then joint angles drawn uniformly within the limits (fixed generator, so
    the verdict is repeatable). With ``marker.orientation_cue`` only the unturned goal (turn
    0) counts: the cue tells the turns apart."""
    rng = np.random.default_rng(0)
    tool = kin.hand_marker_in_ee()
    q0 = np.array(scenario.robot.q0)
    turns = square_turns(goal_pose(scenario))[: 1 if scenario.marker.orientation_cue else 4]
    for i in range(seeds):
        seed = q0 if i == 0 else rng.uniform(kin.JOINT_LOWER_RAD, kin.JOINT_UPPER_RAD)
        for k, goal in enumerate(turns):
            q, pos_err, rot_err = kin.inverse_kinematics(goal, seed, tool, iterations=100)
            if pos_err < 1e-4 and rot_err < 1e-3:
                return q, k
    return None
