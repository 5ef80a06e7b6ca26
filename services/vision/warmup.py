"""A frame before the camera's first. Pure.

Vision's first step in a process costs several times a later one (its code paths and OpenCV's
and numpy's first use; docs/performance.md, a run's first frames), and that first step answers
the camera's first frame, delaying the arm's first command. The node therefore measures
one synthetic frame of the scenario's sizes before it subscribes: the hand's green and the
target's red square, both wholly seen, on grey, with a flat depth image. What it measures is
discarded; the tracker the node starts with is a fresh one.
"""

from __future__ import annotations

import cv2
import numpy as np

from common.camera import CameraIntrinsics
from common.config import VisionConfig
from services.vision.step import VisionStep, depth_image, vision_step
from services.vision.tracking import TrackerState

WARMUP_DEPTH_M = 0.6  # the synthetic squares lie on a plane facing the camera this far away
BACKGROUND_RGB = (110, 110, 110)


def synthetic_frame(
    k: CameraIntrinsics,
    depth_k: CameraIntrinsics,
    config: VisionConfig,
    marker_size_m: float,
) -> tuple[np.ndarray, np.ndarray]:
    """A colour image with the green square left of the centre and the red one right of it,
    each ``marker_size_m`` wide at :data:`WARMUP_DEPTH_M`; the depth image of that plane."""
    rgb = np.empty((k.height_px, k.width_px, 3), np.uint8)
    rgb[:] = BACKGROUND_RGB
    half_px = 0.5 * marker_size_m * k.fx_px / WARMUP_DEPTH_M
    for centre_x, colour in (
        (k.width_px / 3, config.green_rgb),
        (2 * k.width_px / 3, config.red_rgb),
    ):
        x0, x1 = round(centre_x - half_px), round(centre_x + half_px)
        y0, y1 = round(k.height_px / 2 - half_px), round(k.height_px / 2 + half_px)
        cv2.rectangle(rgb, (x0, y0), (x1, y1), tuple(int(c) for c in colour), thickness=-1)
    depth_m = np.full((depth_k.height_px, depth_k.width_px), WARMUP_DEPTH_M, np.float32)
    return rgb, depth_m


def warm_up(
    k: CameraIntrinsics,
    depth_k: CameraIntrinsics,
    config: VisionConfig,
    marker_size_m: float,
    orientation_cue: bool = False,
) -> VisionStep:
    """One vision step on :func:`synthetic_frame` from a fresh tracker (its result, for tests:
    the node discards it)."""
    rgb, depth_m = synthetic_frame(k, depth_k, config, marker_size_m)
    depth = depth_image(depth_m, depth_k, 0.0, 0.0)
    return vision_step(rgb, k, depth, config, marker_size_m, TrackerState(), 0.0, orientation_cue)
