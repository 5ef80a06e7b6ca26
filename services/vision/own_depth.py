"""A partly hidden marker's plane and first guess of its pose from the frame alone. Pure.

:mod:`services.vision.partial` fits a square of known size in a known plane to the edges of
its blob that are really its own. The target's plane usually comes from its last whole view;
but a target hidden in part from the very first frame (the robot's forearm over it) has no
such view, and the hand moves, so a remembered plane is never its own. Both are then taken
from the frame itself:

- the plane, from the depth of the visible blob, eroded away from its outline (where depth
  jumps to what is in front or behind), fitted as a whole view's is
  (:func:`services.vision.depth.fit_inverse_depth_plane`);
- the square's first pose, from the blob's true edges on that plane: their directions give
  its turn (a square's sides repeat every quarter turn), and each pair of opposite sides its
  centre, from the side that is really seen when the other one is hidden.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from common.camera import CameraIntrinsics, pixel_to_normalized
from common.kinematics import cross
from services.vision.depth import (
    DEPTH_ERODE_FRACTION,
    DEPTH_ERODE_MIN_PX,
    DEPTH_MIN_PLANE_PIXELS,
    FloatArray,
    PlaneFit,
    fit_inverse_depth_plane,
    grid_step,
    registered_mask,
    to_depth_pixels,
)
from services.vision.partial import SquareOnPlane
from services.vision.segmentation import Roi, binary_u8, mask_bounds

TANGENT_STEP_PX = 3  # an edge's direction: from the outline point this far behind to ahead
# The edge directions must agree (mean resultant length of their quarter-turn-folded angles):
# less and the blob shows no square's sides to turn it by.
MIN_DIRECTION_AGREEMENT = 0.5
SIDE_BAND = 0.1  # of the marker's size: outline points this close to an extreme are that side


def blob_plane(
    mask: np.ndarray,
    depth_m: np.ndarray,
    k: CameraIntrinsics,
    k_depth: CameraIntrinsics,
    region: Roi | None = None,
) -> PlaneFit | None:
    """The plane of a marker from the depth of its visible blob (``mask``, 0/255 at the
    colour resolution ``k``; ``depth_m`` registered to it at ``k_depth``): the blob eroded by
    as much as a whole view's depth samples are (a tenth of its side, at least 2 depth
    pixels), so that neither its outline nor what borders it counts. None with too few
    samples left. ``region``: where ``mask`` can be non-zero (None: anywhere)."""
    binary = binary_u8(mask)
    found = mask_bounds(binary, 0, region)  # its non-zero pixels' box
    if found is None:
        return None
    top, bottom, left, right = found
    corners = np.array([[left, top], [right, bottom]], dtype=float)
    box = corners if k_depth == k else to_depth_pixels(corners, k, k_depth)
    h, w = depth_m.shape
    r0, r1 = max(math.floor(box[0, 1]) - 1, 0), min(math.ceil(box[1, 1]) + 1, h)
    c0, c1 = max(math.floor(box[0, 0]) - 1, 0), min(math.ceil(box[1, 0]) + 1, w)
    if r1 <= r0 or c1 <= c0:
        return None
    small = registered_mask(mask, depth_m.shape, (r0, r1, c0, c1))
    side_px = math.sqrt(max(cv2.countNonZero(small), 1))
    radius_px = max(DEPTH_ERODE_MIN_PX, round(DEPTH_ERODE_FRACTION * side_px))
    inner = cv2.erode(
        small,
        cv2.getStructuringElement(cv2.MORPH_RECT, (2 * radius_px + 1, 2 * radius_px + 1)),
        borderType=cv2.BORDER_CONSTANT,
        borderValue=0,
    )
    step = grid_step(cv2.countNonZero(inner))
    while True:
        z = depth_m[r0:r1:step, c0:c1:step]
        vv, uu = np.nonzero((inner[::step, ::step] > 0) & (z > 0) & (z < np.inf))
        if step == 1 or len(vv) >= DEPTH_MIN_PLANE_PIXELS:
            break
        step = 1
    if len(vv) < DEPTH_MIN_PLANE_PIXELS:
        return None
    uv = np.column_stack([uu * step + c0, vv * step + r0]).astype(float)
    return fit_inverse_depth_plane(pixel_to_normalized(uv, k_depth), z[vv, uu].astype(float))


def on_plane(plane: PlaneFit, points_px: FloatArray, k: CameraIntrinsics) -> FloatArray | None:
    """The points of ``plane`` seen at ``points_px`` (N, 3, optical frame, m); None if a ray
    misses it (behind the camera)."""
    xy = pixel_to_normalized(np.asarray(points_px, dtype=float), k)
    depths = plane.depths_m(xy)
    if not np.all((depths > 0) & np.isfinite(depths)):
        return None
    return np.column_stack([xy, np.ones(len(xy))]) * depths[:, None]


def _centre_along(x_m: FloatArray, true_edge: np.ndarray, size_m: float) -> float:
    """Where the square's centre lies along one of its axes, from its outline's coordinates
    ``x_m`` along it: between its two extreme sides when both are true edges (or neither),
    else half a side in from the one that is."""
    lo, hi = float(x_m.min()), float(x_m.max())
    band = SIDE_BAND * size_m
    lo_true = bool(np.mean(true_edge[x_m < lo + band]) > 0.5)
    hi_true = bool(np.mean(true_edge[x_m > hi - band]) > 0.5)
    if lo_true and not hi_true:
        return lo + size_m / 2.0
    if hi_true and not lo_true:
        return hi - size_m / 2.0
    return (lo + hi) / 2.0


def square_from_outline(
    plane: PlaneFit,
    outline_px: FloatArray,
    true_edge: np.ndarray,
    k: CameraIntrinsics,
    size_m: float,
) -> SquareOnPlane | None:
    """A first pose of a square of ``size_m`` on ``plane`` whose blob has the outline
    ``outline_px`` (N, 2, in order along it) of which ``true_edge`` (N,) are its own edges:
    turned as those edges run, and centred on the sides they show. None when the edges show
    no common direction (or a ray misses the plane)."""
    n = len(outline_px)
    points = on_plane(plane, outline_px, k) if n > 2 * TANGENT_STEP_PX else None
    if points is None:
        return None
    normal = plane.coefficients / np.linalg.norm(plane.coefficients)  # the plane: c·P = 1
    e1 = np.array([1.0, 0.0, 0.0]) - normal[0] * normal
    e1 /= np.linalg.norm(e1)
    e2 = cross(normal, e1)
    origin = points.mean(axis=0)
    a, b = (points - origin) @ e1, (points - origin) @ e2
    ahead, behind = np.roll(np.arange(n), -TANGENT_STEP_PX), np.roll(np.arange(n), TANGENT_STEP_PX)
    edge = true_edge & true_edge[ahead] & true_edge[behind]
    da, db = a[ahead] - a[behind], b[ahead] - b[behind]
    # A side's direction, folded by a quarter turn (both axes and both senses are a side):
    # the mean of 4θ, weighted by the step's length.
    weight = np.hypot(da, db) * edge
    folded = np.sum(weight * np.exp(4j * np.arctan2(db, da)))
    if np.sum(weight) <= 0 or abs(folded) < MIN_DIRECTION_AGREEMENT * np.sum(weight):
        return None
    turn = float(np.angle(folded)) / 4.0
    axis_u = math.cos(turn) * e1 + math.sin(turn) * e2
    axis_v = cross(normal, axis_u)
    offset = points - origin
    cu = _centre_along(offset @ axis_u, true_edge, size_m)
    cv = _centre_along(offset @ axis_v, true_edge, size_m)
    return SquareOnPlane(origin + cu * axis_u + cv * axis_v, axis_u, axis_v, size_m)
