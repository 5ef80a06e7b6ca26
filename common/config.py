"""Scenario configuration: one TOML file, validated by pydantic, read by every service.

Each service takes its own table (``[camera]``, ``[vision]``, ``[controller]``, ...) from the
same scenario file, so one file describes one experiment. Every model forbids unknown fields,
so a typo is reported with its path instead of being silently ignored.
"""

from __future__ import annotations

import math
import tomllib
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from common.camera import CameraIntrinsics, look_at_rotation
from common.kinematics import BASE_UP, homogeneous

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


class RobotConfig(_Strict):
    q0: Joints6 = Field(description="initial joint angles (rad), joint_1..joint_6")


class TargetConfig(_Strict):
    position: Vec3 = Field(description="red marker centre in the arm base frame (m)")
    yaw: float = Field(0.0, ge=-math.pi, le=math.pi, description="about the vertical (rad)")
    approach_height_m: float = Field(
        0.03,
        ge=0.0,
        le=0.2,
        description="the hand's marker stops this far above the red one, along its normal (m)",
    )


class MarkerConfig(_Strict):
    size_m: float = Field(0.06, gt=0.01, le=0.2, description="side of both square markers (m)")


class KinectConfig(_Strict):
    """Scenario table ``[camera.kinect]``; ``enabled = false`` keeps perfect images."""

    enabled: bool = False
    seed: int = Field(0, ge=0, description="noisy runs stay reproducible")
    min_range_m: float = Field(0.4, ge=0.0, description="near mode; 0.5 m in default mode")
    max_range_m: float = Field(4.0, gt=0.0)
    edge_threshold_m: float = Field(0.03, gt=0.0, description="a jump this large is an edge")
    edge_dropout_px: int = Field(2, ge=0, le=10, description="invalid band along edges")
    lateral_noise_px: float = Field(0.8, ge=0.0, le=5.0)
    quantise: bool = True
    rgb_noise_sigma: float = Field(2.0, ge=0.0, le=50.0, description="per channel, 0-255 units")
    brightness: float = Field(1.0, gt=0.0, le=4.0, description="exposure scale")
    colour_temperature: float = Field(
        0.0, ge=-1.0, le=1.0, description="-1 warm (red up, blue down) … +1 cool"
    )


class CameraConfig(_Strict):
    width_px: int = Field(640, ge=64, le=1920)
    height_px: int = Field(480, ge=48, le=1080)
    hfov_deg: float = Field(57.0, gt=10.0, lt=120.0)
    rate_hz: float = Field(30.0, gt=0.0, le=120.0)
    position: Vec3 = Field(description="optical centre in the arm base frame (m)")
    look_at: Vec3 = Field(description="point on the optical axis in the arm base frame (m)")
    near_m: float = Field(0.05, gt=0.0)
    far_m: float = Field(5.0, gt=0.0)
    kinect: KinectConfig = KinectConfig()

    def intrinsics(self) -> CameraIntrinsics:
        return CameraIntrinsics.from_fov(self.width_px, self.height_px, self.hfov_deg)

    def pose(self) -> np.ndarray:
        """4×4 pose of the optical frame in the base frame (image up as close to up as it gets).

        The sim renders from it; the controller and the pre-launch check use it as the camera
        calibration (the mount the URDF and scenario describe)."""
        rot = look_at_rotation(np.array(self.position), np.array(self.look_at), BASE_UP)
        return homogeneous(rot, np.array(self.position, dtype=float))


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


class VisionConfig(_Strict):
    segmentation: Literal["hsv", "rgb"] = "hsv"
    red_hsv: list[HsvRange] = Field(
        default_factory=lambda: [
            HsvRange(lower=[0, 120, 60], upper=[8, 255, 255]),
            HsvRange(lower=[172, 120, 60], upper=[179, 255, 255]),
        ]
    )
    green_hsv: list[HsvRange] = Field(
        default_factory=lambda: [HsvRange(lower=[45, 120, 60], upper=[75, 255, 255])]
    )
    # RGB mode (the thesis's first method): a reference colour and a per-channel tolerance.
    red_rgb: Annotated[list[int], Field(min_length=3, max_length=3)] = [200, 30, 30]
    green_rgb: Annotated[list[int], Field(min_length=3, max_length=3)] = [30, 200, 30]
    rgb_tolerance: int = Field(60, ge=1, le=255)
    min_area_px: int = Field(60, ge=4, description="smaller blobs are rejected")


class ControllerConfig(_Strict):
    mode: JacobianMode = JacobianMode.DYNAMIC
    gain: float = Field(1.0, gt=0.0, le=20.0, description="λ of e' = -λe (1/s)")
    converged_px: float = Field(0.25, gt=0.0, description="pixel RMS below which it converged")
    converged_frames: int = Field(5, ge=1, description="consecutive frames below the threshold")
    max_linear_m_s: float = Field(0.15, gt=0.0, description="twist clamp, linear (m/s)")
    max_angular_rad_s: float = Field(1.0, gt=0.0, description="twist clamp, angular (rad/s)")


class ActuationConfig(_Strict):
    deadman_timeout_s: float = Field(0.25, gt=0.0, le=5.0)
    damping: float = Field(0.02, ge=0.0, le=1.0, description="DLS damping near singularities")
    manipulability_threshold: float = Field(
        0.002, ge=0.0, description="below this the DLS damping ramps in"
    )
    max_joint_acceleration_rad_s2: float = Field(
        10.0, gt=0.0, le=1000.0, description="bound on the change between commands (rad/s²)"
    )


class SimConfig(_Strict):
    physics_hz: float = Field(240.0, ge=30.0, le=2000.0)
    command_watchdog_s: float = Field(
        0.3, gt=0.0, le=5.0, description="realtime: motors stop when commands stop this long"
    )
    lockstep_resend_s: float = Field(
        1.0, gt=0.0, description="re-publish a frame whose command has not come back (wall s)"
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
    default_restart: RestartPolicy = RestartPolicy.ALWAYS
    backoff_initial_s: float = Field(0.1, ge=0.0, le=10.0)
    backoff_max_s: float = Field(5.0, ge=0.0, le=300.0)
    max_restarts: int = Field(5, ge=0, description="in restart_window_s; then give up")
    restart_window_s: float = Field(60.0, gt=0.0)
    stop_grace_s: float = Field(2.0, gt=0.0, le=30.0, description="SIGTERM → SIGKILL")

    def policy(self, service: str) -> RestartPolicy:
        return self.restart.get(service, self.default_restart)  # type: ignore[call-overload]


class RunConfig(_Strict):
    clock: ClockMode = ClockMode.LOCKSTEP
    timeout_s: float = Field(30.0, gt=0.0, le=3600.0, description="simulated seconds")


class Scenario(_Strict):
    name: str = "default"
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


class ScenarioError(ValueError):
    """A scenario file that cannot be used; the message names the file, field and reason."""


def format_validation_error(err: ValidationError, source: str) -> str:
    lines = [f"{source}: invalid scenario"]
    for e in err.errors():
        loc = ".".join(str(p) for p in e["loc"]) or "(root)"
        lines.append(f"  {loc}: {e['msg']}")
    return "\n".join(lines)


def load_scenario(path: str | Path | None = None, overrides: dict | None = None) -> Scenario:
    """Read and validate a scenario TOML file; ``overrides`` are merged per table first."""
    p = Path(path) if path is not None else DEFAULT_SCENARIO
    try:
        data = tomllib.loads(p.read_text())
    except FileNotFoundError as exc:
        raise ScenarioError(f"{p}: no such scenario file") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{p}: not valid TOML: {exc}") from exc
    for table, values in (overrides or {}).items():
        data.setdefault(table, {}).update(values)
    try:
        return Scenario.model_validate(data)
    except ValidationError as exc:
        raise ScenarioError(format_validation_error(exc, str(p))) from exc
