"""The scenario's ``[camera]`` table: the torso-mounted RGB-D camera, its Kinect model
(``[camera.kinect]``) and the controller's calibration error (``[camera.calibration_error]``)."""

from __future__ import annotations

import numpy as np
from pydantic import Field, model_validator

from common.camera import CameraIntrinsics, look_at_rotation
from common.config.base import Strict, Vec3
from common.kinematics import BASE_UP, homogeneous, rot_x, rot_y, rot_z


class KinectConfig(Strict):
    """Scenario table ``[camera.kinect]``; ``enabled = false`` keeps perfect images."""

    enabled: bool = Field(
        False,
        description="the Kinect v1 model on the rendered images: axial depth noise, disparity "
        "quantisation, range limits, edge dropout, lateral noise, exposure and RGB noise "
        "(docs/vision.md); off: perfect images",
    )
    seed: int = Field(0, ge=0, description="noisy runs stay reproducible")
    min_range_m: float = Field(
        0.4,
        ge=0.0,
        description="near mode's floor (the brief's 0.5 m would blank the markers, about "
        "0.45 m away)",
    )
    max_range_m: float = Field(4.0, gt=0.0, description="farther surfaces give no depth (m)")
    edge_threshold_m: float = Field(0.03, gt=0.0, description="a jump this large is an edge")
    edge_dropout_px: int = Field(2, ge=0, le=10, description="invalid band along edges")
    lateral_noise_px: float = Field(
        0.8,
        ge=0.0,
        le=5.0,
        description="spread of the pixel shift each depth is read from (σ, in the depth "
        "image's pixels; clipped)",
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


class CalibrationError(Strict):
    """How far the camera pose the controller assumes is from the true mount: the true pose
    composed with this offset (translation in the base frame, then a rotation about the optical
    frame's own axes). Zero by default: a perfectly calibrated camera."""

    position_m: Vec3 = Field(
        [0.0, 0.0, 0.0], description="added to the optical centre, in the arm base frame (m)"
    )
    rotation_deg: Vec3 = Field(
        [0.0, 0.0, 0.0], description="about the optical x, y, z axes, applied in that order"
    )


class CameraConfig(Strict):
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
