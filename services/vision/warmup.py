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
from common.kinematics import CUE_CENTRE_DIAGONAL_FRACTION, CUE_SIDE_FRACTION
from services.vision.step import VisionStep, depth_image, vision_step
from services.vision.tracking import TrackerState

WARMUP_DEPTH_M = 0.6  # the synthetic squares lie on a plane facing the camera this far away
BACKGROUND_RGB = (110, 110, 110)


def synthetic_frame(
    k: CameraIntrinsics,
    depth_k: CameraIntrinsics,
    config: VisionConfig,
    marker_size_m: float,
    orientation_cue: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """A colour image with the green square left of the centre and the red one right of it,
    each ``marker_size_m`` wide at :data:`WARMUP_DEPTH_M` (with ``orientation_cue``, each with
    its cue near one corner, as the markers carry it); the depth image of that plane."""
    rgb = np.empty((k.height_px, k.width_px, 3), np.uint8)
    rgb[:] = BACKGROUND_RGB
    side_px = marker_size_m * k.fx_px / WARMUP_DEPTH_M
    top = k.height_px / 2 - side_px / 2
    squares = ((k.width_px / 3, config.green_rgb), (2 * k.width_px / 3, config.red_rgb))
    for centre_x, colour in squares:
        left = centre_x - side_px / 2
        _fill_square(rgb, left, top, side_px, tuple(int(c) for c in colour))
        if orientation_cue:
            cue_side = CUE_SIDE_FRACTION * side_px
            offset = CUE_CENTRE_DIAGONAL_FRACTION * side_px - cue_side / 2  # along the diagonal
            _fill_square(rgb, left + offset, top + offset, cue_side, cue_rgb(config))
    depth_m = np.full((depth_k.height_px, depth_k.width_px), WARMUP_DEPTH_M, np.float32)
    return rgb, depth_m


def cue_rgb(config: VisionConfig) -> tuple[int, int, int]:
    """The middle of the cue's first HSV range, in RGB."""
    hsv_range = config.cue_hsv[0]
    middle = [(lo + hi) // 2 for lo, hi in zip(hsv_range.lower, hsv_range.upper, strict=True)]
    rgb = cv2.cvtColor(np.array([[middle]], np.uint8), cv2.COLOR_HSV2RGB)[0, 0]
    return int(rgb[0]), int(rgb[1]), int(rgb[2])


def _fill_square(
    rgb: np.ndarray, left: float, top: float, side: float, colour: tuple[int, ...]
) -> None:
    corner0 = (round(left), round(top))
    corner2 = (round(left + side), round(top + side))
    cv2.rectangle(rgb, corner0, corner2, colour, thickness=-1)


def warm_up(
    k: CameraIntrinsics,
    depth_k: CameraIntrinsics,
    config: VisionConfig,
    marker_size_m: float,
    orientation_cue: bool = False,
) -> VisionStep:
    """One vision step on :func:`synthetic_frame` from a fresh tracker (its result, for tests:
    the node discards it)."""
    rgb, depth_m = synthetic_frame(k, depth_k, config, marker_size_m, orientation_cue)
    depth = depth_image(depth_m, depth_k, 0.0, 0.0)
    return vision_step(rgb, k, depth, config, marker_size_m, TrackerState(), 0.0, orientation_cue)
