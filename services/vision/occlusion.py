"""Depth tells occlusion apart from shape: is something in front of a marker's outline?

A square that is partly hidden can still look like a (smaller) quadrilateral in colour alone.
With a depth camera, the pixels just outside the blob reveal it: if a band around the outline
holds surfaces clearly *closer* to the camera than the marker itself, an object overlaps the
marker and its corners cannot be trusted.
"""

from __future__ import annotations

import cv2
import numpy as np

RING_WIDTH_PX = 2  # an occluder overlapping the marker borders it directly
CLOSER_MARGIN_M = 0.01  # well above depth noise at 0.5 m (about 1.5 mm), below a hand's thickness
OCCLUDED_FRACTION = 0.03


def occluder_fraction(
    depth_m: np.ndarray, mask: np.ndarray, marker_min_depth_m: float, ring_px: int = RING_WIDTH_PX
) -> float:
    """Fraction of the valid-depth pixels in a ring around ``mask`` that lie more than
    :data:`CLOSER_MARGIN_M` in front of the marker's nearest corner."""
    ys, xs = np.nonzero(mask)
    if ys.size == 0:
        return 0.0
    pad = ring_px + 2
    y0, y1 = max(0, ys.min() - pad), min(mask.shape[0], ys.max() + pad + 1)
    x0, x1 = max(0, xs.min() - pad), min(mask.shape[1], xs.max() + pad + 1)
    roi = (mask[y0:y1, x0:x1] > 0).astype(np.uint8)
    kernel_outer = np.ones((2 * ring_px + 3, 2 * ring_px + 3), np.uint8)
    outer = cv2.dilate(roi, kernel_outer)
    inner = cv2.dilate(roi, np.ones((3, 3), np.uint8))
    ring = (outer > 0) & (inner == 0)
    depth = depth_m[y0:y1, x0:x1][ring]
    depth = depth[np.isfinite(depth) & (depth > 0)]
    if depth.size == 0:
        return 0.0
    return float(np.mean(depth < marker_min_depth_m - CLOSER_MARGIN_M))


def is_occluded(
    depth_m: np.ndarray, mask: np.ndarray, corner_depths_m: np.ndarray, ring_px: int = RING_WIDTH_PX
) -> bool:
    """Something closer than the marker borders it. ``ring_px`` should reach past the band of
    invalid depth a depth camera leaves along an occluder's edge (a few pixels on a Kinect),
    where that edge's depth cannot be seen."""
    fraction = occluder_fraction(depth_m, mask, float(np.min(corner_depths_m)), ring_px)
    return fraction > OCCLUDED_FRACTION


def hidden_behind(depth_m: np.ndarray, region: np.ndarray, marker_min_depth_m: float) -> bool:
    """A marker that was last seen in ``region`` (mask of that quadrilateral, same size as
    ``depth_m``) at ``marker_min_depth_m`` is now (partly) hidden by something in front: more
    than :data:`OCCLUDED_FRACTION` of the valid depth there is closer than it was (a marker
    that is gone, not hidden, leaves the surface it lay on). False when the depth cannot tell."""
    depth = depth_m[region > 0]
    depth = depth[np.isfinite(depth) & (depth > 0)]
    if depth.size == 0:
        return False
    return float(np.mean(depth < marker_min_depth_m - CLOSER_MARGIN_M)) > OCCLUDED_FRACTION
