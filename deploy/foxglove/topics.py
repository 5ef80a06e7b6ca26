"""The view's channels: its topics, the frames of its transform tree, and the JSON schemas of
its plot topics (what :mod:`deploy.foxglove.channels` opens and the layout names)."""

from __future__ import annotations

from typing import Any

from common import kinematics as kin

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
            "lifted": {"type": "boolean"},
        },
    },
}
