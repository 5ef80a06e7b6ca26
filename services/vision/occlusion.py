"""Depth tells occlusion apart from shape: is something in front of a marker's outline?

A square that is partly hidden can still look like a (smaller) quadrilateral in colour alone.
With a depth camera, the pixels just outside the blob reveal it: if a band around the outline
holds surfaces clearly *closer* to the camera than the marker itself, an object overlaps the
marker and its corners cannot be trusted.
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from services.vision.segmentation import binary_u8

RING_WIDTH_PX = 2  # an occluder overlapping the marker borders it directly
# In front of the marker's surface (its plane, per pixel) by more than this: about 5 σ of Kinect
# noise at 0.5 m (1.2 mm) and less than a hand held just above the object.
CLOSER_MARGIN_M = 0.006
OCCLUDED_FRACTION = 0.03


def occluder_fraction(
    depth_m: np.ndarray,
    mask: np.ndarray,
    surface_m: np.ndarray | float,
    reach_px: int = RING_WIDTH_PX,
    ring_px: int = RING_WIDTH_PX,
) -> float:
    """Fraction of the ring of ``ring_px`` pixels around ``mask`` taken by something in front
    of the marker: closer than ``surface_m`` (the marker's surface along each pixel's ray, i.e.
    its plane extended, an array of ``depth_m``'s shape; or one depth) by
    :data:`CLOSER_MARGIN_M`.

    A depth camera leaves no valid depth along an occluder's edge (the Kinect's edge dropout),
    which is exactly where it borders the marker; an invalid ring pixel therefore counts as
    occluder when a closer surface lies within ``reach_px`` of it. Other invalid pixels are
    left out (too close, too far, shiny: nothing is known there); a closer object near the
    marker but not touching it leaves valid background in the ring and does not count.
    """
    binary = binary_u8(mask)  # non-zero: in it
    x, y, w, h = cv2.boundingRect(binary)
    if w == 0 or h == 0:
        return 0.0
    pad = max(ring_px, reach_px) + 2
    y0, y1 = max(0, y - pad), min(mask.shape[0], y + h + pad)
    x0, x1 = max(0, x - pad), min(mask.shape[1], x + w + pad)
    roi = binary[y0:y1, x0:x1]
    outer = cv2.dilate(roi, square_kernel(2 * ring_px + 3))
    inner = cv2.dilate(roi, square_kernel(3))
    ring = (outer > 0) & (inner == 0)
    depth = depth_m[y0:y1, x0:x1]
    surface = surface_m[y0:y1, x0:x1] if isinstance(surface_m, np.ndarray) else surface_m
    valid = np.isfinite(depth) & (depth > 0)
    occluder = _occluder_map(depth, valid, surface, reach_px)
    known = np.count_nonzero(ring & (valid | occluder))
    if known == 0:
        return 0.0
    return float(np.count_nonzero(ring & occluder) / known)


@functools.lru_cache(maxsize=32)
def square_kernel(size_px: int) -> np.ndarray:
    """A square structuring element of ones, ``size_px`` wide (memoised, so read-only)."""
    kernel = np.ones((size_px, size_px), np.uint8)
    kernel.setflags(write=False)
    return kernel


def occluder_map(depth_m: np.ndarray, surface_m: np.ndarray | float, reach_px: int) -> np.ndarray:
    """Pixels taken by something in front of a surface: valid depth closer than ``surface_m``
    by :data:`CLOSER_MARGIN_M`, and invalid depth within ``reach_px`` of such (a depth
    camera's dropout along an occluder's edge)."""
    return _occluder_map(depth_m, np.isfinite(depth_m) & (depth_m > 0), surface_m, reach_px)


def _occluder_map(
    depth_m: np.ndarray, valid: np.ndarray, surface_m: np.ndarray | float, reach_px: int
) -> np.ndarray:
    """:func:`occluder_map`, given which depth pixels are ``valid`` (finite, positive)."""
    closer = valid & (depth_m < surface_m - CLOSER_MARGIN_M)
    near_closer = cv2.dilate(binary_u8(closer), square_kernel(2 * reach_px + 1)) > 0
    return closer | (~valid & near_closer)


def is_occluded(
    depth_m: np.ndarray,
    mask: np.ndarray,
    surface_m: np.ndarray | float,
    reach_px: int = RING_WIDTH_PX,
) -> bool:
    """Something in front of the marker borders it (see :func:`occluder_fraction`).
    ``reach_px`` should reach past the band of invalid depth a depth camera leaves along an
    occluder's edge (a few pixels on a Kinect)."""
    return occluder_fraction(depth_m, mask, surface_m, reach_px) > OCCLUDED_FRACTION


UNCOVERED_MIN_FRACTION = 0.1  # less of the old place left uncovered: all of it is hidden
UNCOVERED_COLOUR_FRACTION = 0.5  # a marker partly hidden still shows its colour where uncovered


def hidden_behind(
    depth_m: np.ndarray, region: np.ndarray, marker_depth_m: np.ndarray, colour: np.ndarray
) -> bool:
    """Is a marker that vanished from ``region`` (where it was last seen, at
    ``marker_depth_m`` per pixel) hidden by something in front, rather than gone?

    ``depth_m``, ``region`` (0/255), ``marker_depth_m`` and ``colour`` (0/255: pixels of the
    marker's colour) are crops of the same size. Something is in front where the depth is now
    clearly closer than the marker's surface was. Where the old place is uncovered and still at
    the marker's depth, a marker still lying there would show its colour: if it does not, the
    marker is gone (taken away, covered up). Where it is uncovered but farther, the object has
    slid away from there, and since the marker is seen nowhere, it is under what is in front.
    False when nothing closer is there, or the depth cannot tell.
    """
    inside = (region > 0) & np.isfinite(depth_m) & (depth_m > 0)
    n_valid = int(np.count_nonzero(inside))
    if n_valid == 0:
        return False
    closer = inside & (depth_m < marker_depth_m - CLOSER_MARGIN_M)
    if np.count_nonzero(closer) <= OCCLUDED_FRACTION * n_valid:
        return False
    same = inside & ~closer & (depth_m <= marker_depth_m + CLOSER_MARGIN_M)
    n_same = int(np.count_nonzero(same))
    if n_same < UNCOVERED_MIN_FRACTION * n_valid:
        return True
    shows_colour = np.count_nonzero(same & (colour > 0)) / n_same
    return shows_colour >= UNCOVERED_COLOUR_FRACTION
