"""Pinhole camera model (thesis eq. 5.22-5.28) and camera-pose helpers.

Frames
------
- Optical frame: z along the optical axis (forward), x to the image right, y to the image down.
  Pixel ``(u, v)``: ``u`` column (right), ``v`` row (down); pixel centres sit at integer
  coordinates, as in OpenCV, so the centre of a W×H image is ``((W-1)/2, (H-1)/2)``.
- ``u = fx·x + cx``, ``v = fy·y + cy`` with ``x = X/Z``, ``y = Y/Z`` (normalized coordinates).
- Depth ``Z`` is the distance along the optical axis (m), what a Kinect depth image stores.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

FloatArray = NDArray[np.float64]


class CameraIntrinsics(BaseModel):
    """Pinhole intrinsics in pixels. Square pixels unless ``fy_px`` differs from ``fx_px``."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    width_px: int = Field(gt=0, le=4096)
    height_px: int = Field(gt=0, le=4096)
    fx_px: float = Field(gt=0, le=1e5)
    fy_px: float = Field(gt=0, le=1e5)
    cx_px: float = Field(ge=-1e5, le=1e5)
    cy_px: float = Field(ge=-1e5, le=1e5)

    @classmethod
    def from_fov(cls, width_px: int, height_px: int, hfov_deg: float) -> CameraIntrinsics:
        """Square-pixel camera with the principal point at the image centre."""
        f = (width_px / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        return cls(
            width_px=width_px,
            height_px=height_px,
            fx_px=f,
            fy_px=f,
            cx_px=(width_px - 1) / 2.0,
            cy_px=(height_px - 1) / 2.0,
        )

    @property
    def vfov_deg(self) -> float:
        return math.degrees(2.0 * math.atan((self.height_px / 2.0) / self.fy_px))

    def matrix(self) -> FloatArray:
        """3×3 camera matrix K."""
        return np.array(
            [[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]]
        )


def project(points_cam_m: FloatArray, k: CameraIntrinsics) -> FloatArray:
    """Project N×3 points in the optical frame to N×2 pixel coordinates."""
    p = np.atleast_2d(np.asarray(points_cam_m, dtype=float))
    x = p[:, 0] / p[:, 2]
    y = p[:, 1] / p[:, 2]
    uv = np.empty((len(p), 2))  # filled in place: np.column_stack's overhead, not its values
    uv[:, 0] = k.fx_px * x + k.cx_px
    uv[:, 1] = k.fy_px * y + k.cy_px
    return uv


def pixel_to_normalized(uv_px: FloatArray, k: CameraIntrinsics) -> FloatArray:
    """N×2 pixels to N×2 normalized coordinates ``(x, y) = (X/Z, Y/Z)``."""
    uv = np.atleast_2d(np.asarray(uv_px, dtype=float))
    xy = np.empty((len(uv), 2))
    xy[:, 0] = (uv[:, 0] - k.cx_px) / k.fx_px
    xy[:, 1] = (uv[:, 1] - k.cy_px) / k.fy_px
    return xy


def back_project(uv_px: FloatArray, depth_m: FloatArray, k: CameraIntrinsics) -> FloatArray:
    """N pixels with depths Z (m) to N×3 points in the optical frame."""
    xy = pixel_to_normalized(uv_px, k)
    z = np.asarray(depth_m, dtype=float).reshape(-1)
    return np.column_stack([xy[:, 0] * z, xy[:, 1] * z, z])


def look_at_rotation(eye_m: FloatArray, target_m: FloatArray, up: FloatArray) -> FloatArray:
    """Rotation (columns = optical x, y, z axes in the parent frame) of a camera at ``eye``
    looking at ``target``, with image-up as close as possible to ``up``."""
    z = np.asarray(target_m, dtype=float) - np.asarray(eye_m, dtype=float)
    z /= np.linalg.norm(z)
    x = np.cross(-np.asarray(up, dtype=float), z)  # image right = down × forward
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.column_stack([x, y, z])
