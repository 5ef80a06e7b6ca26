"""Depth of a marker's corners: a plane fitted to the depth inside its eroded blob (inverse
depth linear in normalized coordinates, outliers rejected), the corner rays intersected with
it; the plane's depth around a marker, for the occlusion check. Pure functions."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from common.camera import CameraIntrinsics, back_project, pixel_to_normalized
from common.messages import usable_depths
from services.vision.occlusion import RING_WIDTH_PX
from services.vision.quad import quad_area_px2
from services.vision.segmentation import Roi

FloatArray = NDArray[np.float64]

DEPTH_ERODE_FRACTION = 0.1  # erosion radius as a fraction of the blob side...
DEPTH_ERODE_MIN_PX = 2  # ...but at least this many pixels
DEPTH_MIN_PLANE_PIXELS = 20  # fewer valid pixels: no plane, so no corner depths
DEPTH_MIN_PIXELS = 3  # fewer: no depth at all
DEPTH_MAX_PLANE_PIXELS = 400  # about this many samples on a grid: plenty for a plane, fast
DEPTH_OUTLIER_SIGMAS = 3.0
DEPTH_OUTLIER_MIN_M = 0.001  # plane residuals below this are never outliers
DEPTH_GATE_MIN_M = 0.01  # depths this close to the median are never gross outliers
MAD_TO_SIGMA = 1.4826  # median absolute deviation → standard deviation for Gaussian noise


def rays_of(xy: FloatArray) -> FloatArray:
    """(N, 3) rays ``(x, y, 1)`` of N normalized coordinates (N, 2)."""
    xy = np.asarray(xy, dtype=float)
    rays = np.empty((len(xy), 3))  # filled in place: np.column_stack costs more here
    rays[:, :2] = xy
    rays[:, 2] = 1.0
    return rays


@dataclass(frozen=True)
class PlaneFit:
    """A plane seen by the depth camera, as inverse depth linear in normalized coordinates:
    ``1/Z = c · (x, y, 1)`` (exact for a plane: ``n·P = d`` with ``P = Z·(x, y, 1)``), with the
    least-squares covariance of ``c``, so depth and its uncertainty follow for any ray."""

    coefficients: FloatArray  # (3,) in 1/m
    covariance: FloatArray  # (3, 3) in 1/m²

    def depths_m(self, xy: FloatArray) -> FloatArray:
        return self._depths_along(rays_of(xy))

    def _depths_along(self, rays: FloatArray) -> FloatArray:
        """Z of the plane along each ray ``(x, y, 1)``."""
        return 1.0 / (rays @ self.coefficients)

    def shifted(self, shift_m: FloatArray) -> PlaneFit:
        """The same plane translated by ``shift_m`` (camera frame): ``n·P = d`` becomes
        ``n·P = d + n·shift``, i.e. ``c' = c / (1 + c·shift)``; the covariance is kept."""
        return PlaneFit(
            self.coefficients / (1.0 + float(self.coefficients @ shift_m)), self.covariance
        )

    def depths_and_sigmas_m(self, xy: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The plane's depth along each ray and its 1-σ: σ(1/Z)·Z², σ(1/Z)² = φᵀ·C·φ."""
        rays = rays_of(xy)
        depths = self._depths_along(rays)
        inverse_var = np.einsum("ij,jk,ik->i", rays, self.covariance, rays)
        return depths, np.sqrt(np.maximum(inverse_var, 0.0)) * depths**2


def bounding_box(
    corners_px: FloatArray, margin_px: int, shape: tuple[int, ...]
) -> tuple[int, int, int, int]:
    """(row0, row1, col0, col1) slice bounds of the pixels within ``margin_px`` of the
    corners' bounding box, clipped to an image of ``shape``."""
    us, vs = zip(*corners_px.tolist(), strict=True)
    return (
        max(math.floor(min(vs)) - margin_px, 0),
        min(math.ceil(max(vs)) + margin_px + 1, shape[0]),
        max(math.floor(min(us)) - margin_px, 0),
        min(math.ceil(max(us)) + margin_px + 1, shape[1]),
    )


def _marker_depth_pixels(
    depth_m: np.ndarray, mask: np.ndarray, corners_px: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """(uv (N, 2) px, Z (N,) m) of the valid depth pixels well inside the marker
    (``corners_px`` in depth pixels; ``mask`` at the colour resolution, registered here).

    Only the mask inside the corners' quadrilateral counts (other blobs stay out), eroded
    (radius 10 % of the side, at least 2 px) so that the outline and the pixels next to
    occluders, where depth jumps to what lies behind or in front, are dropped.
    """
    side_px = math.sqrt(max(quad_area_px2(corners_px), 1.0))
    radius_px = max(DEPTH_ERODE_MIN_PX, round(DEPTH_ERODE_FRACTION * side_px))
    r0, r1, c0, c1 = bounding_box(corners_px, 1, depth_m.shape)  # depth pixels
    if r1 <= r0 or c1 <= c0:
        return np.zeros((0, 2)), np.zeros(0)
    quad = np.zeros((r1 - r0, c1 - c0), np.uint8)
    shift_bits = 4  # sub-pixel vertices for fillConvexPoly, 1/16 px
    vertices = ((corners_px - (c0, r0)) * (1 << shift_bits)).round().astype(np.int32)
    cv2.fillConvexPoly(quad, vertices, 255, cv2.LINE_8, shift_bits)
    inner = cv2.erode(
        cv2.bitwise_and(quad, registered_mask(mask, depth_m.shape, (r0, r1, c0, c1))),
        cv2.getStructuringElement(cv2.MORPH_RECT, (2 * radius_px + 1, 2 * radius_px + 1)),
        borderType=cv2.BORDER_CONSTANT,
        borderValue=0,
    )
    # A regular grid of about DEPTH_MAX_PLANE_PIXELS samples is plenty for a plane; all
    # pixels only if that leaves too few (sparse depth).
    step = grid_step(int(side_px * side_px))
    while True:
        z = depth_m[r0:r1:step, c0:c1:step]
        vv, uu = ((inner[::step, ::step] > 0) & (z > 0) & (z < np.inf)).nonzero()  # NaN: neither
        if step == 1 or len(vv) >= DEPTH_MIN_PLANE_PIXELS:
            break
        step = 1
    uv = np.empty((len(uu), 2))
    uv[:, 0], uv[:, 1] = uu * step + c0, vv * step + r0
    return uv, z[vv, uu].astype(float)


def grid_step(pixel_count: int) -> int:
    """Sampling step (px, both directions) that leaves about :data:`DEPTH_MAX_PLANE_PIXELS` of
    ``pixel_count`` pixels: plenty for a plane, and fast."""
    return max(1, math.isqrt(pixel_count // DEPTH_MAX_PLANE_PIXELS))


def median(values: FloatArray) -> float:
    """Median (upper median for even sizes); partitioning (a copy, as np.partition does) is
    several times faster than np.median on these small arrays."""
    k = len(values) // 2
    partitioned = values.copy()
    partitioned.partition(k)
    return float(partitioned[k])


def _outlier_threshold(deviations: FloatArray, floor: float) -> float:
    """max(3 robust σ, floor), from values' absolute ``deviations`` from their median (the
    median absolute deviation)."""
    sigma = MAD_TO_SIGMA * median(deviations)
    return max(DEPTH_OUTLIER_SIGMAS * sigma, floor)


def fit_inverse_depth_plane(xy: FloatArray, z_m: FloatArray) -> PlaneFit | None:
    """Plane through a marker's depth samples despite holes, edge jumps and flying pixels.

    ``xy`` (N, 2) normalized coordinates, ``z_m`` (N,) their depths. Gross outliers go first
    (Z farther from the median than 3 robust σ, at least 1 cm: a few percent of pixels far
    behind would otherwise tilt the plane); then least squares on ``1/Z = c·(x, y, 1)``, and
    one refit without the samples off it by more than 3 robust σ (at least 1 mm). The
    covariance of ``c`` comes from the residuals of the final fit (noise, quantisation and
    lateral jitter as they are). None with fewer than :data:`DEPTH_MIN_PLANE_PIXELS` samples or
    a plane seen edge-on.
    """
    deviations = np.abs(z_m - median(z_m))
    near = deviations <= _outlier_threshold(deviations, DEPTH_GATE_MIN_M)
    if DEPTH_MIN_PLANE_PIXELS <= np.count_nonzero(near) < len(z_m):  # all near: no copy
        xy, z_m = xy[near], z_m[near]
    if len(z_m) < DEPTH_MIN_PLANE_PIXELS:
        return None
    rays = rays_of(xy)
    fit = _least_squares_plane(rays, 1.0 / z_m)
    if fit is None:
        return None
    residuals_m = z_m - 1.0 / (rays @ fit[0])
    deviations = np.abs(residuals_m - median(residuals_m))
    inliers = np.abs(residuals_m) <= _outlier_threshold(deviations, DEPTH_OUTLIER_MIN_M)
    if np.count_nonzero(inliers) >= DEPTH_MIN_PLANE_PIXELS:
        rays, z_m = rays[inliers], z_m[inliers]
        fit = _least_squares_plane(rays, 1.0 / z_m)
        if fit is None:
            return None
    coefficients, inverse_normal = fit
    inverse_residuals = 1.0 / z_m - rays @ coefficients
    variance = float(inverse_residuals @ inverse_residuals) / max(len(z_m) - 3, 1)
    return PlaneFit(coefficients, variance * inverse_normal)


def _least_squares_plane(
    rays: FloatArray, inverse_z: FloatArray
) -> tuple[FloatArray, FloatArray] | None:
    """Least-squares ``c`` of ``rays @ c = inverse_z`` and the inverse of the normal matrix
    (for the covariance), by the 3×3 normal equations: a few times cheaper than
    ``np.linalg.lstsq`` here, and exact enough (rays (x, y, 1) over a marker: condition
    number of the normal matrix ~1e6, so ~1e-10 relative). None when the normal matrix is
    near-singular (a plane seen edge-on, or samples along a line)."""
    normal = rays.T @ rays
    eigenvalues = np.linalg.eigvalsh(normal)
    if eigenvalues[0] <= eigenvalues[-1] * 1e-12:
        return None
    inverse_normal = np.linalg.inv(normal)
    return inverse_normal @ (rays.T @ inverse_z), inverse_normal


@dataclass(frozen=True)
class CornerDepths:
    """Depths (4,), their 1-σ (4,), the corners' 3-D points (4, 3), all in m, and the plane
    they come from (None for the few-pixel median fallback)."""

    depths_m: FloatArray
    sigmas_m: FloatArray
    points_m: FloatArray
    plane: PlaneFit | None


def registered_mask(
    mask: np.ndarray, shape: tuple[int, ...], bounds: tuple[int, int, int, int] | None = None
) -> np.ndarray:
    """A colour-resolution 0/255 mask at the depth image's resolution (pixels at least half
    covered), for a depth image registered to the colour one at a lower resolution; with
    ``bounds`` (row0, row1, col0, col1 of the depth image) only that crop of it.

    A crop is resampled on its own when the colour image is a whole multiple of the depth one
    (each depth pixel then averages its own block of colour pixels: the same values as the
    whole image's resampling), rather than resampling the whole mask for a marker's box."""
    r0, r1, c0, c1 = bounds if bounds is not None else (0, shape[0], 0, shape[1])
    if mask.shape[:2] == shape[:2]:
        return mask[r0:r1, c0:c1]
    sy, sx = mask.shape[0] // shape[0], mask.shape[1] // shape[1]
    if bounds is not None and (sy * shape[0], sx * shape[1]) == mask.shape[:2] and sy and sx:
        small = cv2.resize(
            mask[r0 * sy : r1 * sy, c0 * sx : c1 * sx],
            (c1 - c0, r1 - r0),
            interpolation=cv2.INTER_AREA,
        )
    else:
        small = cv2.resize(mask, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)[r0:r1, c0:c1]
    return cv2.threshold(small, 127, 255, cv2.THRESH_BINARY)[1]  # ≥ 128: at least half


def registered_region_mask(
    mask: np.ndarray, shape: tuple[int, ...], region: Roi | None
) -> np.ndarray:
    """:func:`registered_mask` of the whole of a mask that is zero outside ``region`` (its
    rows and columns; None: anywhere): when the colour image is a whole multiple of the depth
    one only the depth pixels over the region are resampled, the others being zero."""
    sy, sx = mask.shape[0] // shape[0], mask.shape[1] // shape[1]
    whole_multiple = sy and sx and (sy * shape[0], sx * shape[1]) == mask.shape[:2]
    if region is None or not whole_multiple or mask.shape[:2] == shape[:2]:
        return registered_mask(mask, shape)  # a view of the mask itself at the same size
    rows, cols = region
    r0, r1 = rows.start // sy, -(-rows.stop // sy)  # the depth pixels covering the region
    c0, c1 = cols.start // sx, -(-cols.stop // sx)
    small = np.zeros(shape[:2], np.uint8)
    if r1 > r0 and c1 > c0:
        small[r0:r1, c0:c1] = registered_mask(mask, shape, (r0, r1, c0, c1))
    return small


def to_depth_pixels(corners_px: FloatArray, k: CameraIntrinsics, k_depth: CameraIntrinsics):
    """Colour-image pixels → the registered depth image's pixels (same rays)."""
    xy = pixel_to_normalized(corners_px, k)
    uv = np.empty_like(xy)  # filled column by column: np.column_stack costs more here
    uv[:, 0] = k_depth.fx_px * xy[:, 0] + k_depth.cx_px
    uv[:, 1] = k_depth.fy_px * xy[:, 1] + k_depth.cy_px
    return uv


def corner_depths(
    depth_m: np.ndarray,
    mask: np.ndarray,
    corners_px: np.ndarray,
    k: CameraIntrinsics,
    k_depth: CameraIntrinsics | None = None,
) -> CornerDepths | None:
    """Depths, uncertainties and optical-frame points of a flat marker's corners.

    The corners themselves sit on the depth discontinuity, so their depth comes from a plane
    fitted (:func:`fit_inverse_depth_plane`) to the valid depth pixels well inside the marker,
    evaluated along each corner's viewing ray ``(x, y, 1)·Z``. ``mask`` and ``corners_px`` are
    at the colour resolution (intrinsics ``k``); ``depth_m`` is registered to it, at its own
    resolution ``k_depth`` (default: the same). With fewer valid pixels than a plane needs
    (:data:`DEPTH_MIN_PLANE_PIXELS`), or a plane seen edge-on, the result is None: giving every
    corner the samples' median depth put a tilted marker's corners centimetres off with an
    uncertainty of a millimetre.
    """
    corners = np.asarray(corners_px, dtype=float).reshape(4, 2)
    k_depth = k_depth or k
    depth_corners = corners if k_depth == k else to_depth_pixels(corners, k, k_depth)
    uv, z = _marker_depth_pixels(depth_m, mask, depth_corners)
    if len(z) < DEPTH_MIN_PLANE_PIXELS:
        return None
    plane = fit_inverse_depth_plane(pixel_to_normalized(uv, k_depth), z)
    if plane is None:
        return None  # seen edge-on
    corner_xy = pixel_to_normalized(corners, k)
    depths, sigmas = plane.depths_and_sigmas_m(corner_xy)
    if not usable_depths(depths):  # behind the camera, or nearer than a message carries
        return None
    return CornerDepths(depths, sigmas, back_project(corners, depths, k), plane)


def depth_ring_px(ring_px: int, k: CameraIntrinsics, k_depth: CameraIntrinsics | None) -> int:
    """``ring_px`` (colour pixels) in pixels of a coarser depth image, at least one pixel past
    the occlusion ring: a 320×240 depth pixel covers four 640×480 colour ones, and a reach
    kept at 5 depth pixels would count a hand 10 colour pixels away as in front."""
    if k_depth is None or k_depth.width_px >= k.width_px:
        return ring_px
    return max(RING_WIDTH_PX + 1, round(ring_px * k_depth.width_px / k.width_px))


def plane_depth_image(
    plane: PlaneFit, k: CameraIntrinsics, bounds: tuple[int, int, int, int]
) -> FloatArray:
    """Depth of ``plane`` along the ray of every pixel in ``bounds`` (row0, row1, col0, col1)
    of an image with intrinsics ``k``: the marker's surface, extended around it."""
    r0, r1, c0, c1 = bounds
    # 1/Z = a·x + b·y + c, x by column and y by row: an outer sum, not a ray per pixel
    a, b, c = plane.coefficients.tolist()
    x = (np.arange(c0, c1, dtype=float) - k.cx_px) / k.fx_px
    y = (np.arange(r0, r1, dtype=float) - k.cy_px) / k.fy_px
    return 1.0 / ((a * x)[None, :] + ((b * y) + c)[:, None])


def marker_surface(
    plane: PlaneFit | None,
    depths_m: FloatArray,
    k: CameraIntrinsics,
    bounds: tuple[int, int, int, int],
) -> FloatArray | float:
    """A marker's surface along each pixel's ray of ``bounds`` (row0, row1, col0, col1) of an
    image with intrinsics ``k``: its plane, else its nearest corner's depth (m)."""
    if plane is not None:
        return plane_depth_image(plane, k, bounds)
    return float(np.min(depths_m))
