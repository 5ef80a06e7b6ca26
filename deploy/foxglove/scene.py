"""The 3-D scene as Foxglove scene updates: the fixed scene (arm links, hand, torso, table,
block, markers, both camera frustums), vision's measured markers and the simulator's ground
truth (shown only on its own topic, labelled as such)."""

from __future__ import annotations

from typing import Any

import numpy as np
from foxglove.messages import (
    CubePrimitive,
    CylinderPrimitive,
    LinePrimitive,
    LinePrimitiveLineType,
    Point3,
    SceneEntity,
    SceneUpdate,
    TextPrimitive,
    Vector3,
)

from common import kinematics as kin
from common.camera import CameraIntrinsics
from common.config import Scenario
from common.messages import Features, SimTruth
from deploy.foxglove.style import (
    BLOCK,
    CYAN,
    GREEN,
    GREY,
    MAGENTA,
    RED,
    SKIN,
    TABLE,
    TORSO,
    WHITE,
    YELLOW,
    color,
)
from deploy.foxglove.topics import BASE, CAMERA, CAMERA_TRUE, DH_FRAMES, EE, HAND_MARKER
from deploy.foxglove.transforms import pose, stamp
from services.sim.urdf import (
    MIN_BLOCK_HEIGHT_M,
    TABLE_CENTRE_M,
    TABLE_SIZE_M,
    TORSO_CENTRE_M,
    TORSO_SIZE_M,
    object_block,
)

FloatArray = np.ndarray

FRUSTUM_DEPTH_M = 0.6  # how far the drawn camera frustum reaches


def _cube(transform: FloatArray, size_m: tuple[float, float, float], rgba) -> CubePrimitive:
    return CubePrimitive(
        pose=pose(transform),
        size=Vector3(x=size_m[0], y=size_m[1], z=size_m[2]),
        color=color(rgba),
    )


def _cylinder_between(p0: FloatArray, p1: FloatArray, radius_m: float, rgba) -> CylinderPrimitive:
    """A cylinder from ``p0`` to ``p1`` (its axis is its pose's z)."""
    d = p1 - p0
    length = float(np.linalg.norm(d))
    z = d / length
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    frame = kin.homogeneous(np.column_stack([x, np.cross(z, x), z]), (p0 + p1) / 2)
    return CylinderPrimitive(
        pose=pose(frame),
        size=Vector3(x=2 * radius_m, y=2 * radius_m, z=length),
        bottom_scale=1.0,
        top_scale=1.0,
        color=color(rgba),
    )


def _line(kind: LinePrimitiveLineType, pts, rgba, thickness: float = 2.0) -> LinePrimitive:
    return LinePrimitive(
        type=kind,
        thickness=thickness,
        scale_invariant=True,
        points=[Point3(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in pts],
        color=color(rgba),
    )


def _text(position, text: str, rgba=WHITE) -> TextPrimitive:
    return TextPrimitive(
        pose=pose(kin.homogeneous(np.eye(3), np.asarray(position, dtype=float))),
        billboard=True,
        font_size=14.0,
        scale_invariant=True,
        color=color(rgba),
        text=text,
    )


def _entity(entity_id: str, frame_id: str, t_s: float, **primitives: Any) -> SceneEntity:
    return SceneEntity(
        timestamp=stamp(t_s), frame_id=frame_id, id=entity_id, frame_locked=True, **primitives
    )


def frustum_lines(k: CameraIntrinsics, depth_m: float) -> list[FloatArray]:
    """The camera's field of view as a line list in its optical frame: four rays from the
    centre to the image corners at ``depth_m``, and the rectangle joining them."""
    corners = []
    for u, v in ((-0.5, -0.5), (k.width_px - 0.5, -0.5), (k.width_px - 0.5, k.height_px - 0.5),
                 (-0.5, k.height_px - 0.5)):  # fmt: skip
        corners.append(
            np.array(
                [(u - k.cx_px) / k.fx_px * depth_m, (v - k.cy_px) / k.fy_px * depth_m, depth_m]
            )
        )
    origin = np.zeros(3)
    pts: list[FloatArray] = []
    for i, c in enumerate(corners):
        pts += [origin, c, c, corners[(i + 1) % 4]]
    return pts


def static_scene(scenario: Scenario, t_s: float) -> SceneUpdate:
    """What does not move, or moves only with a frame of the transform tree: the arm's links
    (frame-locked to their DH frames), the hand and its green marker, the torso, the table, the
    block with the red marker as the scenario places it, and both camera frustums."""
    entities = []
    dh = kin.UMAY_DH
    for i in range(len(dh) - 1):
        nxt = dh[i + 1]
        p_next = kin.rot_x(nxt.alpha_prev_rad) @ np.array([nxt.a_prev_m, 0.0, nxt.d_m])
        if np.linalg.norm(p_next) > 0.03:
            cyl = _cylinder_between(np.zeros(3), p_next, kin.LIMB_RADIUS_M, GREY)
            entities.append(_entity(f"link_{i + 1}", DH_FRAMES[i], t_s, cylinders=[cyl]))
    hand_centre = np.array([0.0, kin.HAND_OFFSET_M + kin.HAND_LENGTH_M / 2, 0.0])
    hand = _cube(
        kin.homogeneous(np.eye(3), hand_centre),
        (kin.HAND_THICKNESS_M, kin.HAND_LENGTH_M, kin.HAND_WIDTH_M),
        SKIN,
    )
    size = scenario.marker.size_m
    marker = _cube(np.eye(4), (size, size, 0.002), GREEN)
    entities.append(_entity("hand", EE, t_s, cubes=[hand]))
    entities.append(_entity("hand_marker", HAND_MARKER, t_s, cubes=[marker]))
    entities.append(
        _entity(
            "torso", BASE, t_s,
            cubes=[_cube(kin.homogeneous(np.eye(3), np.array(TORSO_CENTRE_M)), TORSO_SIZE_M,
                         TORSO)],
        )
    )  # fmt: skip
    table = _cube(kin.homogeneous(np.eye(3), np.array(TABLE_CENTRE_M)), TABLE_SIZE_M, TABLE)
    entities.append(_entity("table", BASE, t_s, cubes=[table]))
    target = kin.target_marker_pose(np.array(scenario.target.position), scenario.target.yaw)
    centre, height = object_block(target)  # as the sim builds it
    if height > MIN_BLOCK_HEIGHT_M:
        block_pose = kin.homogeneous(target[:3, :3], centre)
        side = scenario.object_side_m
        block = _cube(block_pose, (side, side, height), BLOCK)
        # The block's height is along the marker's normal (z of the target frame).
        entities.append(_entity("block", BASE, t_s, cubes=[block]))
    red = _cube(target, (size, size, 0.002), RED)
    entities.append(_entity("target_marker", BASE, t_s, cubes=[red]))
    k = scenario.camera.intrinsics()
    lines = LinePrimitiveLineType.LineList
    entities.append(
        _entity(
            "camera_frustum", CAMERA, t_s,
            lines=[_line(lines, frustum_lines(k, FRUSTUM_DEPTH_M), CYAN, 1.5)],
            texts=[_text([0.0, -0.03, 0.0], "camera (assumed: calibration)", CYAN)],
        )
    )  # fmt: skip
    entities.append(
        _entity(
            "camera_true_frustum", CAMERA_TRUE, t_s,
            lines=[_line(lines, frustum_lines(k, FRUSTUM_DEPTH_M * 0.5), MAGENTA, 1.0)],
            texts=[_text([0.0, 0.03, 0.0], "camera true mount (ground truth)", MAGENTA)],
        )
    )  # fmt: skip
    return SceneUpdate(entities=entities)


def measured_markers(features: Features) -> SceneUpdate:
    """Vision's 3-D corners (depth camera) as squares in the ``camera`` frame: where the
    system believes the markers are (an empty entity when a marker is not usable)."""
    t = features.header.sim_time_s
    entities = []
    for name, m, rgba in (("hand", features.hand, GREEN), ("target", features.target, RED)):
        lines = []
        if m.usable:
            lines = [_line(LinePrimitiveLineType.LineLoop, m.points_m, rgba, 3.0)]
        entities.append(_entity(f"measured_{name}", CAMERA, t, lines=lines))
    return SceneUpdate(entities=entities)


def truth_scene(truth: SimTruth, marker_size_m: float) -> SceneUpdate:
    """The simulator's ground truth of both markers as outlined squares, labelled."""
    t = truth.header.sim_time_s
    entities = []
    for name, flat in (("hand", truth.hand_marker_pose), ("target", truth.target_marker_pose)):
        p = np.array(flat).reshape(4, 4)
        corners = kin.marker_corners(p, marker_size_m)
        entities.append(
            _entity(
                f"truth_{name}_marker", BASE, t,
                lines=[_line(LinePrimitiveLineType.LineLoop, corners, YELLOW, 1.0)],
                texts=[_text(p[:3, 3] + np.array([0.0, 0.04, 0.0]), f"{name} (ground truth)",
                             YELLOW)],
            )
        )  # fmt: skip
    return SceneUpdate(entities=entities)
