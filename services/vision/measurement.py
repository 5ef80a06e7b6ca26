"""One frame's measurement of both markers, and the record vision keeps of each.

Pure functions on numpy arrays (no networking, no global state). Conventions:

- Images are RGB ``uint8`` (H, W, 3) in RGB channel order; depth is ``float32`` (H, W), Z along
  the optical axis in metres, with 0 or non-finite meaning "no measurement".
- Pixel ``(u, v)``: column, row; pixel centres sit at integer coordinates (OpenCV style, see
  :mod:`common.camera`).
- Corner order is canonical (:func:`services.vision.quad.order_corners`), or physical with
  ``marker.orientation_cue`` (:mod:`services.vision.cue`).

One frame walks the modules in one direction: :mod:`~services.vision.segmentation` (colour
threshold + morphology, full resolution only around each marker) →
:mod:`~services.vision.quad` (largest blob, rough quadrilateral, one straight edge per side,
corners; both markers' edges refined in one numpy batch) → :mod:`~services.vision.depth`
(plane fitted to the depth inside the eroded blob, corner rays intersected with it) →
:mod:`~services.vision.occlusion` (something in front of the outline?). Tracking across frames
and partly hidden markers are :mod:`~services.vision.tracking`'s and
:mod:`~services.vision.partial`'s.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from common.camera import CameraIntrinsics, pixel_to_normalized
from common.config import VisionConfig
from common.marker import Marker
from common.messages import MarkerState
from common.metrics import percentile
from services.vision.cue import CUE_HIDDEN, label_corners
from services.vision.depth import (
    DEPTH_MIN_PIXELS,
    PlaneFit,
    bounding_box,
    corner_depths,
    depth_ring_px,
    fit_inverse_depth_plane,
    grid_step,
    marker_surface,
    plane_depth_image,
    registered_mask,
    registered_region_mask,
    to_depth_pixels,
)
from services.vision.occlusion import is_occluded
from services.vision.quad import find_quads, order_corners
from services.vision.segmentation import (
    MARKERS,
    MORPH_KERNEL,
    Roi,
    check_rgb,
    marker_masks,
    mask_bounds,
)

FloatArray = NDArray[np.float64]


# Why a marker is not usable → its state (see common.messages.MarkerFeatures).
REASON_STATES: dict[str, MarkerState] = {
    "no blob": "lost",
    "blob too small": "partial",  # a sliver of it shows
    "touches image border": "partial",
    "not a quadrilateral": "partial",
    "occluded": "partial",
    "not the marker's size": "partial",
    "no valid depth": "no_depth",
    "no depth image": "no_depth",
    "depth image too old": "no_depth",
    "depth of it too old": "no_depth",  # its last view with depth (held between images)
    CUE_HIDDEN: "partial",  # its orientation cue is not seen: corner 0 cannot be told
}


@dataclass(frozen=True)
class MarkerMeasurement:
    """One marker in one frame as vision measured it: the :class:`~common.marker.Marker` it
    publishes (its ``reason`` a key of :data:`REASON_STATES`), and the depth plane its depths
    come from (None when they do not come from a fit), which only vision's tracking keeps."""

    marker: Marker
    plane: PlaneFit | None = None


def not_visible(reason: str, occluded: bool = False) -> MarkerMeasurement:
    """A marker that cannot be used, for ``reason`` (a key of :data:`REASON_STATES`)."""
    return MarkerMeasurement(Marker.unseen(REASON_STATES[reason], reason, occluded))


def _measure(
    quad: MarkerQuad,
    depth_m: np.ndarray,
    k: CameraIntrinsics,
    k_depth: CameraIntrinsics | None,
    ring_px: int,
) -> MarkerMeasurement:
    """Depths and occlusion check of a marker whose corners are in their final order."""
    ring_px = depth_ring_px(ring_px, k, k_depth)
    if quad.corners_px is None:
        occluded = quad.area_px > 0 and _blob_occluded(
            quad.mask, depth_m, k_depth or k, ring_px, quad.region
        )
        return not_visible(quad.reason, occluded)
    corners, mask = quad.corners_px, quad.mask
    depth = corner_depths(depth_m, mask, corners, k, k_depth)
    if depth is None:
        return not_visible("no valid depth")
    k_depth = k_depth or k
    depth_corners = corners if k_depth == k else to_depth_pixels(corners, k, k_depth)
    bounds = bounding_box(depth_corners, ring_px + 3, depth_m.shape)
    r0, r1, c0, c1 = bounds
    crop_mask = registered_mask(mask, depth_m.shape, bounds)
    surface = marker_surface(depth.plane, depth.depths_m, k_depth, bounds)
    if is_occluded(depth_m[r0:r1, c0:c1], crop_mask, surface, ring_px):
        return not_visible("occluded", occluded=True)
    marker = Marker(
        state="visible",
        corners_px=corners,
        depth_m=depth.depths_m,
        depth_sigma_m=depth.sigmas_m,
        points_m=depth.points_m,
    )
    return MarkerMeasurement(marker, depth.plane)


def _blob_occluded(
    mask: np.ndarray,
    depth_m: np.ndarray,
    k_depth: CameraIntrinsics,
    ring_px: int,
    region: Roi | None = None,
) -> bool:
    """Is something in front of a blob that did not make a whole square? The ring around it
    against the plane of its own depth (else its nearest depth: a tilted marker spans
    centimetres). ``region``: where ``mask`` can be non-zero (None: anywhere)."""
    small = registered_region_mask(mask, depth_m.shape, region)
    bounds = mask_bounds(small, ring_px + 3)
    if bounds is None:
        return False
    r0, r1, c0, c1 = bounds
    crop_mask, crop_depth = small[r0:r1, c0:c1], depth_m[r0:r1, c0:c1]
    eroded = cv2.erode(crop_mask, MORPH_KERNEL)
    step = grid_step(cv2.countNonZero(eroded))
    z_grid = crop_depth[::step, ::step]
    vv, uu = np.nonzero((eroded[::step, ::step] > 0) & (z_grid > 0) & np.isfinite(z_grid))
    if vv.size < DEPTH_MIN_PIXELS:
        return False
    z = z_grid[vv, uu].astype(float)
    uv = np.column_stack([uu * step + c0, vv * step + r0]).astype(float)
    plane = fit_inverse_depth_plane(pixel_to_normalized(uv, k_depth), z)
    if plane is not None:
        surface: FloatArray | float = plane_depth_image(plane, k_depth, bounds)
    else:
        surface = percentile(z, 5.0)
    return is_occluded(crop_depth, crop_mask, surface, ring_px)


def _check_frame(rgb: np.ndarray, depth_m: np.ndarray, k_depth: CameraIntrinsics | None) -> None:
    check_rgb(rgb)
    expected = rgb.shape[:2] if k_depth is None else (k_depth.height_px, k_depth.width_px)
    if depth_m.shape != expected:
        raise ValueError(f"depth {depth_m.shape} does not match the expected {expected}")


@dataclass(frozen=True)
class MarkerQuad:
    """A marker found in colour alone: corners (canonical order) or why not, its mask, and
    the region of it that can be non-zero (None: anywhere)."""

    corners_px: FloatArray | None
    reason: str
    area_px: float
    mask: np.ndarray
    region: Roi | None = None


def find_marker_quads(
    rgb: np.ndarray,
    cfg: VisionConfig,
    previous: dict[str, np.ndarray] | None = None,
    orientation_cue: bool = False,
    windows: dict[str, np.ndarray] | None = None,
) -> dict[str, MarkerQuad]:
    """Both markers in a colour image, keyed ``"hand"`` (green) and ``"target"`` (red);
    ``previous`` maps the same keys to last frame's corners (to keep their order), and
    ``windows`` (default: ``previous``) to the corners of those seen whole in the last frame,
    whose blobs are looked for around them first.

    ``orientation_cue`` (``marker.orientation_cue``): the corners are labelled by each
    marker's cue (:mod:`services.vision.cue`, physical order), by continuity with
    ``previous`` (which must then hold only markers labelled in the last frame) while the cue
    cannot be told, and the marker is :data:`~services.vision.cue.CUE_HIDDEN` otherwise."""
    check_rgb(rgb)
    previous = previous or {}
    masks = marker_masks(rgb, cfg, previous if windows is None else windows)
    quads = find_quads(masks, cfg.min_area_px)  # both markers' sides refined in one batch
    out = {}
    for name, quad, (mask, region) in zip(MARKERS, quads, masks, strict=True):
        corners, reason = None, quad.reason
        if quad.corners_px is not None and orientation_cue:
            corners = label_corners(rgb, quad.corners_px, previous.get(name), cfg)
            reason = CUE_HIDDEN if corners is None else ""
        elif quad.corners_px is not None:
            corners = order_corners(quad.corners_px, previous.get(name))
        out[name] = MarkerQuad(corners, reason, quad.area_px, mask, region)
    return out


def measure_markers(
    rgb: np.ndarray,
    depth_m: np.ndarray,
    k: CameraIntrinsics,
    cfg: VisionConfig,
    previous: dict[str, np.ndarray] | None = None,
    k_depth: CameraIntrinsics | None = None,
    orientation_cue: bool = False,
) -> dict[str, Marker]:
    """Both markers, keyed ``"hand"`` (green) and ``"target"`` (red), from a colour image and
    the depth image taken with it; ``previous`` maps the same keys to last frame's corners
    (missing keys: no previous); ``orientation_cue``: see :func:`find_marker_quads`."""
    _check_frame(rgb, depth_m, k_depth)
    return {
        name: measure_quad(quad, depth_m, k, cfg, k_depth).marker
        for name, quad in find_marker_quads(rgb, cfg, previous, orientation_cue).items()
    }


def measure_quad(
    quad: MarkerQuad,
    depth_m: np.ndarray,
    k: CameraIntrinsics,
    cfg: VisionConfig,
    k_depth: CameraIntrinsics | None = None,
) -> MarkerMeasurement:
    """Depths and occlusion check of a marker found by :func:`find_marker_quads`, with the
    depth image taken together with the colour image."""
    return _measure(quad, depth_m, k, k_depth, cfg.occlusion_ring_px)
