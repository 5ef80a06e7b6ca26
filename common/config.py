"""Scenario configuration: one TOML file, validated by pydantic, read by every service.

Each service takes its own table (``[camera]``, ``[vision]``, ``[controller]``, ...) from the
same scenario file, so one file describes one experiment. Every model forbids unknown fields,
so a typo is reported with its path instead of being silently ignored.
"""

from __future__ import annotations

import math
import re
import tomllib
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from common.camera import CameraIntrinsics, look_at_rotation
from common.kinematics import (
    BASE_UP,
    HAND_THICKNESS_M,
    JOINT_VELOCITY_LIMIT_RAD_S,
    MARKER_THICKNESS_M,
    POSITION_LIMIT_ZONE_RAD,
    homogeneous,
    rot_x,
    rot_y,
    rot_z,
)
from common.messages import MAX_ANGULAR_RAD_S, MAX_LINEAR_M_S

DEFAULT_SCENARIO = Path(__file__).resolve().parent.parent / "deploy" / "scenarios" / "default.toml"

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
Joints6 = Annotated[list[float], Field(min_length=6, max_length=6)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)


class ClockMode(StrEnum):
    """How simulated time advances."""

    LOCKSTEP = "lockstep"  # one camera period per command: deterministic, speed-independent
    REALTIME = "realtime"  # physics at wall-clock rate, frames dropped when rendering lags


class JacobianMode(StrEnum):
    """The four image-Jacobian strategies of the thesis (§5.6-5.7), and points3d: the corners'
    3-D positions from the depth camera as features instead of their image points."""

    CONSTANT = "constant"
    DYNAMIC = "dynamic"
    PMJ = "pmj"
    MPJ = "mpj"
    POINTS3D = "points3d"


class ConstantDepth(StrEnum):
    """The depths the constant strategy's frozen interaction matrix is built with."""

    SINGLE = "single"  # one depth for every corner: the thesis's (the target's at the start)
    PER_CORNER = "per_corner"  # each desired corner's own depth, measured at the start


class ClearanceCorrection(StrEnum):
    """How a twist that would lower the hand box onto the object's top face is corrected."""

    # the law's twist changed where its features notice it least (controller/constrained.py)
    LEAST_FEATURE_CHANGE = "least_feature_change"
    LIFT = "lift"  # the least upward velocity added, the rest of the twist kept as it was


class RobotConfig(_Strict):
    q0: Joints6 = Field(description="initial joint angles (rad), joint_1..joint_6")


OBJECT_SIDE_PER_MARKER = 1.25  # the object's top face, in marker sides, unless given


class TargetConfig(_Strict):
    position: Vec3 = Field(description="red marker centre in the arm base frame (m)")
    yaw: float = Field(0.0, ge=-math.pi, le=math.pi, description="about the vertical (rad)")
    approach_height_m: float = Field(
        0.03,
        ge=0.0,
        le=0.2,
        description="the hand's marker stops this far above the red one, along its normal (m)",
    )
    object_side_m: float | None = Field(
        None,
        gt=0.0,
        le=0.5,
        description="side of the object's square top face, centred under the red marker (m; "
        "default 1.25 × marker.size_m): the sim builds the object so, and the controller is "
        "given it as the object's model (as vision is given the marker's size) to keep the "
        "forearm off it",
    )


class MarkerConfig(_Strict):
    size_m: float = Field(0.06, gt=0.01, le=0.2, description="side of both square markers (m)")
    orientation_cue: bool = Field(
        False,
        description="each marker carries a small blue square inside it near its corner 0, so "
        "vision labels the corners physically and a hand turned up to 180° about the optical "
        "axis is seen as such (a plain square looks the same turned by 90°); the controller "
        "then pairs hand corner i with target corner i. Off: the thesis's plain squares",
    )


class KinectConfig(_Strict):
    """Scenario table ``[camera.kinect]``; ``enabled = false`` keeps perfect images."""

    enabled: bool = Field(
        False,
        description="the Kinect v1 model on the rendered images: axial depth noise, disparity "
        "quantisation, range limits, edge dropout, lateral noise, exposure and RGB noise "
        "(docs/vision.md); off: perfect images",
    )
    seed: int = Field(0, ge=0, description="noisy runs stay reproducible")
    min_range_m: float = Field(0.4, ge=0.0, description="near mode; 0.5 m in default mode")
    max_range_m: float = Field(4.0, gt=0.0, description="farther surfaces give no depth (m)")
    edge_threshold_m: float = Field(0.03, gt=0.0, description="a jump this large is an edge")
    edge_dropout_px: int = Field(2, ge=0, le=10, description="invalid band along edges")
    lateral_noise_px: float = Field(
        0.8,
        ge=0.0,
        le=5.0,
        description="spread of the pixel shift each depth is read from (σ, px; clipped)",
    )
    quantise: bool = Field(
        True, description="depths in the disparity's 1/8 px steps, coarser with distance"
    )
    rgb_noise_sigma: float = Field(2.0, ge=0.0, le=50.0, description="per channel, 0-255 units")
    brightness: float = Field(1.0, gt=0.0, le=4.0, description="exposure scale")
    colour_temperature: float = Field(
        0.0, ge=-1.0, le=1.0, description="-1 warm (red up, blue down) … +1 cool"
    )

    @model_validator(mode="after")
    def _range(self) -> KinectConfig:
        if self.min_range_m >= self.max_range_m:  # no depth at any range
            raise ValueError(
                f"min_range_m ({self.min_range_m}) must be below max_range_m ({self.max_range_m})"
            )
        return self


class CalibrationError(_Strict):
    """How far the camera pose the controller assumes is from the true mount: the true pose
    composed with this offset (translation in the base frame, then a rotation about the optical
    frame's own axes). Zero by default: a perfectly calibrated camera."""

    position_m: Vec3 = Field(
        [0.0, 0.0, 0.0], description="added to the optical centre, in the arm base frame (m)"
    )
    rotation_deg: Vec3 = Field(
        [0.0, 0.0, 0.0], description="about the optical x, y, z axes, applied in that order"
    )


class CameraConfig(_Strict):
    width_px: int = Field(640, ge=64, le=1920, description="colour image width (px)")
    height_px: int = Field(480, ge=48, le=1080, description="colour image height (px)")
    hfov_deg: float = Field(
        57.0, gt=10.0, lt=120.0, description="horizontal field of view (°), the Kinect's"
    )
    rgb_hz: float = Field(
        30.0,
        ge=9.0,
        le=120.0,
        description="colour frames per second; at least 9, and a frame (in whole physics "
        "steps) shorter than a joint takes to cross its slow-down zone at full speed: a joint "
        "command is followed for a frame, and a longer one could carry a joint past its limit",
    )
    depth_hz: float | None = Field(
        None,
        gt=0.0,
        le=120.0,
        description="depth images per second, each taken with a colour frame (default: "
        "rgb_hz; the thesis ran depth at 1 Hz)",
    )
    depth_width_px: int | None = Field(
        None,
        ge=16,
        le=1920,
        description="native depth width, registered to colour (default: the colour one)",
    )
    depth_height_px: int | None = Field(
        None, ge=12, le=1080, description="native depth height (default: the colour one)"
    )
    position: Vec3 = Field(description="optical centre in the arm base frame (m)")
    look_at: Vec3 = Field(description="point on the optical axis in the arm base frame (m)")
    near_m: float = Field(0.05, gt=0.0, description="the renderer's near clipping plane (m)")
    far_m: float = Field(5.0, gt=0.0, description="the renderer's far clipping plane (m)")
    kinect: KinectConfig = KinectConfig()
    calibration_error: CalibrationError = CalibrationError()

    @model_validator(mode="after")
    def _consistent(self) -> CameraConfig:
        if self.depth_hz is not None and self.depth_hz > self.rgb_hz:
            raise ValueError(
                f"depth_hz ({self.depth_hz}) above rgb_hz ({self.rgb_hz}): every depth image "
                "is taken with a colour frame"
            )
        if (self.depth_width_px is None) != (self.depth_height_px is None):
            raise ValueError("give both depth_width_px and depth_height_px, or neither")
        if self.depth_width_px is not None and self.depth_height_px is not None:
            if self.depth_width_px > self.width_px:
                raise ValueError("depth_width_px above width_px: depth is registered to colour")
            if abs(
                self.depth_width_px * self.height_px - self.depth_height_px * self.width_px
            ) > max(self.width_px, self.height_px):
                raise ValueError(
                    f"depth image {self.depth_width_px}×{self.depth_height_px} does not have "
                    f"the colour image's aspect ratio ({self.width_px}×{self.height_px})"
                )
        if self.near_m >= self.far_m:
            raise ValueError(f"near_m ({self.near_m}) must be below far_m ({self.far_m})")
        axis = np.array(self.look_at, dtype=float) - np.array(self.position, dtype=float)
        if np.linalg.norm(axis) < 1e-6:
            raise ValueError("look_at equals position: no optical axis")
        if np.linalg.norm(np.cross(axis / np.linalg.norm(axis), BASE_UP)) < 1e-3:
            raise ValueError(
                "look_at straight above or below position: the image's up is undefined"
            )
        return self

    @property
    def depth_rate_hz(self) -> float:
        return self.rgb_hz if self.depth_hz is None else self.depth_hz

    def intrinsics(self) -> CameraIntrinsics:
        return CameraIntrinsics.from_fov(self.width_px, self.height_px, self.hfov_deg)

    def depth_intrinsics(self) -> CameraIntrinsics:
        """The depth image's own intrinsics: same field of view, its own resolution."""
        if self.depth_width_px is None or self.depth_height_px is None:
            return self.intrinsics()
        return CameraIntrinsics.from_fov(self.depth_width_px, self.depth_height_px, self.hfov_deg)

    def pose(self) -> np.ndarray:
        """4×4 pose of the optical frame in the base frame (image up as close to up as it gets).

        This is the true mount: the sim renders from it, and the pre-launch check uses it."""
        rot = look_at_rotation(np.array(self.position), np.array(self.look_at), BASE_UP)
        return homogeneous(rot, np.array(self.position, dtype=float))

    def assumed_pose(self) -> np.ndarray:
        """The pose the controller believes (its calibration): :meth:`pose` with
        ``calibration_error`` applied; equal to it by default."""
        true = self.pose()
        rx, ry, rz = np.radians(self.calibration_error.rotation_deg)
        turn = rot_x(rx) @ rot_y(ry) @ rot_z(rz)
        return homogeneous(
            true[:3, :3] @ turn, true[:3, 3] + np.array(self.calibration_error.position_m)
        )


Rgb = Annotated[list[Annotated[int, Field(ge=0, le=255)]], Field(min_length=3, max_length=3)]


class HsvRange(_Strict):
    """Inclusive OpenCV HSV range (H in 0..179, S and V in 0..255). Red wraps: give two."""

    lower: Annotated[list[int], Field(min_length=3, max_length=3)]
    upper: Annotated[list[int], Field(min_length=3, max_length=3)]

    @field_validator("lower", "upper")
    @classmethod
    def _in_range(cls, v: list[int]) -> list[int]:
        if not (0 <= v[0] <= 179 and 0 <= v[1] <= 255 and 0 <= v[2] <= 255):
            raise ValueError("expected H in 0..179, S and V in 0..255")
        return v

    @model_validator(mode="after")
    def _lower_below_upper(self) -> HsvRange:
        # An empty range matches nothing: a marker never found (red's wrap is two ranges).
        if any(lo > up for lo, up in zip(self.lower, self.upper, strict=True)):
            raise ValueError(f"lower {self.lower} above upper {self.upper} in some channel")
        return self


class VisionConfig(_Strict):
    segmentation: Literal["hsv", "rgb"] = Field(
        "hsv",
        description="hsv: hue bands (exposure changes leave them alone); rgb: a reference "
        "colour per marker and a tolerance (the thesis's first method)",
    )
    # HSV: hue bands with a high saturation floor and a low value floor, so that exposure
    # changes (value) leave the masks alone; low-saturation table, arm and floor stay out.
    red_hsv: list[HsvRange] = Field(
        min_length=1,
        description="the red marker's OpenCV HSV ranges (H 0..179; red wraps, so two)",
        default_factory=lambda: [
            HsvRange(lower=[0, 120, 30], upper=[8, 255, 255]),
            HsvRange(lower=[172, 120, 30], upper=[179, 255, 255]),
        ],
    )
    green_hsv: list[HsvRange] = Field(
        min_length=1,
        description="the green marker's HSV ranges",
        default_factory=lambda: [HsvRange(lower=[45, 120, 30], upper=[75, 255, 255])],
    )
    # The orientation cue (marker.orientation_cue): a saturated blue, a hue that neither marker,
    # the table, the arm, the floor nor the blue-grey block (saturation below 100) reaches.
    # Looked for only inside a marker's square, in both segmentation modes.
    cue_hsv: list[HsvRange] = Field(
        min_length=1,
        description="the orientation cue's HSV ranges, looked for inside each marker",
        default_factory=lambda: [HsvRange(lower=[100, 120, 30], upper=[130, 255, 255])],
    )
    # RGB mode (the thesis's first method): a reference colour per marker and a per-channel
    # tolerance, calibrated on the markers as the default scene renders them (diffuse light).
    red_rgb: Annotated[
        list[Annotated[int, Field(ge=0, le=255)]], Field(min_length=3, max_length=3)
    ] = Field([130, 12, 12], description="rgb: the red marker's reference colour (0..255)")
    green_rgb: Annotated[
        list[Annotated[int, Field(ge=0, le=255)]], Field(min_length=3, max_length=3)
    ] = Field([15, 115, 22], description="rgb: the green marker's reference colour (0..255)")
    rgb_tolerance: int = Field(
        50, ge=1, le=255, description="rgb: how far each channel may be from the reference"
    )
    min_area_px: int = Field(
        60,
        ge=4,
        description="a smaller blob is not measured as a whole square; the fit of a partly "
        "hidden marker from its visible edges may still find it",
    )
    occlusion_ring_px: int = Field(
        5,
        ge=1,
        le=30,
        description="invalid depth pixels next to a marker count as something in front of it "
        "when a closer surface lies this near (past the band a depth camera leaves invalid "
        "along an occluder's edge)",
    )
    max_depth_age_s: float = Field(
        1.2,
        gt=0.0,
        le=60.0,
        description="a colour frame is paired with the newest depth image no older than this",
    )


class ControllerConfig(_Strict):
    mode: JacobianMode = Field(
        JacobianMode.DYNAMIC,
        description="the image Jacobian: constant, dynamic, pmj, mpj (the thesis's four) or "
        "points3d (the corners' 3-D points as features)",
    )
    gain: float = Field(1.0, gt=0.0, le=20.0, description="λ of e' = -λe (1/s)")
    converged_px: float = Field(
        0.25,
        gt=0.0,
        description="pixel RMS of the error averaged over converged_frames frames below which "
        "it converged",
    )
    converged_frames: int = Field(
        5, ge=1, description="frames servoed on a still goal the error is averaged over"
    )
    constant_depth: ConstantDepth = Field(
        ConstantDepth.SINGLE,
        description="constant: build the frozen matrix with one depth for every corner (the "
        "thesis) or with each desired corner's depth measured at the start (per_corner: the "
        "tilt of the target's plane kept; docs/campaign.md)",
    )
    plateau_px: float = Field(
        1.0,
        ge=0.0,
        description="an averaged error below this that has stopped falling for plateau_s also "
        "converged: the goal lies against a joint limit the law cannot pass (0: off)",
    )
    plateau_s: float = Field(
        1.5, gt=0.0, description="sim time without a 5 % fall of the averaged error (s)"
    )
    keep_above_target: bool = Field(
        True, description="keep the hand box above the object's top face (hand_clearance_m)"
    )
    hand_clearance_m: float = Field(
        0.002,
        ge=0.0,
        description="the hand box's corners stay this far above the plane of the red marker "
        "(the object's top face, as vision measures it)",
    )
    keep_forearm_off_object: bool = Field(
        True,
        description="keep the forearm's surface forearm_clearance_m off the object (the prism "
        "under its top face, target.object_side_m wide; services/controller/forearm.py)",
    )
    forearm_clearance_m: float = Field(
        0.002,
        ge=0.0,
        le=0.05,
        description="the least gap between the forearm's surface (its axis less the limb's "
        "radius) and the object (m)",
    )
    clearance_correction: ClearanceCorrection = Field(
        ClearanceCorrection.LEAST_FEATURE_CHANGE,
        description="how a twist that breaks the clearance is corrected: least_feature_change "
        "(the law's least squares under the bound) or lift (straight up, the rest kept)",
    )
    clearance_rate_1_s: float = Field(
        3.0, gt=0.0, description="a corner's height may fall at most this times its margin (1/s)"
    )
    max_linear_m_s: float = Field(
        0.15, gt=0.0, le=MAX_LINEAR_M_S, description="twist clamp, linear (m/s)"
    )
    max_angular_rad_s: float = Field(
        1.0, gt=0.0, le=MAX_ANGULAR_RAD_S, description="twist clamp, angular (rad/s)"
    )
    track_target_motion: bool = Field(
        True,
        description="estimate the target's velocity from its recent views, feed it forward, "
        "and carry a hidden target along it",
    )
    predict_hand_s: float = Field(
        2.0,
        ge=0.0,
        le=60.0,
        description="while vision cannot use the hand marker, servo on its last view carried "
        "along the encoders' motion for at most this long (sim s; 0: hold at once); never "
        "converged on",
    )
    reachable_pairing: bool = Field(
        True,
        description="pair the squares' corners by the least turn among the pairings whose goal "
        "posture an inverse kinematics from the arm's present posture reaches within the joint "
        "limits, checked on the first frame servoed and again once the goal has moved 2 cm "
        "(services/controller/reach.py); false: the least turn whatever the limits",
    )
    acquire: bool = Field(
        True,
        description="when the target cannot be used because something (the hand) is in front "
        "of it, move the hand's image away to uncover it (services/controller/acquisition.py)",
    )
    acquire_after_s: float = Field(
        0.5, ge=0.0, le=60.0, description="hold this long (sim s) before acquiring"
    )
    acquire_attempts: int = Field(
        4, ge=1, le=20, description="image directions tried before acquisition fails"
    )
    acquire_attempt_s: float = Field(
        4.0, gt=0.0, le=60.0, description="sim s one attempt may take at most"
    )
    acquire_max_linear_m_s: float = Field(
        0.06, gt=0.0, le=0.5, description="twist clamp while acquiring, linear (m/s)"
    )
    acquire_gain: float = Field(
        3.0,
        gt=0.0,
        le=20.0,
        description="λ of the acquisition's slide (1/s): the hand slides at its clamp "
        "(acquire_max_linear_m_s) and slows only near the attempt's goal",
    )
    stuck_after_s: float = Field(
        4.0,
        gt=0.0,
        le=3600.0,
        description="a hold this long (sim s) is reported as stuck: umay run ends with it, "
        "umay status shows what it waits for",
    )
    stall_after_s: float = Field(
        5.0,
        gt=0.0,
        le=3600.0,
        description="servoing this long (sim s) without the image error falling 5 % below its "
        "best is reported as stalled (a local minimum of the law, or a limit it pushes "
        "against): umay run ends with it",
    )


class ActuationConfig(_Strict):
    deadman_timeout_s: float = Field(
        0.2,
        gt=0.0,
        le=5.0,
        description="zero velocity without a fresh valid twist this long (wall s): 6 camera "
        "periods at 30 Hz, and room within the 300 ms stop budget for the stop to reach the "
        "motors on a loaded machine; below sim.command_watchdog_s",
    )
    damping: float = Field(0.02, ge=0.0, le=1.0, description="DLS damping near singularities")
    manipulability_threshold: float = Field(
        0.002, ge=0.0, description="below this the DLS damping ramps in"
    )
    max_joint_acceleration_rad_s2: float = Field(
        10.0, gt=0.0, le=1000.0, description="bound on the change between commands (rad/s²)"
    )


class SimConfig(_Strict):
    physics_hz: float = Field(
        240.0, ge=30.0, le=2000.0, description="physics steps per simulated second"
    )
    renderer: Literal["gl", "tiny"] = Field(
        "gl",
        description="gl: OpenGL through a headless EGL context (a GPU's driver, else Mesa's "
        "llvmpipe on the CPU), exact float32 depth; falls back to tiny, saying why, where no "
        "EGL context can be made. tiny: pybullet's TinyRenderer, the reference it is tested "
        "against",
    )
    command_watchdog_s: float = Field(
        0.3, gt=0.0, le=5.0, description="realtime: motors stop when commands stop this long"
    )
    lockstep_resend_s: float = Field(
        1.0, gt=0.0, description="re-publish a frame whose command has not come back (wall s)"
    )
    realtime_command_wait_s: float = Field(
        0.1,
        ge=0.0,
        le=1.0,
        description="realtime: after a frame, physics runs on but the next render waits this "
        "long at most (wall s) for that frame's joint command; a render holds the interpreter, "
        "so a command arriving during one would be applied only after it (0: render back to "
        "back)",
    )


class RestartPolicy(StrEnum):
    ALWAYS = "always"
    ON_FAILURE = "on-failure"  # restart after a non-zero exit or a signal only
    NEVER = "never"


class SupervisorConfig(_Strict):
    """How ``umay up`` keeps the services alive (as systemd/supervisord would)."""

    restart: dict[Literal["sim", "vision", "controller", "actuation"], RestartPolicy] = Field(
        default_factory=dict, description="per service; unnamed services use default_restart"
    )
    default_restart: RestartPolicy = Field(
        RestartPolicy.ALWAYS,
        description="always, on-failure (after a non-zero exit or a signal) or never",
    )
    backoff_initial_s: float = Field(
        0.1, ge=0.0, le=10.0, description="wait before a restart (s), doubled per recent one"
    )
    backoff_max_s: float = Field(
        5.0, ge=0.0, le=300.0, description="the longest wait before a restart (s)"
    )
    max_restarts: int = Field(5, ge=0, description="in restart_window_s; then give up")
    restart_window_s: float = Field(
        60.0, gt=0.0, description="the window max_restarts counts in (s)"
    )
    stop_grace_s: float = Field(2.0, gt=0.0, le=30.0, description="SIGTERM → SIGKILL")
    hang_timeout_s: float = Field(
        5.0,
        ge=0.0,
        le=300.0,
        description="a service whose event loop is stuck in one step, or that stops answering "
        "status queries, this long is killed (then restarted by its policy); 0: never",
    )
    start_timeout_s: float = Field(
        20.0,
        ge=0.0,
        le=600.0,
        description="a service that has answered no status query this long after it started "
        "is taken as hung (a start that never ends, or a hang before its first answer) and "
        "killed; 0: never",
    )
    launch: Literal["fork", "exec"] = Field(
        "fork",
        description="fork: each service a fork of a process that imported the services once "
        "(deploy/service_process.py); exec: each a fresh `python -m services.NAME`",
    )
    cpu_wakeup_latency_us: int | None = Field(
        None,
        ge=0,
        le=100_000,
        description="while the supervisor runs the services (not in in-process runs, which "
        "have no hops), ask Linux for CPU wake-up latencies at most this long (PM QoS, "
        "/dev/cpu_dma_latency: needs write access); 0: idle CPUs poll instead of halting, so "
        "each hop's wake-up is fast but a core stays busy while idle; None: leave the host's "
        "power management alone",
    )

    def policy(self, service: str) -> RestartPolicy:
        return self.restart.get(service, self.default_restart)  # type: ignore[call-overload]


class EventAction(StrEnum):
    HIDE_TARGET = "hide_target"  # the red marker disappears (for duration_s, or until shown)
    SHOW_TARGET = "show_target"
    OCCLUDE_HAND = "occlude_hand"  # a panel comes between the camera and the hand's marker
    MOVE_TARGET = "move_target"  # the object slides at velocity_m_s for duration_s


MAX_TARGET_SPEED_M_S = 0.2  # how fast a move_target event may slide the object


class Event(_Strict):
    """One entry of the scenario's ``[[events]]`` timeline (simulated time). Only the sim acts
    on events: perception and control learn of them through the camera, as they would."""

    at_s: float = Field(ge=0.0, le=3600.0, description="simulated time it starts (s)")
    action: EventAction = Field(
        description="hide_target (for duration_s, or until a show_target), show_target, "
        "occlude_hand (a panel before the hand's marker for duration_s) or move_target (the "
        "object slides at velocity_m_s for duration_s)"
    )
    duration_s: float | None = Field(
        None, gt=0.0, le=3600.0, description="how long it lasts (simulated s)"
    )
    velocity_m_s: Vec3 | None = Field(None, description="move_target: base frame (m/s)")

    @model_validator(mode="after")
    def _fields_fit_the_action(self) -> Event:
        moving = self.action is EventAction.MOVE_TARGET
        if moving and self.velocity_m_s is None:
            raise ValueError("move_target needs velocity_m_s")
        if not moving and self.velocity_m_s is not None:
            raise ValueError(f"velocity_m_s is only for move_target, not {self.action.value}")
        if moving and float(np.linalg.norm(self.velocity_m_s)) > MAX_TARGET_SPEED_M_S:
            raise ValueError(f"move_target: speed above {MAX_TARGET_SPEED_M_S:g} m/s")
        timed = self.action in (EventAction.MOVE_TARGET, EventAction.OCCLUDE_HAND)
        if timed and self.duration_s is None:
            raise ValueError(f"{self.action.value} needs duration_s")
        if self.action is EventAction.SHOW_TARGET and self.duration_s is not None:
            raise ValueError("show_target takes no duration_s")
        return self

    @property
    def end_s(self) -> float:
        return self.at_s + (self.duration_s or 0.0)


class RunConfig(_Strict):
    clock: ClockMode = Field(
        ClockMode.LOCKSTEP,
        description="lockstep: one camera period per command, deterministic; realtime: "
        "physics at the wall clock's rate, frames dropped when rendering lags",
    )
    timeout_s: float = Field(30.0, gt=0.0, le=3600.0, description="simulated seconds")


DEADMAN_FRAMES = 1.5  # the deadman's time, in camera frames, must exceed this
FRAME_RATE_TOLERANCE = 0.25  # the camera's rate in whole physics steps, this near rgb_hz


class Scenario(_Strict):
    name: str = Field(
        "default",
        description="the scenario's name in results and recordings (letters, digits, _ . -: it "
        "names folders)",
    )
    robot: RobotConfig
    target: TargetConfig
    marker: MarkerConfig = MarkerConfig()
    camera: CameraConfig
    vision: VisionConfig = VisionConfig()
    controller: ControllerConfig = ControllerConfig()
    actuation: ActuationConfig = ActuationConfig()
    sim: SimConfig = SimConfig()
    run: RunConfig = RunConfig()
    supervisor: SupervisorConfig = SupervisorConfig()
    events: list[Event] = Field(
        default_factory=list,
        max_length=100,
        description="a timeline the sim acts on (`[[events]]`, below); a run is not judged "
        "converged before the last event ends",
    )

    @model_validator(mode="after")
    def _object_holds_its_marker(self) -> Scenario:
        if self.object_side_m < self.marker.size_m:
            raise ValueError(
                f"target.object_side_m ({self.object_side_m}) below marker.size_m "
                f"({self.marker.size_m}): the red marker lies on the object's top face"
            )
        return self

    @model_validator(mode="after")
    def _deadman_before_watchdog(self) -> Scenario:
        deadman, watchdog = self.actuation.deadman_timeout_s, self.sim.command_watchdog_s
        if deadman >= watchdog:
            raise ValueError(
                f"actuation.deadman_timeout_s ({deadman}) not below sim.command_watchdog_s "
                f"({watchdog}): the deadman is the first stop, the sim's watchdog the second, "
                "and the stop must have time to reach the motors before the watchdog acts"
            )
        return self

    @field_validator("name")
    @classmethod
    def _a_folder_name(cls, name: str) -> str:
        if not re.fullmatch(r"[A-Za-z0-9_.-]+", name) or set(name) == {"."}:
            raise ValueError(f"{name!r}: letters, digits, _ . - only (it names a folder)")
        return name

    @model_validator(mode="after")
    def _deadman_longer_than_a_frame(self) -> Scenario:
        # In realtime twists come once a camera frame: a deadman as short would stop the arm
        # between any two of them, and each twist would find it stopped and ramp it up from
        # rest again, so the arm never moves. (In lockstep the motors follow each frame's
        # command whatever the deadman sends between frames: tests use that.)
        if self.run.clock is not ClockMode.REALTIME:
            return self
        deadman, frame_s = self.actuation.deadman_timeout_s, self.frame_period_s
        if deadman <= DEADMAN_FRAMES * frame_s:
            raise ValueError(
                f"actuation.deadman_timeout_s ({deadman}) not above {DEADMAN_FRAMES:g} camera "
                f"frames ({DEADMAN_FRAMES * frame_s:.3f} s at camera.rgb_hz "
                f"{self.camera.rgb_hz:g}): in realtime it would stop the arm between two twists"
            )
        return self

    @model_validator(mode="after")
    def _goal_above_the_clearance(self) -> Scenario:
        # The hand box lies under its marker: with the box kept above the object's top face,
        # a goal lower than the box's thickness and the clearance is one the hand never reaches.
        if not self.controller.keep_above_target:
            return self
        lowest = HAND_THICKNESS_M + MARKER_THICKNESS_M + self.controller.hand_clearance_m
        if self.target.approach_height_m < lowest:
            raise ValueError(
                f"target.approach_height_m ({self.target.approach_height_m}) below {lowest:.4f} "
                "m, the hand box's thickness under its marker and controller.hand_clearance_m: "
                "the clearance keeps the hand from its goal (or set "
                "controller.keep_above_target = false)"
            )
        return self

    @model_validator(mode="after")
    def _moves_together_within_the_speed_limit(self) -> Scenario:
        # Moves that overlap add up (services/sim/events.py): their sum has the one's limit.
        moves = [(i, e) for i, e in enumerate(self.events) if e.action is EventAction.MOVE_TARGET]
        for i, started in moves:
            t = started.at_s  # the sum only changes where a move starts or ends
            together = [e for _, e in moves if e.at_s <= t < e.end_s]
            speed = float(np.linalg.norm(np.sum([e.velocity_m_s for e in together], axis=0)))
            if speed > MAX_TARGET_SPEED_M_S:
                raise ValueError(
                    f"events[{i}]: with the moves it overlaps the object slides at {speed:.3f} "
                    f"m/s at {t:g} s, above {MAX_TARGET_SPEED_M_S:g} m/s"
                )
        return self

    @model_validator(mode="after")
    def _events_within_the_run(self) -> Scenario:
        # A run is judged converged only once the last event is over.
        ends = [e.end_s for e in self.events]
        if ends and max(ends) > self.run.timeout_s:
            last = int(np.argmax(ends))
            raise ValueError(
                f"events[{last}] ends at {ends[last]:g} s, after run.timeout_s "
                f"({self.run.timeout_s:g}): a run is judged only once its events are over"
            )
        return self

    @model_validator(mode="after")
    def _frames_near_the_rate_asked(self) -> Scenario:
        # A frame lasts whole physics steps: the rate the camera gets is physics_hz over their
        # number, which for a rate near or above physics_hz is far from the one asked.
        got_hz = 1.0 / self.frame_period_s
        if abs(got_hz - self.camera.rgb_hz) > FRAME_RATE_TOLERANCE * self.camera.rgb_hz:
            raise ValueError(
                f"camera.rgb_hz ({self.camera.rgb_hz:g}) at sim.physics_hz "
                f"({self.sim.physics_hz:g}): a frame lasts whole physics steps, which makes "
                f"{got_hz:.4g} frames/s; choose a rate that divides the physics rate"
            )
        return self

    @model_validator(mode="after")
    def _a_frame_shorter_than_the_slow_down_zone(self) -> Scenario:
        # A joint command is followed for one camera frame (lockstep: whole physics steps), and
        # actuation bounds the speed towards a limit by the angle at the frame's start: a frame
        # crossing the whole slow-down zone at full speed could carry a joint past its limit.
        crossing_s = POSITION_LIMIT_ZONE_RAD / float(np.max(JOINT_VELOCITY_LIMIT_RAD_S))
        if self.frame_period_s >= crossing_s:
            raise ValueError(
                f"camera.rgb_hz ({self.camera.rgb_hz}) at sim.physics_hz "
                f"({self.sim.physics_hz}) makes a camera frame of {self.frame_period_s:.4f} s "
                f"(whole physics steps), not below the {crossing_s:.4f} s a joint takes to cross "
                "its slow-down zone at full speed: a joint could pass its limit within a frame"
            )
        return self

    @property
    def object_side_m(self) -> float:
        """The object's top face side (m): ``target.object_side_m``, else 1.25 markers."""
        side = self.target.object_side_m
        return OBJECT_SIDE_PER_MARKER * self.marker.size_m if side is None else side

    @property
    def frame_period_s(self) -> float:
        """The sim time between two camera frames: the camera period in whole physics steps
        (:func:`substeps_per_frame`), as the sim advances its clock."""
        physics_dt_s = 1.0 / self.sim.physics_hz
        return substeps_per_frame(self.camera.rgb_hz, physics_dt_s) * physics_dt_s

    @property
    def events_end_s(self) -> float:
        """When the last scheduled event is over (0 without events): a run is not judged
        converged before it."""
        return max((e.end_s for e in self.events), default=0.0)


def substeps_per_frame(rgb_hz: float, physics_dt_s: float) -> int:
    """Physics steps in one camera period (at least one)."""
    return max(1, round(1.0 / rgb_hz / physics_dt_s))


class ScenarioError(ValueError):
    """A scenario file that cannot be used; the message names the file, field and reason."""


def format_validation_error(err: ValidationError, source: str) -> str:
    lines = [f"{source}: invalid scenario"]
    for e in err.errors():
        loc = ".".join(str(p) for p in e["loc"]) or "(root)"
        lines.append(f"  {loc}: {e['msg']}")
    return "\n".join(lines)


def merge_overrides(data: dict, overrides: dict) -> dict:
    """``overrides`` merged into ``data`` in place, table by table (nested tables too); a value
    that is not a table replaces what was there."""
    for key, value in overrides.items():
        if isinstance(value, dict) and isinstance(data.get(key), dict):
            merge_overrides(data[key], value)
        else:
            data[key] = value
    return data


def load_scenario(path: str | Path | None = None, overrides: dict | None = None) -> Scenario:
    """Read and validate a scenario TOML file; ``overrides`` (nested tables, as from
    :func:`common.runtime.parse_overrides`) are merged into it first."""
    p = Path(path) if path is not None else DEFAULT_SCENARIO
    try:
        data = tomllib.loads(p.read_text())
    except FileNotFoundError as exc:
        raise ScenarioError(f"{p}: no such scenario file") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{p}: not valid TOML: {exc}") from exc
    except UnicodeDecodeError as exc:
        raise ScenarioError(f"{p}: not a text file (not UTF-8 at byte {exc.start})") from exc
    except OSError as exc:  # a directory, no permission, ...
        raise ScenarioError(f"{p}: cannot read it: {exc.strerror or exc}") from exc
    merge_overrides(data, overrides or {})
    try:
        return Scenario.model_validate(data)
    except ValidationError as exc:
        raise ScenarioError(format_validation_error(exc, str(p))) from exc
