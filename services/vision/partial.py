"""A partly hidden marker from what is left of it. Pure functions.

When the hand covers part of the target, the corners of the red blob are no longer the
square's corners. But the square's size is known and so is its plane (from the last view of
it with depth; an object sliding on the table keeps it): the square is moved within its plane
(two translations and a turn about its normal) until its sides run along the blob's edges
that are really the marker's, i.e. those not bordering something in front of it. Two adjacent
sides fix the pose; the corners then follow, hidden ones included.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from common.camera import CameraIntrinsics, project
from services.vision.features import FloatArray

EDGE_CLEARANCE_PX = 3  # a blob edge point this close to an occluder may be the occluder's edge
CORNER_CLEARANCE_PX = 3.0  # edge points this close to a corner are not fitted (rounded corners)
MIN_POINTS = 12
MAX_RMS_PX = 0.8  # the fitted sides must run along the edges this well
# The visible edges must pin the pose down: 1-σ of the fitted slide and turn at most these
# (from the residuals and the fit's Jacobian). Two opposite sides alone leave the slide along
# them free; a few points of a third side fix it.
MAX_SLIDE_SIGMA_M = 0.001
MAX_TURN_SIGMA_RAD = math.radians(1.0)
MAX_TURN_RAD = math.radians(20.0)  # from the remembered pose: more is not this square
MAX_STRAY_FRACTION = 0.03  # of the blob's pixels outside the fitted square
ITERATIONS = 8
STEP_M = 1e-4  # finite-difference step of the Gauss-Newton Jacobian
STEP_RAD = 1e-3


@dataclass(frozen=True)
class SquareOnPlane:
    """A square marker lying on a known plane (camera frame, metres): its centre and two unit
    in-plane axes along its sides (their cross product is its normal)."""

    centre_m: FloatArray
    axis_u: FloatArray
    axis_v: FloatArray
    size_m: float

    @classmethod
    def from_corners(cls, corners_m: FloatArray, size_m: float) -> SquareOnPlane:
        """From 4 corners (consecutive, any direction), re-orthonormalised."""
        c = np.asarray(corners_m, dtype=float)
        u = c[1] - c[0] + c[2] - c[3]
        u /= np.linalg.norm(u)
        v = c[3] - c[0] + c[2] - c[1]
        v -= (v @ u) * u
        v /= np.linalg.norm(v)
        return cls(c.mean(axis=0), u, v, size_m)

    def moved(self, du_m: float, dv_m: float, turn_rad: float) -> SquareOnPlane:
        """Slid by (du, dv) along its axes and turned about its normal."""
        c, s = math.cos(turn_rad), math.sin(turn_rad)
        u = c * self.axis_u + s * self.axis_v
        v = -s * self.axis_u + c * self.axis_v
        centre = self.centre_m + du_m * self.axis_u + dv_m * self.axis_v
        return SquareOnPlane(centre, u, v, self.size_m)

    def corners_m(self) -> FloatArray:
        h = self.size_m / 2.0
        signs = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
        return self.centre_m + h * (signs[:, :1] * self.axis_u + signs[:, 1:] * self.axis_v)


def true_edge_points(
    mask: np.ndarray, occluder: np.ndarray, offset_px: tuple[int, int] = (0, 0)
) -> FloatArray:
    """Outline points (u, v) of the largest blob of ``mask`` that border no ``occluder`` pixel
    (0/1 or 0/255 arrays of the same size; ``offset_px`` = (column, row) of the crop in the
    image), nor the crop's border.

    The outline pixels sit half a pixel inside the true edge, on average: the caller's line
    fit is against the square's sides, which agree to well under a pixel either way."""
    contours, _ = cv2.findContours(
        (mask > 0).astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE
    )
    if not contours:
        return np.zeros((0, 2))
    points = max(contours, key=cv2.contourArea).reshape(-1, 2)
    size = 2 * EDGE_CLEARANCE_PX + 1
    near_occluder = cv2.dilate((occluder > 0).astype(np.uint8), np.ones((size, size), np.uint8))
    h, w = mask.shape
    keep = near_occluder[points[:, 1], points[:, 0]] == 0
    keep &= (
        (points[:, 0] > 0) & (points[:, 1] > 0) & (points[:, 0] < w - 1) & (points[:, 1] < h - 1)
    )
    return points[keep].astype(float) + np.asarray(offset_px, dtype=float)


@dataclass(frozen=True)
class _Sides:
    """The four side lines of a projected square, ``normals[k]·p = offsets[k]`` (unit normals;
    the offsets already moved by where outline pixels sit, half a lattice step inside the true
    edge, towards the centre), with each side's start corner, direction and length (px)."""

    normals: FloatArray  # (4, 2)
    offsets: FloatArray  # (4,)
    starts: FloatArray  # (4, 2)
    directions: FloatArray  # (4, 2), start → end
    lengths: FloatArray  # (4,)


def _sides(corners_px: FloatArray) -> _Sides:
    starts = corners_px
    directions = corners_px[[1, 2, 3, 0]] - starts
    lengths = np.sqrt(np.sum(directions**2, axis=1))
    normals = np.stack([-directions[:, 1], directions[:, 0]], axis=1) / lengths[:, None]
    along_normal = np.sum(normals * starts, axis=1)
    towards_centre = np.sign(normals @ corners_px.mean(axis=0) - along_normal)
    inset = towards_centre * 0.5 * np.max(np.abs(normals), axis=1)
    return _Sides(normals, along_normal + inset, starts, directions, lengths)


def _assign(sides: _Sides, points_px: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Each point's residual against the side it lies along (the nearest side whose extent it
    falls in), and that side's index; -1 (residual 0) for points near a corner, left out
    (corners are rounded)."""
    dist = points_px @ sides.normals.T - sides.offsets  # (N, 4)
    t = (points_px @ sides.directions.T - np.sum(sides.starts * sides.directions, axis=1)) / (
        sides.lengths**2
    )
    within = (t > -0.25) & (t < 1.25)  # a side's neighbourhood, corners included
    side = np.argmin(np.where(within, np.abs(dist), np.inf), axis=1)
    rows = np.arange(len(points_px))
    margin = CORNER_CLEARANCE_PX / sides.lengths[side]
    t_side = t[rows, side]
    keep = within[rows, side] & (t_side > margin) & (t_side < 1.0 - margin)
    return np.where(keep, dist[rows, side], 0.0), np.where(keep, side, -1)


@dataclass(frozen=True)
class SquareFit:
    square: SquareOnPlane
    corners_px: FloatArray


def slid_to(square: SquareOnPlane, uv_px: FloatArray, k: CameraIntrinsics) -> SquareOnPlane:
    """``square`` slid in its plane so that its centre is seen at pixel ``uv_px``."""
    ray = np.array([(uv_px[0] - k.cx_px) / k.fx_px, (uv_px[1] - k.cy_px) / k.fy_px, 1.0])
    normal = np.cross(square.axis_u, square.axis_v)
    depth = float(normal @ square.centre_m) / float(normal @ ray)
    offset = depth * ray - square.centre_m
    return square.moved(float(offset @ square.axis_u), float(offset @ square.axis_v), 0.0)


def fit_square_to_blob(
    square: SquareOnPlane,
    edge_points_px: FloatArray,
    blob_centre_px: FloatArray,
    k: CameraIntrinsics,
) -> SquareFit | None:
    """:func:`fit_square` from the remembered pose, else from that pose slid under the blob's
    centre (the object may have moved while hidden)."""
    return fit_square(square, edge_points_px, k) or fit_square(
        slid_to(square, blob_centre_px, k), edge_points_px, k
    )


def fit_square(
    square: SquareOnPlane, edge_points_px: FloatArray, k: CameraIntrinsics
) -> SquareFit | None:
    """Slide and turn ``square`` in its plane until its projected sides run along the edge
    points (Gauss-Newton on the three in-plane parameters from the given pose). None unless
    the fit is tight, the edges pin the pose down (its 1-σ within :data:`MAX_SLIDE_SIGMA_M` and
    :data:`MAX_TURN_SIGMA_RAD`) and it turned little."""
    if len(edge_points_px) < MIN_POINTS:
        return None
    params = np.zeros(3)
    steps = np.array([STEP_M, STEP_M, STEP_RAD])

    def sides_at(p: FloatArray) -> _Sides:
        return _sides(project(square.moved(*p).corners_m(), k))

    def jacobian(p: FloatArray, sides: _Sides, side: FloatArray) -> FloatArray:
        """d(residual)/d(params) of the used points: the lines differentiated numerically
        (three projections of four corners), the points' residuals follow linearly."""
        used = side >= 0
        points, k_side = edge_points_px[used], side[used]
        jac = np.empty((len(points), 3))
        for j in range(3):
            bumped = p.copy()
            bumped[j] += steps[j]
            moved = sides_at(bumped)
            d_normals = (moved.normals - sides.normals) / steps[j]
            d_offsets = (moved.offsets - sides.offsets) / steps[j]
            jac[:, j] = np.sum(points * d_normals[k_side], axis=1) - d_offsets[k_side]
        return jac

    for _ in range(ITERATIONS):
        sides = sides_at(params)
        r, side = _assign(sides, edge_points_px)
        if np.count_nonzero(side >= 0) < MIN_POINTS:
            return None
        delta, *_ = np.linalg.lstsq(jacobian(params, sides, side), -r[side >= 0], rcond=None)
        params += delta
        if abs(delta[0]) + abs(delta[1]) < 1e-6 and abs(delta[2]) < 1e-5:
            break
    # A square turned by 90° is the same square: keep the turn within ±45°, so that the
    # corners keep the labels they had (the corner set does not change).
    params[2] = math.remainder(params[2], math.pi / 2.0)
    sides = sides_at(params)
    r, side = _assign(sides, edge_points_px)
    used = side >= 0
    if np.count_nonzero(used) < MIN_POINTS:
        return None
    rms = float(np.sqrt(np.mean(r[used] ** 2)))
    if rms > MAX_RMS_PX or abs(params[2]) > MAX_TURN_RAD:
        return None
    jac = jacobian(params, sides, side)
    information = jac.T @ jac
    if np.linalg.cond(information) > 1e12:
        return None
    sigma = np.sqrt(np.diag(np.linalg.inv(information))) * max(rms, 0.1)
    if max(sigma[0], sigma[1]) > MAX_SLIDE_SIGMA_M or sigma[2] > MAX_TURN_SIGMA_RAD:
        return None
    return SquareFit(square.moved(*params), sides.starts)


def stray_fraction(mask: np.ndarray, corners_px: FloatArray, offset_px: tuple[int, int]) -> float:
    """Fraction of the blob's pixels (crop ``mask``) more than a pixel outside the fitted square:
    a blob that is not this square (another red thing, a wrong fit) leaves many."""
    blob = mask > 0
    n = np.count_nonzero(blob)
    if n == 0:
        return 1.0
    square = np.zeros(mask.shape, np.uint8)
    local = (corners_px - np.asarray(offset_px, dtype=float)) * 16
    cv2.fillConvexPoly(square, np.round(local).astype(np.int32), 1, cv2.LINE_8, 4)
    square = cv2.dilate(square, np.ones((3, 3), np.uint8))
    return float(np.count_nonzero(blob & (square == 0)) / n)
