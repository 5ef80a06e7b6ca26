"""Colour segmentation of the two markers: threshold (HSV or RGB) and morphology, first on a
half-resolution image to find each marker, then at full resolution around it (or in last
frame's tracking window). Pure functions on RGB ``uint8`` images."""

from __future__ import annotations

import math
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from common.config import VisionConfig

FloatArray = NDArray[np.float64]
Color = Literal["red", "green"]
Roi = tuple[slice, slice]  # rows, columns of an image region

MARKERS: dict[str, Color] = {"hand": "green", "target": "red"}

MORPH_KERNEL = np.ones((3, 3), np.uint8)  # square: leaves straight digital edges untouched
COARSE_STEP = 2  # colour is first thresholded on every 2nd pixel to find each marker...
ROI_PAD_PX = 8  # ...then at full resolution in its bounding box grown by this margin
# A marker seen last frame is first looked for in a window around its last corners: their box
# grown by this fraction of its longer side, and by at least TRACK_MARGIN_MIN_PX (how far it
# may have moved since); anywhere in the image when it is not found well inside the window.
TRACK_MARGIN_FRACTION = 0.5
TRACK_MARGIN_MIN_PX = 16


def binary_u8(mask: np.ndarray) -> np.ndarray:
    """A uint8 array non-zero where ``mask`` is (what OpenCV's contours, morphology and boxes
    take): ``mask`` itself when uint8, a bool array's bytes (no copy), else ``mask > 0``."""
    if mask.dtype == np.uint8:
        return mask
    if mask.dtype == np.bool_:
        return mask.view(np.uint8)
    return (mask > 0).astype(np.uint8)


def _threshold_space(rgb: np.ndarray, cfg: VisionConfig) -> np.ndarray:
    """The image in the colour space ``cfg.segmentation`` thresholds: OpenCV HSV, or RGB."""
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV) if cfg.segmentation == "hsv" else rgb


def _threshold(image: np.ndarray, color: Color, cfg: VisionConfig) -> np.ndarray:
    """0/255 mask of an image already in :func:`_threshold_space`."""
    if cfg.segmentation == "hsv":
        ranges = cfg.red_hsv if color == "red" else cfg.green_hsv
        mask = cv2.inRange(
            image, np.array(ranges[0].lower, np.uint8), np.array(ranges[0].upper, np.uint8)
        )
        for r in ranges[1:]:  # red wraps around H = 0: several ranges, OR-ed
            mask |= cv2.inRange(image, np.array(r.lower, np.uint8), np.array(r.upper, np.uint8))
        return mask
    ref = np.array(cfg.red_rgb if color == "red" else cfg.green_rgb, dtype=int)
    lower = np.clip(ref - cfg.rgb_tolerance, 0, 255).astype(np.uint8)
    upper = np.clip(ref + cfg.rgb_tolerance, 0, 255).astype(np.uint8)
    return cv2.inRange(image, lower, upper)


def colour_mask(rgb: np.ndarray, color: Color, cfg: VisionConfig) -> np.ndarray:
    """0/255 mask of the pixels of a marker colour, without clean-up (for small crops)."""
    return _threshold(_threshold_space(np.ascontiguousarray(rgb), cfg), color, cfg)


def _open_close(mask: np.ndarray) -> np.ndarray:
    """3×3 opening then closing: drops isolated pixels and fills pinholes. With a square
    kernel a straight digital edge is left exactly as it was (a 3×3 block fits inside any
    digital half-plane next to each of its pixels); only corners are nibbled, and the corner
    fit ignores them."""
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, MORPH_KERNEL)
    return cv2.morphologyEx(mask, cv2.MORPH_CLOSE, MORPH_KERNEL)


def segment(rgb: np.ndarray, color: Color, cfg: VisionConfig) -> np.ndarray:
    """Binary mask (uint8, 0 or 255, shape (H, W)) of the pixels of one marker colour.

    ``cfg.segmentation == "hsv"``: OpenCV HSV (H 0..179) inside any of the colour's ranges,
    which tolerates the brightness changes of diffuse lighting. ``"rgb"``: every channel
    within ``cfg.rgb_tolerance`` of the reference colour (brightness-sensitive). Then a small
    morphological open/close.
    """
    check_rgb(rgb)
    return _open_close(_threshold(_threshold_space(rgb, cfg), color, cfg))


def check_rgb(rgb: np.ndarray) -> None:
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"expected an RGB uint8 (H, W, 3) image, got {rgb.dtype} {rgb.shape}")


def coarse_image(rgb: np.ndarray, cfg: VisionConfig) -> np.ndarray:
    """Every COARSE_STEP-th pixel, in the threshold colour space (4× fewer pixels to convert).
    Of an even-sized image or window, the pixels at multiples of COARSE_STEP from its start."""
    h, w = rgb.shape[:2]
    size = ((w + COARSE_STEP - 1) // COARSE_STEP, (h + COARSE_STEP - 1) // COARSE_STEP)
    return _threshold_space(cv2.resize(rgb, size, interpolation=cv2.INTER_NEAREST), cfg)


def tracking_window(corners_px: FloatArray | None, shape: tuple[int, ...]) -> Roi | None:
    """Where to look first for a marker whose last corners were ``corners_px`` (see
    TRACK_MARGIN_FRACTION), inside the image. It starts on the coarse grid and spans a multiple
    of COARSE_STEP, so that its coarse pixels are those of the whole image (of an even size:
    cv2.resize samples an odd one slightly differently). None: no corners, or none inside."""
    if corners_px is None:
        return None
    (u0, v0), (u1, v1) = corners_px.min(axis=0).tolist(), corners_px.max(axis=0).tolist()
    margin = max(TRACK_MARGIN_MIN_PX, TRACK_MARGIN_FRACTION * max(u1 - u0, v1 - v0))

    def span(lo: float, hi: float, size: int) -> slice:
        """[lo - margin, hi + margin] out to the coarse grid, clipped to its whole steps."""
        usable = size - size % COARSE_STEP
        start = min(max(math.floor((lo - margin) / COARSE_STEP) * COARSE_STEP, 0), usable)
        stop = min(max(math.ceil((hi + margin) / COARSE_STEP) * COARSE_STEP, start), usable)
        return slice(start, stop)

    rows, cols = span(v0, v1, shape[0]), span(u0, u1, shape[1])
    return (rows, cols) if rows.stop > rows.start and cols.stop > cols.start else None


def blob_region(
    coarse: np.ndarray,
    color: Color,
    cfg: VisionConfig,
    shape: tuple[int, ...],
    window: Roi | None = None,
) -> Roi | None:
    """The region (full resolution, in an image of ``shape``) of the largest coarse blob of the
    colour: its bounding box grown by ROI_PAD_PX. None: no blob. ``coarse``: the whole image's
    :func:`coarse_image`, or ``window``'s; then None also when the blob reaches an edge of the
    window that is not the image's (it may go on outside)."""
    contours, _ = cv2.findContours(
        _threshold(coarse, color, cfg), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE
    )
    if not contours:
        return None
    x, y, w, h = cv2.boundingRect(max(contours, key=cv2.contourArea))
    if window is not None:
        rows, cols = window
        if (
            (x == 0 and cols.start > 0)
            or (y == 0 and rows.start > 0)
            or (x + w == coarse.shape[1] and cols.stop < shape[1])
            or (y + h == coarse.shape[0] and rows.stop < shape[0])
        ):
            return None
        x, y = x + cols.start // COARSE_STEP, y + rows.start // COARSE_STEP
    return (
        slice(
            max(y * COARSE_STEP - ROI_PAD_PX, 0), min((y + h) * COARSE_STEP + ROI_PAD_PX, shape[0])
        ),
        slice(
            max(x * COARSE_STEP - ROI_PAD_PX, 0), min((x + w) * COARSE_STEP + ROI_PAD_PX, shape[1])
        ),
    )


def marker_mask(
    rgb: np.ndarray, region: Roi | None, color: Color, cfg: VisionConfig
) -> tuple[np.ndarray, Roi]:
    """Full-size 0/255 mask equal to :func:`segment` in ``region`` (the largest coarse blob's,
    :func:`blob_region`) and 0 elsewhere (so the largest blob is the same, at a fraction of
    the cost), and that region (empty: none)."""
    mask = np.zeros(rgb.shape[:2], np.uint8)
    if region is None:
        return mask, (slice(0, 0), slice(0, 0))
    mask[region] = segment(rgb[region], color, cfg)
    return mask, region


def marker_masks(
    rgb: np.ndarray, cfg: VisionConfig, previous: dict[str, np.ndarray]
) -> list[tuple[np.ndarray, Roi]]:
    """Each marker's :func:`marker_mask`, its blob looked for in its tracking window when it was
    seen last frame (the same region as from the whole image when the blob is well inside the
    window; the whole image's colour conversion is then skipped), else in the whole image.

    When a marker has no window the whole image is converted first, and the other's window
    cut from it (of an even-sized image, a window's coarse pixels are the whole image's)."""
    windows = [tracking_window(previous.get(name), rgb.shape) for name in MARKERS]
    whole: np.ndarray | None = None  # the whole image's coarse pixels, made when first needed
    even = rgb.shape[0] % COARSE_STEP == 0 and rgb.shape[1] % COARSE_STEP == 0
    if None in windows and even:
        whole = coarse_image(rgb, cfg)
    masks = []
    for color, window in zip(MARKERS.values(), windows, strict=True):
        region = None
        if window is not None:
            if whole is None or not even:  # cv2.resize samples an odd-sized image otherwise
                coarse = coarse_image(rgb[window], cfg)
            else:
                rows, cols = window
                coarse = whole[
                    rows.start // COARSE_STEP : rows.stop // COARSE_STEP,
                    cols.start // COARSE_STEP : cols.stop // COARSE_STEP,
                ]
            region = blob_region(coarse, color, cfg, rgb.shape, window)
        if region is None:
            whole = coarse_image(rgb, cfg) if whole is None else whole
            region = blob_region(whole, color, cfg, rgb.shape)
        masks.append(marker_mask(rgb, region, color, cfg))
    return masks


def mask_bounds(
    mask: np.ndarray, pad_px: int, region: Roi | None = None
) -> tuple[int, int, int, int] | None:
    """(row0, row1, col0, col1) of the non-zero pixels of ``mask`` grown by ``pad_px`` and
    clipped to it; None for an empty mask (cv2.boundingRect: far faster than np.nonzero).
    ``region``: the part of the mask that can be non-zero (searched alone, for speed)."""
    if region is None:
        x, y, w, h = cv2.boundingRect(mask)
    else:
        rows, cols = region
        x, y, w, h = cv2.boundingRect(mask[rows, cols])
        x, y = x + cols.start, y + rows.start
    if w == 0 or h == 0:
        return None
    rows, cols = mask.shape[:2]
    return (
        max(y - pad_px, 0),
        min(y + h + pad_px, rows),
        max(x - pad_px, 0),
        min(x + w + pad_px, cols),
    )
