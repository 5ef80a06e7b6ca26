"""A partly hidden marker fitted from its edges stays within what the wire lets a usable marker
carry: a square cut by the image border near the camera, fitted right, can have a hidden corner
nearer than 1 cm or far beyond the image. Fitted so, the Features message failed validation
and ended the vision service."""

from __future__ import annotations

import numpy as np

from common.camera import CameraIntrinsics
from common.config import VisionConfig
from common.messages import Header
from services.vision.step import vision_step
from services.vision.tracking import DepthImage, TrackerState

K = CameraIntrinsics.from_fov(640, 480, 57.0)


def a_square_cut_by_the_border_near_the_camera(side_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Colour and exact depth (640×480) of a red square of ``side_m`` tilted close before the
    camera, one corner beyond the image and within a centimetre of the camera's plane."""
    centre = np.array([-0.0501, -0.08, 0.1354])
    u = np.array([-0.8921, 0.1874, -0.4112])
    u /= np.linalg.norm(u)
    v = np.array([0.3133, -0.3992, -0.8617])
    v -= (v @ u) * u
    v /= np.linalg.norm(v)
    rows, cols = np.mgrid[0:480, 0:640]
    rays = np.stack(
        [(cols - K.cx_px) / K.fx_px, (rows - K.cy_px) / K.fy_px, np.ones(cols.shape)], -1
    )
    normal = np.cross(u, v)
    z = (normal @ centre) / (rays @ normal)
    on_plane = rays * z[..., None] - centre
    red = (z > 0) & (np.abs(on_plane @ u) <= side_m / 2) & (np.abs(on_plane @ v) <= side_m / 2)
    rgb = np.full((480, 640, 3), 128, np.uint8)
    rgb[red] = (217, 20, 20)
    return rgb, np.where(red, z, 0.9).astype(np.float32)


def test_a_fit_with_a_corner_too_near_is_not_used_and_the_message_validates() -> None:
    side_m = 0.2
    rgb, depth = a_square_cut_by_the_border_near_the_camera(side_m)
    image = DepthImage(depth, K, 0.0)
    step = vision_step(rgb, K, image, VisionConfig(), side_m, TrackerState(), 0.0)
    target = step.measured["target"]
    assert target.state == "partial" and not target.fitted  # seen in part, not acted on
    features = step.features(Header(seq=0, sim_time_s=0.0, send_time_s=0.0), K)  # validates
    assert not features.target.usable
