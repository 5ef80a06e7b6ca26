"""Project messages → Foxglove well-known messages: the functional core of ``umay view`` and
``umay export --foxglove``.

Nothing here opens a socket, a Zenoh session or a file: :class:`ViewState` takes the wire
messages of one run (:mod:`common.messages`), in the order they come, and returns what to show
as :class:`Out` records (topic, Foxglove message, log time). The live server
(:mod:`deploy.foxglove.node`) and the exporter (:mod:`deploy.foxglove.export`) feed it the same
way, so a recording opened in Foxglove shows what the live view showed.

Time: every message is stamped with the **simulation** time of the data it shows
(``header.sim_time_s``), and that is also its log time, so plots and the timeline are in
simulated seconds, live and in an export alike.

Frames (Foxglove's transform tree): ``world`` (z up, as Foxglove's 3-D panel expects),
``base`` (DH frame 0, the arm base: x forward, y up, z right; turned +90° about x from
``world``), ``dh_1`` … ``dh_6`` (each child of the previous one, by the DH link transform of its
joint), ``end_effector`` (= ``dh_6``), ``hand_marker`` (the green square on the back of the
hand), ``camera`` (the optical frame where the controller *assumes* the camera is: its
calibration) and ``camera_true`` (the true mount the simulator renders from; separately
labelled). The images and vision's 3-D corners are in ``camera``.

Ground truth: the simulator's truth topic (:class:`common.messages.SimTruth`) is shown only
on its own topic (:data:`TRUTH_SCENE`), labelled as ground truth. The view is an observer: it
never publishes anything back to the system.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from foxglove.messages import (
    CameraCalibration,
    CircleAnnotation,
    Color,
    CompressedImage,
    CubePrimitive,
    CylinderPrimitive,
    FrameTransform,
    FrameTransforms,
    ImageAnnotations,
    JointState,
    JointStates,
    KeyValuePair,
    LinePrimitive,
    LinePrimitiveLineType,
    Log,
    LogLevel,
    Point2,
    Point3,
    PointsAnnotation,
    PointsAnnotationType,
    Pose,
    Quaternion,
    RawImage,
    SceneEntity,
    SceneUpdate,
    TextAnnotation,
    TextPrimitive,
    Timestamp,
    Vector3,
)

from common import keys
from common import kinematics as kin
from common.camera import CameraIntrinsics
from common.config import Scenario
from common.keys import SERVICES
from common.messages import (
    DepthFrame,
    EndEffectorTwist,
    Features,
    JointVelocityCommand,
    MarkerFeatures,
    RgbFrame,
    ServiceStatus,
    SimTruth,
)
from common.messages import JointState as UmayJointState
from services.controller.ibvs import choose_pairing, desired_observation, pairing_costs_px2
from services.controller.step import observation
from services.sim.urdf import TORSO_CENTRE_M, TORSO_SIZE_M

FloatArray = np.ndarray

# --- topics -----------------------------------------------------------------------------------
COLOUR_IMAGE = "/camera/colour/compressed"  # CompressedImage, JPEG
DEPTH_IMAGE = "/camera/depth"  # RawImage, 32FC1, metres along the optical axis (0: none)
CALIBRATION = "/camera/calibration"  # CameraCalibration of the colour image
ANNOTATIONS = "/camera/annotations"  # ImageAnnotations on the colour image
TRANSFORMS = "/tf"  # FrameTransforms
SCENE = "/scene"  # SceneUpdate: arm, torso, table, markers, frustum, vision's 3-D corners
TRUTH_SCENE = "/truth/scene"  # SceneUpdate: the simulator's ground truth, labelled as such
JOINT_STATES = "/joint_states"  # JointStates: encoder positions and velocities
JOINT_COMMAND = "/actuation/joint_command"  # JointStates: commanded velocities
FEATURE_ERROR = "/plot/feature_error"  # JSON: e = s - s* per coordinate, its RMS
TWIST = "/plot/twist"  # JSON: commanded end-effector twist (base frame)
PHASE = "/plot/controller_phase"  # JSON: servoing / holding / converged, hold reason
LOG = "/log"  # Log: each service's status once a second; controller phase changes

JOINT_NAMES = tuple(f"joint_{i + 1}" for i in range(kin.N_JOINTS))
DH_FRAMES = tuple(f"dh_{i + 1}" for i in range(kin.N_JOINTS))
WORLD, BASE, EE, HAND_MARKER = "world", "base", "end_effector", "hand_marker"
CAMERA, CAMERA_TRUE = "camera", "camera_true"

PHASES = ("servoing", "holding", "converged")  # phase_code is the index

# JSON schemas of the plot channels (Foxglove plots any numeric message path of them).
_NUMBERS = {"type": "array", "items": {"type": "number"}}
JSON_SCHEMAS: dict[str, dict[str, Any]] = {
    FEATURE_ERROR: {
        "type": "object",
        "title": "umay.FeatureError",
        "properties": {
            "sim_time_s": {"type": "number"},
            "frame_seq": {"type": "integer"},
            "error_px": _NUMBERS,
            "error_px_rms": {"type": "number"},
            "hand_state": {"type": "string"},
            "target_state": {"type": "string"},
        },
    },
    TWIST: {
        "type": "object",
        "title": "umay.Twist",
        "properties": {
            "sim_time_s": {"type": "number"},
            "frame_seq": {"type": "integer"},
            "linear_m_s": _NUMBERS,
            "angular_rad_s": _NUMBERS,
            "speed_m_s": {"type": "number"},
            "error_px_rms": {"type": "number"},
        },
    },
    PHASE: {
        "type": "object",
        "title": "umay.ControllerPhase",
        "properties": {
            "sim_time_s": {"type": "number"},
            "phase": {"type": "string", "enum": list(PHASES)},
            "phase_code": {"type": "integer"},
            "hold_reason": {"type": "string"},
            "mode": {"type": "string"},
            "converged": {"type": "boolean"},
        },
    },
}

# Colours (r, g, b, a in 0..1).
WHITE = (1.0, 1.0, 1.0, 1.0)
GREEN = (0.1, 0.9, 0.2, 1.0)
RED = (1.0, 0.15, 0.15, 1.0)
ORANGE = (1.0, 0.6, 0.0, 1.0)
YELLOW = (1.0, 0.9, 0.1, 1.0)
CYAN = (0.1, 0.9, 1.0, 1.0)
MAGENTA = (1.0, 0.2, 1.0, 1.0)
GREY = (0.75, 0.75, 0.78, 1.0)
SKIN = (0.92, 0.90, 0.86, 1.0)
TORSO = (0.35, 0.37, 0.42, 1.0)
TABLE = (0.86, 0.84, 0.80, 1.0)
BLOCK = (0.45, 0.55, 0.70, 1.0)

TABLE_TOP_Y_M = -0.40  # as the sim's world draws it (services/sim/world.py)
TABLE_CENTRE_M = (0.42, TABLE_TOP_Y_M - 0.02, 0.0)
TABLE_SIZE_M = (0.56, 0.04, 0.90)
LIMB_RADIUS_M = 0.022
FRUSTUM_DEPTH_M = 0.6  # how far the drawn camera frustum reaches
TRAIL_MAX_POINTS = 3000  # the hand-marker centre's trail (the thesis's white dots)
TRAIL_MIN_STEP_PX = 1.0  # a dot is added once the centre has moved this far from the last
STATIC_PERIOD_S = 1.0  # the fixed scene is sent again this often (sim s), for late clients


@dataclass(frozen=True)
class Out:
    """One message to show: ``message`` is a Foxglove message, or a dict for a JSON topic."""

    topic: str
    message: Any
    log_time_ns: int


def time_ns(sim_time_s: float) -> int:
    return round(sim_time_s * 1e9)


def stamp(sim_time_s: float) -> Timestamp:
    ns = time_ns(sim_time_s)
    return Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)


def color(rgba: tuple[float, float, float, float]) -> Color:
    return Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


def quaternion_xyzw(rotation: FloatArray) -> tuple[float, float, float, float]:
    """Unit quaternion (x, y, z, w) of a 3×3 rotation matrix (Shepperd's method, w ≥ 0)."""
    r = np.asarray(rotation, dtype=float)
    trace = r[0, 0] + r[1, 1] + r[2, 2]
    if trace > 0.0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = ((r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, s / 4)
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = 2.0 * math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        q = (s / 4, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s, (r[2, 1] - r[1, 2]) / s)
    elif r[1, 1] > r[2, 2]:
        s = 2.0 * math.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
        q = ((r[0, 1] + r[1, 0]) / s, s / 4, (r[1, 2] + r[2, 1]) / s, (r[0, 2] - r[2, 0]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
        q = ((r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, s / 4, (r[1, 0] - r[0, 1]) / s)
    n = math.sqrt(sum(c * c for c in q))
    x, y, z, w = (c / n for c in q)
    return (-x, -y, -z, -w) if w < 0 else (x, y, z, w)


def rotation_from_quaternion(x: float, y: float, z: float, w: float) -> FloatArray:
    """3×3 rotation of a unit quaternion (the inverse of :func:`quaternion_xyzw`)."""
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def pose(transform: FloatArray) -> Pose:
    x, y, z, w = quaternion_xyzw(transform[:3, :3])
    p = transform[:3, 3]
    return Pose(
        position=Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
        orientation=Quaternion(x=x, y=y, z=z, w=w),
    )


def frame_transform(parent: str, child: str, transform: FloatArray, t_s: float) -> FrameTransform:
    x, y, z, w = quaternion_xyzw(transform[:3, :3])
    p = transform[:3, 3]
    return FrameTransform(
        timestamp=stamp(t_s),
        parent_frame_id=parent,
        child_frame_id=child,
        translation=Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
        rotation=Quaternion(x=x, y=y, z=z, w=w),
    )


def arm_transforms(q_rad: FloatArray, t_s: float) -> list[FrameTransform]:
    """``base`` → ``dh_1`` → … → ``dh_6`` (one DH link transform each), ``dh_6`` →
    ``end_effector`` (identity) → ``hand_marker``: composed, they give forward kinematics."""
    out = []
    parent = BASE
    for i, (row, qi) in enumerate(zip(kin.UMAY_DH, q_rad, strict=True)):
        out.append(
            frame_transform(parent, DH_FRAMES[i], kin.dh_link_transform(row, float(qi)), t_s)
        )
        parent = DH_FRAMES[i]
    out.append(frame_transform(parent, EE, np.eye(4), t_s))
    out.append(frame_transform(EE, HAND_MARKER, kin.hand_marker_in_ee(), t_s))
    return out


# base → world: the base's y (up) becomes the world's z.
WORLD_FROM_BASE = kin.homogeneous(kin.rot_x(math.pi / 2), np.zeros(3))


def camera_transforms(scenario: Scenario, t_s: float) -> list[FrameTransform]:
    """``world`` → ``base``, the assumed camera pose (calibration: ``camera``) and the true
    mount (``camera_true``)."""
    cam = scenario.camera
    return [
        frame_transform(WORLD, BASE, WORLD_FROM_BASE, t_s),
        frame_transform(BASE, CAMERA, cam.assumed_pose(), t_s),
        frame_transform(BASE, CAMERA_TRUE, cam.pose(), t_s),
    ]


def compressed_image(frame: RgbFrame, jpeg_quality: int = 85) -> CompressedImage:
    """The colour frame as JPEG (OpenCV), in the ``camera`` frame."""
    bgr = cv2.cvtColor(frame.rgb.to_array(), cv2.COLOR_RGB2BGR)
    ok, jpeg = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
    if not ok:
        raise ValueError("OpenCV could not encode the frame as JPEG")
    return CompressedImage(
        timestamp=stamp(frame.header.sim_time_s),
        frame_id=CAMERA,
        data=jpeg.tobytes(),
        format="jpeg",
    )


def depth_image(frame: DepthFrame) -> RawImage:
    """The depth image as it is (float32 metres, 0 = no measurement): encoding ``32FC1``."""
    h, w = frame.depth_m.shape
    return RawImage(
        timestamp=stamp(frame.header.sim_time_s),
        frame_id=CAMERA,
        width=w,
        height=h,
        encoding="32FC1",
        step=4 * w,
        data=bytes(frame.depth_m.data),
    )


def calibration(k: CameraIntrinsics, t_s: float) -> CameraCalibration:
    """Pinhole intrinsics of the colour image, no distortion (the simulated Kinect has none)."""
    return CameraCalibration(
        timestamp=stamp(t_s),
        frame_id=CAMERA,
        width=k.width_px,
        height=k.height_px,
        distortion_model="plumb_bob",
        D=[0.0] * 5,
        K=[k.fx_px, 0.0, k.cx_px, 0.0, k.fy_px, k.cy_px, 0.0, 0.0, 1.0],
        R=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        P=[k.fx_px, 0.0, k.cx_px, 0.0, 0.0, k.fy_px, k.cy_px, 0.0, 0.0, 0.0, 1.0, 0.0],
    )


def desired_corners_px(features: Features, approach_height_m: float) -> FloatArray | None:
    """s*: the controller's desired corners for this frame (the target's measured corners
    raised by the approach height, :func:`services.controller.ibvs.desired_observation`), or
    None while the target is not usable."""
    if not features.target.usable:
        return None
    target = desired_observation(
        observation(features.target), approach_height_m, features.intrinsics
    )
    return np.asarray(target.corners_px, dtype=float)


def paired_error_px(hand_px: FloatArray, desired_px: FloatArray) -> FloatArray:
    """e = s - s* (4×2) with the hand's corners paired to the desired ones as the controller
    pairs them (the cyclic pairing of least cost)."""
    k = choose_pairing(pairing_costs_px2(hand_px, desired_px), None)
    return hand_px - np.roll(desired_px, -k, axis=0)


def _points(
    kind: PointsAnnotationType,
    pts: FloatArray,
    rgba: tuple[float, float, float, float],
    t_s: float,
    name: str,
    thickness: float = 2.0,
) -> PointsAnnotation:
    return PointsAnnotation(
        timestamp=stamp(t_s),
        type=kind,
        points=[Point2(x=float(u), y=float(v)) for u, v in pts],
        outline_color=color(rgba),
        thickness=thickness,
        metadata=[KeyValuePair(key="name", value=name)],
    )


def _marker_colour(m: MarkerFeatures, seen: tuple[float, float, float, float]):
    return seen if m.state == "visible" else ORANGE


def _state_text(name: str, m: MarkerFeatures) -> str:
    extra = " (fitted)" if m.fitted else ""
    extra += " (occluded)" if m.occluded else ""
    return f"{name}: {m.state}{extra}"


def image_annotations(
    features: Features,
    desired_px: FloatArray | None,
    trail_px: list[tuple[float, float]],
    error_px_rms: float | None,
) -> ImageAnnotations:
    """Fig. 5.10-5.16's overlay: the hand's square (green), the target's (red), both orange
    when only partly seen, the desired corners s* (yellow), the error vectors s → s* (cyan),
    the hand-marker centre's trail (white dots) and the states and pixel error as text.
    Each points annotation names itself in its metadata (``name``: hand, target, desired,
    error, trail)."""
    t = features.header.sim_time_s
    points: list[PointsAnnotation] = []
    circles: list[CircleAnnotation] = []
    loop = PointsAnnotationType.LineLoop
    for name, m, rgba in (("hand", features.hand, GREEN), ("target", features.target, RED)):
        if not m.usable:
            continue
        corners = np.asarray(m.corners_px, dtype=float)
        points.append(_points(loop, corners, _marker_colour(m, rgba), t, name))
        circles.extend(
            CircleAnnotation(
                timestamp=stamp(t),
                position=Point2(x=float(u), y=float(v)),
                diameter=6.0,
                thickness=1.5,
                outline_color=color(_marker_colour(m, rgba)),
            )
            for u, v in corners
        )
    if desired_px is not None:
        points.append(_points(loop, desired_px, YELLOW, t, "desired", 1.5))
        if features.hand.usable:
            hand = np.asarray(features.hand.corners_px, dtype=float)
            err = paired_error_px(hand, desired_px)
            segments = np.stack([hand, hand - err], axis=1).reshape(-1, 2)
            points.append(_points(PointsAnnotationType.LineList, segments, CYAN, t, "error", 1.5))
    if trail_px:
        points.append(
            _points(PointsAnnotationType.Points, np.array(trail_px), WHITE, t, "trail", 3.0)
        )
    lines = [
        _state_text("hand", features.hand),
        _state_text("target", features.target),
        "e: -" if error_px_rms is None else f"e: {error_px_rms:.2f} px rms",
    ]
    texts = [
        TextAnnotation(
            timestamp=stamp(t),
            position=Point2(x=8.0, y=20.0 + 18.0 * i),
            text=line,
            font_size=14.0,
            text_color=color(WHITE),
            background_color=Color(r=0.0, g=0.0, b=0.0, a=0.5),
        )
        for i, line in enumerate(lines)
    ]
    return ImageAnnotations(circles=circles, points=points, texts=texts)


# --- the 3-D scene ----------------------------------------------------------------------------
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
            cyl = _cylinder_between(np.zeros(3), p_next, LIMB_RADIUS_M, GREY)
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
    top_y = float(target[1, 3])
    if top_y - TABLE_TOP_Y_M > 0.005:
        centre = np.array([target[0, 3], (top_y + TABLE_TOP_Y_M) / 2, target[2, 3]])
        block_pose = kin.homogeneous(target[:3, :3], centre)
        side = size * 1.25
        block = _cube(block_pose, (side, side, top_y - TABLE_TOP_Y_M), BLOCK)
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


def joint_states(names: tuple[str, ...], position, velocity, t_s: float) -> JointStates:
    return JointStates(
        timestamp=stamp(t_s),
        joints=[
            JointState(
                name=n,
                position=None if position is None else float(position[i]),
                velocity=None if velocity is None else float(velocity[i]),
            )
            for i, n in enumerate(names)
        ],
    )


def phase_of(twist: EndEffectorTwist) -> str:
    if twist.converged:
        return "converged"
    return "servoing" if twist.valid else "holding"


def status_log(status: ServiceStatus | None, service: str, t_s: float) -> Log:
    """One line per service and status query: its state, rates and processing time."""
    if status is None:
        return Log(
            timestamp=stamp(t_s),
            level=LogLevel.Warning,
            message="no status answer",
            name=service,
        )
    rates = ", ".join(
        f"{k.rsplit('/', 1)[-1]} {s.rate_hz:.1f} Hz" for k, s in sorted(status.published.items())
    )
    p50 = status.processing_ms_p50
    parts = [
        status.state + (f" ({status.degraded_reason})" if status.degraded_reason else ""),
        f"pid {status.pid}",
        f"up {status.uptime_s:.0f} s",
    ]
    if rates:
        parts.append(f"out: {rates}")
    if p50 is not None:
        parts.append(f"processing p50 {p50:.2f} ms")
    if status.rejected:
        parts.append(f"rejected {status.rejected}: {status.last_rejection}")
    level = LogLevel.Info if status.state == "running" else LogLevel.Warning
    return Log(timestamp=stamp(t_s), level=level, message="; ".join(parts), name=service)


def status_logs(statuses: list[ServiceStatus], t_s: float) -> list[Out]:
    """A log line for each of the four services (a warning for one that did not answer)."""
    by_name = {s.service: s for s in statuses}
    return [Out(LOG, status_log(by_name.get(s), s, t_s), time_ns(t_s)) for s in SERVICES]


@dataclass
class ViewState:
    """The view of one run: feed it the run's messages in order (``on_*``), show what they
    return. State: the hand-marker trail, the last features, the controller's last phase, when
    the fixed scene was last sent and the newest simulation time seen."""

    scenario: Scenario
    trail_max: int = TRAIL_MAX_POINTS
    trail_px: list[tuple[float, float]] = field(default_factory=list)
    last_error_px_rms: float | None = None
    last_phase: tuple[str, str] | None = None
    static_sent_s: float | None = None
    sim_time_s: float = 0.0

    def _advance(self, t_s: float) -> None:
        self.sim_time_s = max(self.sim_time_s, t_s)

    def fixed(self, t_s: float) -> list[Out]:
        """The fixed scene, the camera frames and the calibration, once per
        :data:`STATIC_PERIOD_S` (and on the first call)."""
        if self.static_sent_s is not None and t_s - self.static_sent_s < STATIC_PERIOD_S:
            return []
        self.static_sent_s = t_s
        ns = time_ns(t_s)
        k = self.scenario.camera.intrinsics()
        return [
            Out(SCENE, static_scene(self.scenario, t_s), ns),
            Out(CALIBRATION, calibration(k, t_s), ns),
        ]

    def on_rgb(self, frame: RgbFrame, jpeg_quality: int = 85) -> list[Out]:
        t = frame.header.sim_time_s
        self._advance(t)
        return [Out(COLOUR_IMAGE, compressed_image(frame, jpeg_quality), time_ns(t))]

    def on_depth(self, frame: DepthFrame) -> list[Out]:
        t = frame.header.sim_time_s
        self._advance(t)
        return [Out(DEPTH_IMAGE, depth_image(frame), time_ns(t))]

    def on_joint_state(self, js: UmayJointState) -> list[Out]:
        t = js.header.sim_time_s
        self._advance(t)
        tf = FrameTransforms(
            transforms=[*arm_transforms(np.array(js.position_rad), t),
                        *camera_transforms(self.scenario, t)]
        )  # fmt: skip
        ns = time_ns(t)
        states = joint_states(JOINT_NAMES, js.position_rad, js.velocity_rad_s, t)
        return [*self.fixed(t), Out(TRANSFORMS, tf, ns), Out(JOINT_STATES, states, ns)]

    def on_features(self, features: Features) -> list[Out]:
        t = features.header.sim_time_s
        self._advance(t)
        ns = time_ns(t)
        hand = features.hand
        if hand.usable:
            u, v = np.mean(np.asarray(hand.corners_px, dtype=float), axis=0)
            last = self.trail_px[-1] if self.trail_px else None
            if last is None or math.hypot(u - last[0], v - last[1]) >= TRAIL_MIN_STEP_PX:
                self.trail_px.append((float(u), float(v)))
            del self.trail_px[: max(0, len(self.trail_px) - self.trail_max)]
        desired = desired_corners_px(features, self.scenario.target.approach_height_m)
        error: dict[str, Any] = {
            "sim_time_s": t,
            "frame_seq": features.header.frame_seq,
            "error_px": [],
            "error_px_rms": None,
            "hand_state": hand.state,
            "target_state": features.target.state,
        }
        rms = None
        if desired is not None and hand.usable:
            e = paired_error_px(np.asarray(hand.corners_px, dtype=float), desired)
            rms = float(np.sqrt(np.mean(e**2)))
            error.update(error_px=e.reshape(-1).tolist(), error_px_rms=rms)
        self.last_error_px_rms = rms
        ann = image_annotations(features, desired, self.trail_px, rms)
        return [
            Out(ANNOTATIONS, ann, ns),
            Out(FEATURE_ERROR, error, ns),
            Out(SCENE, measured_markers(features), ns),
        ]

    def on_twist(self, twist: EndEffectorTwist) -> list[Out]:
        t = twist.header.sim_time_s
        self._advance(t)
        ns = time_ns(t)
        phase = phase_of(twist)
        out = [
            Out(
                TWIST,
                {
                    "sim_time_s": t,
                    "frame_seq": twist.header.frame_seq,
                    "linear_m_s": list(twist.linear_m_s),
                    "angular_rad_s": list(twist.angular_rad_s),
                    "speed_m_s": float(np.linalg.norm(twist.linear_m_s)),
                    "error_px_rms": twist.error_px_rms,
                },
                ns,
            ),
            Out(
                PHASE,
                {
                    "sim_time_s": t,
                    "phase": phase,
                    "phase_code": PHASES.index(phase),
                    "hold_reason": twist.hold_reason,
                    "mode": twist.mode,
                    "converged": twist.converged,
                },
                ns,
            ),
        ]
        now = (phase, twist.hold_reason)
        if now != self.last_phase:
            self.last_phase = now
            text = phase + (f": {twist.hold_reason}" if twist.hold_reason else "")
            level = LogLevel.Warning if phase == "holding" else LogLevel.Info
            log = Log(
                timestamp=stamp(t),
                level=level,
                message=f"{text} (frame {twist.header.frame_seq}, mode {twist.mode})",
                name="controller",
            )
            out.append(Out(LOG, log, ns))
        return out

    def on_joint_command(self, cmd: JointVelocityCommand) -> list[Out]:
        t = cmd.header.sim_time_s
        self._advance(t)
        states = joint_states(JOINT_NAMES, None, cmd.velocity_rad_s, t)
        return [Out(JOINT_COMMAND, states, time_ns(t))]

    def on_truth(self, truth: SimTruth) -> list[Out]:
        t = truth.header.sim_time_s
        self._advance(t)
        scene = truth_scene(truth, self.scenario.marker.size_m)
        return [Out(TRUTH_SCENE, scene, time_ns(t))]

    def on_message(self, suffix: str, message: Any, jpeg_quality: int = 85) -> list[Out]:
        """Route a message by its key relative to the prefix (``sim/rgb``, ...); keys the
        view does not show (``sim/timing``) give nothing."""
        if suffix == keys.RGB:
            return self.on_rgb(message, jpeg_quality)
        handler = self._handlers().get(suffix)
        return [] if handler is None else handler(message)

    def _handlers(self) -> dict[str, Any]:
        return {
            keys.DEPTH: self.on_depth,
            keys.JOINT_STATE: self.on_joint_state,
            keys.FEATURES: self.on_features,
            keys.TWIST: self.on_twist,
            keys.JOINT_COMMAND: self.on_joint_command,
            keys.TRUTH: self.on_truth,
        }


# The keys the view subscribes to (relative to the prefix) and their models.
VIEWED_KEYS: dict[str, type] = {
    keys.RGB: RgbFrame,
    keys.DEPTH: DepthFrame,
    keys.JOINT_STATE: UmayJointState,
    keys.FEATURES: Features,
    keys.TWIST: EndEffectorTwist,
    keys.JOINT_COMMAND: JointVelocityCommand,
    keys.TRUTH: SimTruth,
}
