"""The orientation cue: which corner of a marker's square is its corner 0. Pure functions.

A plain square looks the same turned by 90°, so corners labelled by their place in the image
(:func:`services.vision.quad.order_corners`) fold any turn about the optical axis into ±45°.
With ``marker.orientation_cue`` each marker carries a small square of a third colour inside
it, near its physical corner 0 (:data:`common.kinematics.CUE_CENTRE_DIAGONAL_FRACTION` of the
diagonal from it, :data:`common.kinematics.CUE_SIDE_FRACTION` of the side). Its outline stays
a whole square, so segmentation and the corner fit are unchanged; the cue is a hole in the
colour mask, which the depth plane fit (eroded mask) never samples.

Labelling with the cue: the corners are put in the physical order of
:func:`common.kinematics.marker_corners`, which a marker facing the camera shows
counter-clockwise in the image (the reverse of the colour-only order), then rolled so that
corner 0 is the one whose cue point (each corner's 1/4-diagonal point, mapped through the
square's homography) lies in the cue's colour. When no corner, or more than one, shows the
cue (hidden, too small to see), the labelling of the previous frame is carried on by
continuity if the marker was labelled there; otherwise the marker is not usable
(:data:`CUE_HIDDEN`).
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

from common.config import VisionConfig
from common.kinematics import CUE_CENTRE_DIAGONAL_FRACTION, CUE_SIDE_FRACTION
from services.vision.quad import quad_area_px2

FloatArray = NDArray[np.float64]

CUE_HIDDEN = "cue hidden"  # the reason of a marker whose corner 0 cannot be told
# Each corner's cue point is judged on a window of this fraction of the cue's side (a quarter:
# well inside the cue even at a steep view) and at least one pixel...
SAMPLE_FRACTION_OF_CUE = 0.25
# ...which must be mostly cue colour at the cued corner, and nearly free of it at the others.
CUE_PRESENT_FRACTION = 0.5
CUE_ABSENT_FRACTION = 0.2
# The unit square's corners in the physical order (marker_corners: (-,-), (+,-), (+,+), (-,+)).
_UNIT_SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]], np.float32)


def physical_order(clockwise_px: FloatArray) -> FloatArray:
    """Corners in the image's clockwise order (colour-only labelling) → the same start corner,
    then counter-clockwise: the turn of :func:`common.kinematics.marker_corners` on a marker
    whose face is towards the camera."""
    return np.asarray(clockwise_px, dtype=float)[[0, 3, 2, 1]]


def cue_points_px(corners_px: FloatArray) -> FloatArray:
    """(4, 2): where the cue's centre would be if corner i were corner 0, for corners in the
    physical order (through the square's homography: exact in perspective)."""
    homography = cv2.getPerspectiveTransform(_UNIT_SQUARE, np.asarray(corners_px, np.float32))
    f = CUE_CENTRE_DIAGONAL_FRACTION
    unit = np.array([[f, f], [1 - f, f], [1 - f, 1 - f], [f, 1 - f]])  # next to corner i
    mapped = np.column_stack([unit, np.ones(4)]) @ homography.T
    return mapped[:, :2] / mapped[:, 2:]


def cue_mask(rgb: np.ndarray, cfg: VisionConfig) -> np.ndarray:
    """0/255 mask of the cue's colour (HSV ``cfg.cue_hsv``, whatever the markers' mode)."""
    hsv = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2HSV)
    mask = np.zeros(hsv.shape[:2], np.uint8)
    for r in cfg.cue_hsv:
        mask |= cv2.inRange(hsv, np.array(r.lower, np.uint8), np.array(r.upper, np.uint8))
    return mask


def cue_fractions(rgb: np.ndarray, corners_px: FloatArray, cfg: VisionConfig) -> FloatArray:
    """(4,) fraction of cue-coloured pixels in a small window at each corner's cue point
    (corners in the physical order); only the pixels around the square are converted."""
    points = cue_points_px(corners_px)
    side_px = math.sqrt(max(quad_area_px2(corners_px), 1.0))
    half = max(1, round(0.5 * SAMPLE_FRACTION_OF_CUE * CUE_SIDE_FRACTION * side_px))
    h, w = rgb.shape[:2]
    lo = np.clip(np.floor(points.min(axis=0)).astype(int) - half, 0, [w, h])
    hi = np.clip(np.ceil(points.max(axis=0)).astype(int) + half + 1, 0, [w, h])
    fractions = np.zeros(4)
    if np.any(hi <= lo):  # every cue point beyond the image (a fitted marker's): none seen
        return fractions
    crop = cue_mask(rgb[lo[1] : hi[1], lo[0] : hi[0]], cfg)
    for i, (u, v) in enumerate(np.rint(points).astype(int) - lo):
        rows = slice(max(v - half, 0), max(v + half + 1, 0))
        window = crop[rows, max(u - half, 0) : max(u + half + 1, 0)]
        if window.size:
            fractions[i] = np.count_nonzero(window) / window.size
    return fractions


def cued_corner(fractions: FloatArray) -> int | None:
    """The one corner whose cue point shows the cue while the others do not; None when no
    corner does, or more than one does (hidden, too small, or not this cue)."""
    present = np.flatnonzero(fractions >= CUE_PRESENT_FRACTION)
    if len(present) != 1:
        return None
    others = np.delete(fractions, present[0])
    return int(present[0]) if np.all(others <= CUE_ABSENT_FRACTION) else None


def closest_roll(corners_px: FloatArray, previous_px: FloatArray) -> FloatArray:
    """``corners_px`` cyclically shifted to be nearest ``previous_px`` (least sum of squared
    distances): the labelling carried on from the previous frame."""
    shifts = [np.roll(corners_px, -s, axis=0) for s in range(4)]
    costs = [float(np.sum((c - previous_px) ** 2)) for c in shifts]
    return shifts[int(np.argmin(costs))]


def label_corners(
    rgb: np.ndarray,
    clockwise_px: FloatArray,
    previous_px: FloatArray | None,
    cfg: VisionConfig,
) -> FloatArray | None:
    """A marker's corners (clockwise in the image, from :mod:`services.vision.quad`) labelled
    by its cue: physical order, corner 0 the cued one; by continuity with ``previous_px``
    (last frame's labelled corners, None if it was not labelled there) when the cue cannot
    be told; None when neither (the marker is then :data:`CUE_HIDDEN`)."""
    corners = physical_order(clockwise_px)
    cued = cued_corner(cue_fractions(rgb, corners, cfg))
    if cued is not None:
        return np.roll(corners, -cued, axis=0)
    if previous_px is not None:
        return closest_roll(corners, np.asarray(previous_px, dtype=float).reshape(4, 2))
    return None
