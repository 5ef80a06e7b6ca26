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
from numpy.typing import NDArray

from common.camera import CameraIntrinsics, pixel_to_normalized
from common.kinematics import centroid, cross
from services.vision.occlusion import square_kernel
from services.vision.segmentation import binary_u8

FloatArray = NDArray[np.float64]

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
_SIGNS = ((-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0))  # the corners along (u, v)


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
        return cls(centroid(c), u, v, size_m)

    def moved(self, du_m: float, dv_m: float, turn_rad: float) -> SquareOnPlane:
        """Slid by (du, dv) along its axes and turned about its normal."""
        c, s = math.cos(turn_rad), math.sin(turn_rad)
        u = c * self.axis_u + s * self.axis_v
        v = -s * self.axis_u + c * self.axis_v
        centre = self.centre_m + du_m * self.axis_u + dv_m * self.axis_v
        return SquareOnPlane(centre, u, v, self.size_m)

    def corners_m(self) -> FloatArray:
        signs = np.array(_SIGNS)
        h = self.size_m / 2.0
        return self.centre_m + h * (signs[:, :1] * self.axis_u + signs[:, 1:] * self.axis_v)


def outline(
    mask: np.ndarray, occluder: np.ndarray, offset_px: tuple[int, int] = (0, 0)
) -> tuple[FloatArray, np.ndarray]:
    """The outline of the largest blob of ``mask`` in order along it (N, 2; (u, v) in the
    image, ``offset_px`` = (column, row) of the crop), and which of its points are the
    marker's true edge (N,): bordering no ``occluder`` pixel (0/1 or 0/255 arrays of the
    same size), nor the crop's border."""
    contours, _ = cv2.findContours(binary_u8(mask), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return np.zeros((0, 2)), np.zeros(0, bool)
    points = max(contours, key=cv2.contourArea).reshape(-1, 2)
    size = 2 * EDGE_CLEARANCE_PX + 1
    near_occluder = cv2.dilate(binary_u8(occluder), square_kernel(size))
    h, w = mask.shape
    keep = near_occluder[points[:, 1], points[:, 0]] == 0
    keep &= (
        (points[:, 0] > 0) & (points[:, 1] > 0) & (points[:, 0] < w - 1) & (points[:, 1] < h - 1)
    )
    return points.astype(float) + np.asarray(offset_px, dtype=float), keep


def true_edge_points(
    mask: np.ndarray, occluder: np.ndarray, offset_px: tuple[int, int] = (0, 0)
) -> FloatArray:
    """Outline points (u, v) of the largest blob of ``mask`` that border no ``occluder`` pixel
    nor the crop's border (see :func:`outline`).

    The outline pixels sit half a pixel inside the true edge, on average: the caller's line
    fit is against the square's sides, which agree to well under a pixel either way."""
    points, keep = outline(mask, occluder, offset_px)
    return points[keep]


@dataclass(frozen=True)
class _Sides:
    """The four sides of a projected square as linear maps of a pixel in homogeneous form
    ``q = (u, v, 1)``: ``q @ distance`` (3, 4) its signed distance (px) from each side line
    (unit normals; the lines already moved by where outline pixels sit, half a lattice step
    inside the true edge, towards the centre), ``q @ along`` (3, 4) its position along each
    side (0 at its start corner, 1 at its end), and ``q @ d_distance`` (3, 4·3) the distances'
    derivatives with respect to the fit's parameters (linear in ``q`` too: a line's normal and
    offset are what move). ``corners_px`` (4, 2): the start corners, side k from corner k to
    k+1; ``lengths`` (4,) px."""

    distance: FloatArray
    along: FloatArray
    d_distance: FloatArray
    corners_px: FloatArray
    lengths: FloatArray


def _sides(corners_px: list[list[float]], d_corners: list[list[list[float]]]) -> _Sides:
    """The sides of the quadrilateral ``corners_px`` (4 × (u, v)) whose corners move with the
    parameters as ``d_corners`` (4 × (d/dp of u, d/dp of v)). Plain Python: four sides of
    a few numbers each, where numpy's per-call overhead would be the whole cost."""
    cu = sum(c[0] for c in corners_px) / 4.0
    cv = sum(c[1] for c in corners_px) / 4.0
    distance: list[list[float]] = [[], [], []]  # rows: u, v, 1 coefficients of each side
    along: list[list[float]] = [[], [], []]
    d_distance: list[list[float]] = [[], [], []]
    lengths = []
    for k in range(4):
        (au, av), (bu, bv) = corners_px[k], corners_px[(k + 1) % 4]
        (dau, dav), (dbu, dbv) = d_corners[k], d_corners[(k + 1) % 4]
        du, dv = bu - au, bv - av
        length = math.hypot(du, dv)
        nu, nv = -dv / length, du / length
        on_line = nu * au + nv * av
        towards_centre = math.copysign(1.0, nu * cu + nv * cv - on_line)
        along_u = abs(nu) >= abs(nv)  # inset = ±½·max|n|: follows the larger component
        inset = towards_centre * 0.5 * (abs(nu) if along_u else abs(nv))
        distance[0].append(nu)
        distance[1].append(nv)
        distance[2].append(-(on_line + inset))
        squared = length * length
        along[0].append(du / squared)
        along[1].append(dv / squared)
        along[2].append(-(du * au + dv * av) / squared)
        lengths.append(length)
        for j in range(3):  # n = perp(d)/|d|  ⇒  dn = perp(dd)/|d| − n·(d·dd)/|d|²
            ddu, ddv = dbu[j] - dau[j], dbv[j] - dav[j]
            d_dot_dd = (du * ddu + dv * ddv) / squared
            dnu = -ddv / length - nu * d_dot_dd
            dnv = ddu / length - nv * d_dot_dd
            d_inset = (
                towards_centre
                * 0.5
                * ((dnu if nu >= 0.0 else -dnu) if along_u else (dnv if nv >= 0.0 else -dnv))
            )
            d_offset = dnu * au + dnv * av + nu * dau[j] + nv * dav[j] + d_inset
            d_distance[0].append(dnu)
            d_distance[1].append(dnv)
            d_distance[2].append(-d_offset)
    return _Sides(
        np.array(distance),
        np.array(along),
        np.array(d_distance),
        np.array(corners_px),
        np.array(lengths),
    )


def _assign(sides: _Sides, points_h: FloatArray) -> tuple[FloatArray, np.ndarray, np.ndarray]:
    """The points that lie along a side (the nearest side whose extent they fall in) away from
    its corners (corners are rounded): their residuals against that side, its index, and
    which of the points they are (N,). ``points_h`` (N, 3): pixels (u, v, 1)."""
    dist = points_h @ sides.distance  # (N, 4)
    t = points_h @ sides.along
    within = (t > -0.25) & (t < 1.25)  # a side's neighbourhood, corners included
    side = np.where(within, np.abs(dist), np.inf).argmin(axis=1)
    at = np.arange(0, 4 * len(points_h), 4) + side  # [rows, side] as indices into the raveled
    margin = CORNER_CLEARANCE_PX / sides.lengths[side]
    t_side = t.take(at)
    keep = within.take(at) & (t_side > margin) & (t_side < 1.0 - margin)
    return dist.take(at)[keep], side[keep], keep


@dataclass(frozen=True)
class SquareFit:
    square: SquareOnPlane
    corners_px: FloatArray


def slid_to(square: SquareOnPlane, uv_px: FloatArray, k: CameraIntrinsics) -> SquareOnPlane:
    """``square`` slid in its plane so that its centre is seen at pixel ``uv_px``."""
    ray = np.append(pixel_to_normalized(uv_px, k)[0], 1.0)
    normal = cross(square.axis_u, square.axis_v)
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


def _corners_and_jacobian(
    square: SquareOnPlane, params: FloatArray, k: CameraIntrinsics
) -> tuple[list[list[float]], list[list[list[float]]]]:
    """The corners (4 × (u, v), px) of ``square.moved(*params)`` and their derivatives
    (4 × (d/dp of u, d/dp of v)) with respect to the parameters (slide along u, slide along
    v, turn). Plain Python, as :func:`_sides`."""
    du_m, dv_m, turn_rad = np.asarray(params, dtype=float).tolist()
    axis_u, axis_v = square.axis_u.tolist(), square.axis_v.tolist()
    # square.moved(du_m, dv_m, turn_rad), the same operations on plain floats
    c, s = math.cos(turn_rad), math.sin(turn_rad)
    u = [c * a + s * b for a, b in zip(axis_u, axis_v, strict=True)]
    v = [-s * a + c * b for a, b in zip(axis_u, axis_v, strict=True)]
    centre = [
        m + du_m * a + dv_m * b
        for m, a, b in zip(square.centre_m.tolist(), axis_u, axis_v, strict=True)
    ]
    (mx, my, mz), (ux, uy, uz), (vx, vy, vz) = centre, u, v
    (aux, auy, auz), (avx, avy, avz) = axis_u, axis_v
    h = square.size_m / 2.0
    fx, fy, cx, cy = k.fx_px, k.fy_px, k.cx_px, k.cy_px
    corners, d_corners = [], []
    for su, sv in _SIGNS:
        x, y, z = (
            mx + h * (su * ux + sv * vx),
            my + h * (su * uy + sv * vy),
            mz + h * (su * uz + sv * vz),
        )
        # d(point)/d(turn); the slides move every corner by axis_u, axis_v
        tx, ty, tz = h * (su * vx - sv * ux), h * (su * vy - sv * uy), h * (su * vz - sv * uz)
        x_n, y_n = x / z, y / z
        corners.append([fx * x_n + cx, fy * y_n + cy])
        # d(f·X/Z) = f·(dX − (X/Z)·dZ)/Z
        d_corners.append(
            [
                [fx * (aux - x_n * auz) / z, fx * (avx - x_n * avz) / z, fx * (tx - x_n * tz) / z],
                [fy * (auy - y_n * auz) / z, fy * (avy - y_n * avz) / z, fy * (ty - y_n * tz) / z],
            ]
        )
    return corners, d_corners


def fit_square(
    square: SquareOnPlane, edge_points_px: FloatArray, k: CameraIntrinsics
) -> SquareFit | None:
    """Slide and turn ``square`` in its plane until its projected sides run along the edge
    points (Gauss-Newton on the three in-plane parameters from the given pose; the Jacobian
    written out, :func:`_sides`). None unless the fit is tight, the edges pin the pose down
    (its 1-σ within :data:`MAX_SLIDE_SIGMA_M` and :data:`MAX_TURN_SIGMA_RAD`) and it turned
    little."""
    if len(edge_points_px) < MIN_POINTS:
        return None
    points_h = np.column_stack([edge_points_px, np.ones(len(edge_points_px))])
    params = np.zeros(3)

    def linearised(p: FloatArray) -> tuple[_Sides, FloatArray, FloatArray] | None:
        """The sides at ``p``, the used points' residuals and their Jacobian (N, 3); None
        with too few points away from the corners."""
        sides = _sides(*_corners_and_jacobian(square, p, k))
        r, side, used = _assign(sides, points_h)
        if len(side) < MIN_POINTS:
            return None
        d_all = (points_h[used] @ sides.d_distance).reshape(-1, 3)  # 4 sides' rows per point
        return sides, r, d_all.take(np.arange(0, 4 * len(side), 4) + side, axis=0)

    for _ in range(ITERATIONS):
        now = linearised(params)
        if now is None:
            return None
        _, r, jac = now
        delta, *_ = np.linalg.lstsq(jac, -r, rcond=None)
        params += delta
        if abs(delta[0]) + abs(delta[1]) < 1e-6 and abs(delta[2]) < 1e-5:
            break
    # A square turned by 90° is the same square: keep the turn within ±45°, so that the
    # corners keep the labels they had (the corner set does not change).
    params[2] = math.remainder(params[2], math.pi / 2.0)
    now = linearised(params)
    if now is None:
        return None
    sides, r, jac = now
    rms = float(np.sqrt((r**2).sum() / len(r)))  # np.mean's operations
    if rms > MAX_RMS_PX or abs(params[2]) > MAX_TURN_RAD:
        return None
    information = jac.T @ jac
    if np.linalg.cond(information) > 1e12:
        return None
    sigma = np.sqrt(np.diag(np.linalg.inv(information))) * max(rms, 0.1)
    if max(sigma[0], sigma[1]) > MAX_SLIDE_SIGMA_M or sigma[2] > MAX_TURN_SIGMA_RAD:
        return None
    return SquareFit(square.moved(*params), sides.corners_px)


def stray_fraction(mask: np.ndarray, corners_px: FloatArray, offset_px: tuple[int, int]) -> float:
    """Fraction of the blob's pixels (crop ``mask``) more than a pixel outside the fitted square:
    a blob that is not this square (another red thing, a wrong fit) leaves many."""
    blob = mask > 0
    n = np.count_nonzero(blob)
    if n == 0:
        return 1.0
    square = np.zeros(mask.shape, np.uint8)
    local = (corners_px - np.asarray(offset_px, dtype=float)) * 16
    cv2.fillConvexPoly(square, local.round().astype(np.int32), 1, cv2.LINE_8, 4)
    square = cv2.dilate(square, square_kernel(3))
    return float(np.count_nonzero(blob & (square == 0)) / n)
