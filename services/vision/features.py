"""Marker detection for the vision service: colour mask → square corners → corner depths.

Pure functions on numpy arrays (no networking, no global state). Conventions:

- Images are RGB ``uint8`` (H, W, 3) in RGB channel order; depth is ``float32`` (H, W), Z along
  the optical axis in metres, with 0 or non-finite meaning "no measurement".
- Pixel ``(u, v)``: column, row; pixel centres sit at integer coordinates (OpenCV style, see
  :mod:`common.camera`). A renderer without anti-aliasing marks a pixel when its CENTRE is
  inside a polygon; the corners returned here estimate the TRUE polygon vertices under that
  model, not the outermost pixel centres (which lie up to one pixel inside).
- Corner order is canonical (:func:`order_corners`): clockwise in the image, starting at the
  top-left corner, or following the previous frame's order when one is given.

Pipeline per marker: :func:`segment` (colour threshold + morphology) → :func:`square_corners`
(largest blob, rough quadrilateral, one straight edge estimated per side, adjacent edges
intersected) → :func:`corner_depths` (plane fitted to the depth inside the eroded blob,
corner rays intersected with it) → :mod:`services.vision.occlusion` (something in front of
the outline?). :func:`measure_markers` does this for both markers on a frame; for speed it
thresholds colour at full resolution only around each marker (found on a half-resolution
image) and refines both markers' edges in one numpy batch, with the same results.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from common.camera import CameraIntrinsics, back_project, pixel_to_normalized
from common.config import VisionConfig
from common.messages import is_usable
from common.metrics import percentile
from services.vision.occlusion import RING_WIDTH_PX, is_occluded

FloatArray = NDArray[np.float64]
Color = Literal["red", "green"]
Roi = tuple[slice, slice]  # rows, columns of an image region

MARKERS: dict[str, Color] = {"hand": "green", "target": "red"}

# --- tuning constants (geometry of a clean, non-anti-aliased rendering) -----------------------
MORPH_KERNEL = np.ones((3, 3), np.uint8)  # square: leaves straight digital edges untouched
COARSE_STEP = 2  # colour is first thresholded on every 2nd pixel to find each marker...
ROI_PAD_PX = 8  # ...then at full resolution in its bounding box grown by this margin
# A marker seen last frame is first looked for in a window around its last corners: their box
# grown by this fraction of its longer side, and by at least TRACK_MARGIN_MIN_PX (how far it
# may have moved since); anywhere in the image when it is not found well inside the window.
TRACK_MARGIN_FRACTION = 0.5
TRACK_MARGIN_MIN_PX = 16
APPROX_EPSILON_FRACTIONS = (0.01, 0.02, 0.03, 0.05, 0.08)  # of the hull perimeter
MIN_CORNER_ANGLE_RAD = math.radians(20.0)  # sharper or flatter: not a square in perspective
MAX_CORNER_ANGLE_RAD = math.radians(165.0)
CORNER_EXCLUSION_PX = 3.0  # contour points this close to a rough corner are not fitted...
CORNER_EXCLUSION_FRACTION = 0.1  # ...nor those within this fraction of the side length...
CORNER_EXCLUSION_ACUTE_PX = 2.0  # ...nor, at a corner of angle θ, within this / tan(θ/2)
MIN_POINTS_PER_SIDE = 4
MAX_SIDE_RESIDUAL_PX = 1.2  # straight digital edges measured: ≤ 0.93 px (p99 0.6 px)
MAX_CORNER_SHIFT_PX = 6.0  # refined vs rough corner: farther means the fit went wrong
PREIMAGE_MAX_SLOPE = 0.25  # edge slope search range about the fitted line (≈ rad)
DEPTH_ERODE_FRACTION = 0.1  # erosion radius as a fraction of the blob side...
DEPTH_ERODE_MIN_PX = 2  # ...but at least this many pixels
DEPTH_MIN_PLANE_PIXELS = 20  # fewer valid pixels: use their median depth instead of a plane
DEPTH_MIN_PIXELS = 3  # fewer: no depth at all
DEPTH_MAX_PLANE_PIXELS = 400  # about this many samples on a grid: plenty for a plane, fast
DEPTH_OUTLIER_SIGMAS = 3.0
DEPTH_OUTLIER_MIN_M = 0.001  # plane residuals below this are never outliers
DEPTH_GATE_MIN_M = 0.01  # depths this close to the median are never gross outliers
MAD_TO_SIGMA = 1.4826  # median absolute deviation → standard deviation for Gaussian noise


# Why a marker is not usable → its state (see common.messages.MarkerFeatures).
REASON_STATES: dict[str, str] = {
    "no blob": "lost",
    "blob too small": "partial",  # a sliver of it shows
    "touches image border": "partial",
    "not a quadrilateral": "partial",
    "occluded": "partial",
    "not the marker's size": "partial",
    "no valid depth": "no_depth",
    "no depth image": "no_depth",
    "depth image too old": "no_depth",
}


@dataclass(frozen=True)
class PlaneFit:
    """A plane seen by the depth camera, as inverse depth linear in normalized coordinates:
    ``1/Z = c · (x, y, 1)`` (exact for a plane: ``n·P = d`` with ``P = Z·(x, y, 1)``), with the
    least-squares covariance of ``c``, so depth and its uncertainty follow for any ray."""

    coefficients: FloatArray  # (3,) in 1/m
    covariance: FloatArray  # (3, 3) in 1/m²

    def depths_m(self, xy: FloatArray) -> FloatArray:
        rays = np.column_stack([np.asarray(xy, dtype=float), np.ones(len(xy))])
        return 1.0 / (rays @ self.coefficients)

    def shifted(self, shift_m: FloatArray) -> PlaneFit:
        """The same plane translated by ``shift_m`` (camera frame): ``n·P = d`` becomes
        ``n·P = d + n·shift``, i.e. ``c' = c / (1 + c·shift)``; the covariance is kept."""
        return PlaneFit(
            self.coefficients / (1.0 + float(self.coefficients @ shift_m)), self.covariance
        )

    def depth_sigmas_m(self, xy: FloatArray) -> FloatArray:
        """1-σ of the plane's depth along each ray: σ(1/Z)·Z², σ(1/Z)² = φᵀ·C·φ."""
        rays = np.column_stack([np.asarray(xy, dtype=float), np.ones(len(xy))])
        inverse_var = np.einsum("ij,jk,ik->i", rays, self.covariance, rays)
        return np.sqrt(np.maximum(inverse_var, 0.0)) * self.depths_m(xy) ** 2


@dataclass(frozen=True)
class MarkerMeasurement:
    """One marker in one frame.

    ``corners_px`` (4, 2) sub-pixel (u, v) in canonical order; ``depths_m`` (4,) Z of each
    corner (m) and ``depth_sigmas_m`` (4,) its 1-σ uncertainty; ``points_m`` (4, 3) corners in
    the camera optical frame (m); ``area_px`` the blob's pixel count (0 when there is no blob);
    ``plane`` the depth plane the depths come from (None when they do not come from a fit).
    ``state``: "visible", or why not (see :data:`REASON_STATES`, ``reason`` says which);
    when not visible the arrays are zeros, unless ``fitted``: a partly hidden marker whose
    corners were found from its visible edges, known size and plane
    (:mod:`services.vision.partial`). ``occluded``: something is seen in front of it.
    """

    state: str
    corners_px: FloatArray
    depths_m: FloatArray
    depth_sigmas_m: FloatArray
    points_m: FloatArray
    area_px: float
    reason: str
    occluded: bool = False
    plane: PlaneFit | None = None
    fitted: bool = False

    @property
    def visible(self) -> bool:
        return self.state == "visible"

    @property
    def usable(self) -> bool:
        """Corners and depths can be acted on: seen whole, or fitted from what is seen."""
        return is_usable(self.state, self.fitted)


def not_visible(reason: str, area_px: float = 0.0, occluded: bool = False) -> MarkerMeasurement:
    """A marker that cannot be used, for ``reason`` (a key of :data:`REASON_STATES`)."""
    return MarkerMeasurement(
        state=REASON_STATES[reason],
        corners_px=np.zeros((4, 2)),
        depths_m=np.zeros(4),
        depth_sigmas_m=np.zeros(4),
        points_m=np.zeros((4, 3)),
        area_px=float(area_px),
        reason=reason,
        occluded=occluded,
    )


# --- segmentation ------------------------------------------------------------------------------
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
    _check_rgb(rgb)
    return _open_close(_threshold(_threshold_space(rgb, cfg), color, cfg))


def _check_rgb(rgb: np.ndarray) -> None:
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"expected an RGB uint8 (H, W, 3) image, got {rgb.dtype} {rgb.shape}")


def _coarse_image(rgb: np.ndarray, cfg: VisionConfig) -> np.ndarray:
    """Every COARSE_STEP-th pixel, in the threshold colour space (4× fewer pixels to convert).
    Of an even-sized image or window, the pixels at multiples of COARSE_STEP from its start."""
    h, w = rgb.shape[:2]
    size = ((w + COARSE_STEP - 1) // COARSE_STEP, (h + COARSE_STEP - 1) // COARSE_STEP)
    return _threshold_space(cv2.resize(rgb, size, interpolation=cv2.INTER_NEAREST), cfg)


def _tracking_window(corners_px: FloatArray | None, shape: tuple[int, ...]) -> Roi | None:
    """Where to look first for a marker whose last corners were ``corners_px`` (see
    TRACK_MARGIN_FRACTION), inside the image. It starts on the coarse grid and spans a multiple
    of COARSE_STEP, so that its coarse pixels are those of the whole image (of an even size:
    cv2.resize samples an odd one slightly differently). None: no corners, or none inside."""
    if corners_px is None:
        return None
    low, high = corners_px.min(axis=0), corners_px.max(axis=0)
    margin = max(TRACK_MARGIN_MIN_PX, TRACK_MARGIN_FRACTION * float(np.max(high - low)))

    def span(lo: float, hi: float, size: int) -> slice:
        """[lo - margin, hi + margin] out to the coarse grid, clipped to its whole steps."""
        usable = size - size % COARSE_STEP
        start = min(max(math.floor((lo - margin) / COARSE_STEP) * COARSE_STEP, 0), usable)
        stop = min(max(math.ceil((hi + margin) / COARSE_STEP) * COARSE_STEP, start), usable)
        return slice(start, stop)

    rows, cols = span(low[1], high[1], shape[0]), span(low[0], high[0], shape[1])
    return (rows, cols) if rows.stop > rows.start and cols.stop > cols.start else None


def _blob_region(
    coarse: np.ndarray,
    color: Color,
    cfg: VisionConfig,
    shape: tuple[int, ...],
    window: Roi | None = None,
) -> Roi | None:
    """The region (full resolution, in an image of ``shape``) of the largest coarse blob of the
    colour: its bounding box grown by ROI_PAD_PX. None: no blob. ``coarse``: the whole image's
    :func:`_coarse_image`, or ``window``'s; then None also when the blob reaches an edge of the
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


def _marker_mask(
    rgb: np.ndarray, region: Roi | None, color: Color, cfg: VisionConfig
) -> tuple[np.ndarray, Roi]:
    """Full-size 0/255 mask equal to :func:`segment` in ``region`` (the largest coarse blob's,
    :func:`_blob_region`) and 0 elsewhere (so the largest blob is the same, at a fraction of
    the cost), and that region (empty: none)."""
    mask = np.zeros(rgb.shape[:2], np.uint8)
    if region is None:
        return mask, (slice(0, 0), slice(0, 0))
    mask[region] = segment(rgb[region], color, cfg)
    return mask, region


def _marker_masks(
    rgb: np.ndarray, cfg: VisionConfig, previous: dict[str, np.ndarray]
) -> list[tuple[np.ndarray, Roi]]:
    """Each marker's :func:`_marker_mask`, its blob looked for in its tracking window when it was
    seen last frame (the same region as from the whole image when the blob is well inside the
    window; the whole image's colour conversion is then skipped), else in the whole image."""
    whole: np.ndarray | None = None  # the whole image's coarse pixels, made when first needed
    masks = []
    for name, color in MARKERS.items():
        window = _tracking_window(previous.get(name), rgb.shape)
        region = None
        if window is not None:
            coarse = _coarse_image(rgb[window], cfg)
            region = _blob_region(coarse, color, cfg, rgb.shape, window)
        if region is None:
            whole = _coarse_image(rgb, cfg) if whole is None else whole
            region = _blob_region(whole, color, cfg, rgb.shape)
        masks.append(_marker_mask(rgb, region, color, cfg))
    return masks


# --- corner ordering ---------------------------------------------------------------------------
def _canonical_order(pts: list[list[float]], previous: list[list[float]] | None) -> list[int]:
    """Permutation of 4 points (plain lists) into the canonical order of :func:`order_corners`
    (4 points: plain Python is faster than numpy here)."""
    cu, cv = sum(p[0] for p in pts) / 4.0, sum(p[1] for p in pts) / 4.0
    angles = [math.atan2(v - cv, u - cu) for u, v in pts]
    clockwise = sorted(range(4), key=angles.__getitem__)
    if previous is None:

        def cost(s: int) -> float:  # angle of the first corner away from the top-left
            return abs(math.remainder(angles[clockwise[s]] + 0.75 * math.pi, 2.0 * math.pi))

    else:

        def cost(s: int) -> float:  # squared distances to the previous frame's corners
            return sum(math.dist(pts[clockwise[(s + i) % 4]], previous[i]) ** 2 for i in range(4))

    start = min(range(4), key=cost)
    return [clockwise[(start + i) % 4] for i in range(4)]


def order_corners(corners_px: np.ndarray, previous_px: np.ndarray | None = None) -> np.ndarray:
    """Reorder 4 corners (4, 2) canonically; returns a new (4, 2) float64 array.

    Corners are sorted clockwise in the image (v points down, so by increasing
    ``atan2(v - v_c, u - u_c)`` about the centroid). Without ``previous_px`` the first corner
    is the one whose direction from the centroid is closest to the image's top-left direction
    (-3π/4). With ``previous_px`` (the same marker's corners in the previous frame, canonical
    order) the cyclic shift closest to it (least sum of squared distances) is chosen instead,
    so the labelling follows the physical corners as the square rotates past 45°.
    """
    c = np.asarray(corners_px, dtype=float).reshape(4, 2)
    previous = (
        None if previous_px is None else np.asarray(previous_px, float).reshape(4, 2).tolist()
    )
    return c[_canonical_order(c.tolist(), previous)]


# --- quadrilateral checks ----------------------------------------------------------------------
def _interior_angles_rad(quad_px: FloatArray) -> list[float]:
    q = np.asarray(quad_px, dtype=float).tolist()
    angles = []
    for i in range(4):
        (pu, pv), (u, v), (nu, nv) = q[i - 1], q[i], q[(i + 1) % 4]
        a = math.atan2(pv - v, pu - u) - math.atan2(nv - v, nu - u)
        angles.append(abs(math.remainder(a, 2.0 * math.pi)))
    return angles


def _is_plausible_quad(quad_px: FloatArray) -> bool:
    """Convex, with no needle-sharp or nearly flat corner, as a square seen in perspective."""
    q = np.asarray(quad_px, dtype=float).tolist()
    turns = []
    for i in range(4):
        (u0, v0), (u1, v1), (u2, v2) = q[i], q[(i + 1) % 4], q[(i + 2) % 4]
        turns.append((u1 - u0) * (v2 - v1) - (v1 - v0) * (u2 - u1))
    if not (all(t > 0 for t in turns) or all(t < 0 for t in turns)):
        return False
    return all(MIN_CORNER_ANGLE_RAD < a < MAX_CORNER_ANGLE_RAD for a in _interior_angles_rad(q))


# --- corners -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class _QuadResult:
    corners_px: FloatArray | None  # canonical order (no previous), or None with a reason
    reason: str
    area_px: float


def _blob_pixel_count(contour: np.ndarray) -> float:
    """Pixel count of a blob from its 8-connected outer contour (Pick's theorem, I + B).

    ``cv2.contourArea`` of the pixel-centre polygon is A = I + B/2 - 1, and the contour lists
    the B boundary pixels, so the count is A + B/2 + 1 (exact unless the blob has 1-px
    spurs, which are traversed twice). Holes are included, as the marker's own area should be.
    """
    return float(cv2.contourArea(contour)) + len(contour) / 2.0 + 1.0


def _touches_border(contour: np.ndarray, shape: tuple[int, ...]) -> bool:
    x, y, w, h = cv2.boundingRect(contour)
    return x <= 0 or y <= 0 or x + w >= shape[1] or y + h >= shape[0]


def _rough_quad(contour: np.ndarray) -> tuple[FloatArray, list[int]] | None:
    """4 vertices (~1 px, canonical order) of the blob's convex hull simplified with growing
    tolerance, and their indices in ``contour`` (N, 2); None if it has no 4-vertex form."""
    hull_index = cv2.convexHull(contour, returnPoints=False).ravel()
    hull = contour[hull_index]
    perimeter_px = cv2.arcLength(hull, True)
    for fraction in APPROX_EPSILON_FRACTIONS:
        approx = cv2.approxPolyDP(hull, fraction * perimeter_px, True)
        if len(approx) < 4:
            return None  # a triangle (or a sliver): it will not become a quadrilateral
        if len(approx) == 4:
            corners = approx.reshape(4, 2).tolist()
            order = _canonical_order(corners, None)
            # approxPolyDP keeps a subset of the hull points, which are contour points
            index_of = dict(zip(map(tuple, hull.tolist()), hull_index.tolist(), strict=True))
            return (
                np.array([corners[i] for i in order], dtype=float),
                [index_of[tuple(corners[i])] for i in order],
            )
    return None


def _side_runs(
    contour: np.ndarray, rough_px: FloatArray, corner_index: list[int]
) -> list[np.ndarray] | None:
    """Contour points (int32 (n, 2)) of each side i (rough corner i → i+1), in contour order,
    without those near the rough corners (only good to ~1 px and rounded by the morphology,
    more so when acute). None if the corners are not in contour order.

    An 8-connected digital edge advances one pixel along its dominant axis per point, so the
    point k steps from a corner lies k/m px away (m: largest component of the side's unit
    direction) and dropping ⌈r·m⌉ points drops exactly those within r px.
    """
    q = rough_px.tolist()
    sides = [(q[(i + 1) % 4][0] - q[i][0], q[(i + 1) % 4][1] - q[i][1]) for i in range(4)]
    lengths = [math.hypot(du, dv) for du, dv in sides]
    radius_px = [
        max(
            CORNER_EXCLUSION_PX,
            CORNER_EXCLUSION_FRACTION * min(lengths),
            CORNER_EXCLUSION_ACUTE_PX / math.tan(angle / 2.0),
        )
        for angle in _interior_angles_rad(rough_px)
    ]
    dominant = [max(abs(du), abs(dv)) / n for (du, dv), n in zip(sides, lengths, strict=True)]
    n = len(contour)

    def offsets(index: list[int]) -> list[int]:
        return [(i - index[0]) % n for i in index]

    if not offsets(corner_index)[1] < offsets(corner_index)[2] < offsets(corner_index)[3]:
        contour = contour[::-1]  # the contour runs the other way round: walk it backwards
        corner_index = [n - 1 - i for i in corner_index]
        if not offsets(corner_index)[1] < offsets(corner_index)[2] < offsets(corner_index)[3]:
            return None
    twice = np.concatenate([contour, contour])  # so that the last side need not wrap
    ends = [corner_index[0] + r for r in [*offsets(corner_index), n]]
    runs = []
    for i in range(4):
        first = ends[i] + math.ceil(radius_px[i] * dominant[i])
        last = ends[i + 1] - math.ceil(radius_px[(i + 1) % 4] * dominant[i])
        runs.append(twice[first : last + 1])
    return runs


@dataclass(frozen=True)
class _EdgeFits:
    """Total-least-squares lines ``normals[s]·p = offsets_px[s]`` of S sides."""

    normals: FloatArray  # (S, 2) unit, pointing out of the blob
    offsets_px: FloatArray  # (S,) already moved out by half a lattice step
    centres_px: FloatArray  # (S, 2) centroid of each side's points
    max_residual_px: FloatArray  # (S,) largest distance of a point from its side's line


def _fit_edges_tls(
    points: np.ndarray, side: np.ndarray, starts: np.ndarray, inward_px: FloatArray
) -> _EdgeFits:
    """Lines behind the boundary pixel centres of S sides (``points`` (N, 2), grouped by side,
    ``side`` (N,) their side index, ``starts`` (S,) where each side's points begin), normals
    pointing away from ``inward_px`` (S, 2).

    Total least squares gives the line through the pixel centres. The boundary pixels of a
    polygon rasterised by pixel-centre sampling lie between the true edge and one lattice
    step ``m = max(|n_u|, |n_v|)`` inside it (the largest projection of a 4-neighbour step
    on the normal: 1 px for an axis-aligned edge, 1/√2 for a diagonal one), on average m/2
    inside, so each line is moved out by m/2 (a flat 0.5 px would put corners of diagonal
    edges ~0.1 px outside). All sides at once, from per-side moments.
    """
    u, v = points[:, 0].astype(float), points[:, 1].astype(float)
    count = np.bincount(side)
    centres = np.column_stack([np.bincount(side, u), np.bincount(side, v)]) / count[:, None]
    du, dv = u - centres[side, 0], v - centres[side, 1]
    suu, svv, suv = (
        np.bincount(side, du * du),
        np.bincount(side, dv * dv),
        np.bincount(side, du * dv),
    )
    theta = 0.5 * np.arctan2(2.0 * suv, suu - svv)  # direction of largest spread: the edge
    normals = np.column_stack([-np.sin(theta), np.cos(theta)])
    normals *= np.sign(np.sum(normals * (centres - inward_px), axis=1) + 1e-300)[:, None]
    residuals = np.abs(du * normals[side, 0] + dv * normals[side, 1])
    max_residual_px = np.maximum.reduceat(residuals, starts)
    half_step_px = 0.5 * np.max(np.abs(normals), axis=1)
    offsets = np.sum(normals * centres, axis=1) + half_step_px
    return _EdgeFits(normals, offsets, centres, max_residual_px)


def _outside_neighbours(
    points: np.ndarray, side: np.ndarray, normals: FloatArray, mask: np.ndarray
) -> list[np.ndarray]:
    """Per side, the 4-neighbours one step out along the normal's dominant axis of its
    boundary pixels (outside the blob for a straight edge), keeping those the mask says
    are outside."""
    dominant_u = np.abs(normals[:, 0]) >= np.abs(normals[:, 1])
    steps = np.where(dominant_u[:, None], [[1, 0]], [[0, 1]]) * np.sign(normals).astype(np.int32)
    outside = points + steps[side].astype(np.int32)
    keep = mask[outside[:, 1], outside[:, 0]] == 0
    kept_side = side[keep]
    return np.split(outside[keep], np.searchsorted(kept_side, np.arange(1, len(normals))))


def _padded_hulls(point_sets: list[np.ndarray]) -> np.ndarray:
    """(S, K, 2) float convex-hull vertices of S int32 point sets, each padded to K points by
    repeating its first vertex (a repeated point changes no envelope)."""
    hulls = [cv2.convexHull(p).reshape(-1, 2) for p in point_sets]
    out = np.empty((len(hulls), max(len(h) for h in hulls), 2))
    for i, h in enumerate(hulls):
        out[i, : len(h)] = h
        out[i, len(h) :] = h[0]
    return out


@functools.lru_cache(maxsize=64)
def _pair_indices(n: int) -> np.ndarray:
    """Flat indices into an n×n matrix of its n·(n-1)/2 entries above the diagonal
    (memoised: pure, and np.triu_indices is slow for its size)."""
    i, j = np.triu_indices(n, 1)
    return i * n + j


def _preimage_centroids(inside: np.ndarray, outside: np.ndarray) -> tuple[FloatArray, ...]:
    """Centroid (α, β) of the lines ``t = α·s + β`` that keep every inside pixel centre on or
    below them and every outside one on or above, for S edges at once (s along the edge, t
    outwards, px; ``inside`` (S, K, 2), ``outside`` (S, K', 2) hull vertices).

    This "preimage" of a digital edge is the exact set of edges that rasterise to the
    observed pixels; its centroid is the least-squares-optimal estimate under a flat prior.
    It beats the fitted line where the staircase has only a step or two (edges within a few
    degrees of a lattice direction) but cannot remove the up-to-one-step ambiguity of an edge
    exactly parallel to one. The region lies between the convex L(α) = max(t_i − α s_i) and
    the concave U(α) = min(t_j − α s_j), piecewise linear with breakpoints among the slopes
    between hull vertices, so integrating over those breakpoints is exact. (Written with
    few, batched numpy calls: on these tiny arrays the per-call overhead is the cost.)

    Returns (α, β, ok): ok is False where the region is empty (pixels not from one straight
    edge, or a renderer that does not sample at pixel centres) or unbounded.
    """
    n_edges, limit = len(inside), PREIMAGE_MAX_SLOPE
    both = np.concatenate([inside, outside], axis=1)
    n = both.shape[1]
    diff = (both[:, :, None, :] - both[:, None, :, :]).reshape(n_edges, n * n, 2)
    ds, dt = diff[:, _pair_indices(n), 0], diff[:, _pair_indices(n), 1]
    valid = np.abs(dt) < limit * np.abs(ds)  # |slope| < limit, and ds ≠ 0
    alphas = np.empty((n_edges, ds.shape[1] + 2))
    alphas[:, :-2] = np.where(valid, dt / np.where(valid, ds, 1.0), limit)  # repeats harmless
    alphas[:, -2:] = (-limit, limit)
    alphas.sort(axis=1)
    lower = np.maximum.reduce(inside[:, :, 1:2] - inside[:, :, 0:1] * alphas[:, None, :], axis=1)
    upper = np.minimum.reduce(outside[:, :, 1:2] - outside[:, :, 0:1] * alphas[:, None, :], axis=1)
    gap = upper - lower
    feasible = gap >= -1e-9  # U − L is concave: the feasible α form an interval
    lo = np.minimum.reduce(np.where(feasible, alphas, np.inf), axis=1)
    hi = np.maximum.reduce(np.where(feasible, alphas, -np.inf), axis=1)
    span = (alphas >= lo[:, None]) & (alphas <= hi[:, None])
    # width; a tiny floor keeps a zero-width preimage (a segment of lines) well defined
    w = np.where(span, np.maximum(gap, 0.0) + 1e-12, 0.0)
    f = np.stack([np.ones_like(alphas), alphas, 0.5 * (upper + lower)])  # 1, α, middle β
    da = np.diff(alphas, axis=1) * (span[:, 1:] & span[:, :-1])
    f0, f1, w0, w1 = f[..., :-1], f[..., 1:], w[:, :-1], w[:, 1:]
    # ∫ f·w dα, exact for f and w linear between breakpoints (×6)
    moments = np.add.reduce(da * ((2 * f0 + f1) * w0 + (f0 + 2 * f1) * w1), axis=-1)
    ok = (lo > -limit) & (hi < limit) & (moments[0] > 0)  # bounded, non-empty, not a point
    area = np.where(ok, moments[0], 1.0)
    return moments[1] / area, moments[2] / area, ok


@dataclass(frozen=True)
class _Blob:
    """A blob that passed the cheap checks, its sides ready for sub-pixel refinement."""

    rough_px: FloatArray  # (4, 2) canonical order
    runs: list[np.ndarray]  # per side, its boundary pixels away from the corners, int32 (n, 2)
    mask: np.ndarray
    area_px: float


def _edge_lines(blobs: list[_Blob]) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Edge lines ``normals[s]·p = offsets[s]`` (outward unit normals, px) of the 4 sides of
    every blob, batched (numpy's per-call overhead dominates on these small arrays), and
    each side's largest TLS residual (px, to reject sides that are not straight).

    Each line is the preimage centroid expressed in the frame of the side's total-least-
    squares line, or that line moved out by half a lattice step where the preimage is empty.
    """
    runs = [run for blob in blobs for run in blob.runs]
    counts = [len(run) for run in runs]
    points = np.concatenate(runs)
    side = np.repeat(np.arange(len(runs)), counts)
    starts = np.cumsum([0, *counts[:-1]])
    inward = np.repeat([blob.rough_px.mean(axis=0) for blob in blobs], 4, axis=0)
    fits = _fit_edges_tls(points, side, starts, inward)
    outside_runs = []
    for b, blob in enumerate(blobs):  # each blob has its own mask
        mine = slice(starts[4 * b], starts[4 * b] + sum(counts[4 * b : 4 * b + 4]))
        normals = fits.normals[4 * b : 4 * b + 4]
        outside_runs += _outside_neighbours(points[mine], side[mine] - 4 * b, normals, blob.mask)
    # a side with too few outside pixels to bound its edge keeps its TLS line
    unbounded = np.array([len(o) < 2 for o in outside_runs])
    outside_runs = [r if len(o) < 2 else o for r, o in zip(runs, outside_runs, strict=True)]
    origins = fits.centres_px[:, None, :]
    alongs = np.column_stack([-fits.normals[:, 1], fits.normals[:, 0]])
    frames = np.stack([alongs, fits.normals], axis=2)  # (p - origin) @ frame = (s along, t out)
    alphas, betas, oks = _preimage_centroids(
        (_padded_hulls(runs) - origins) @ frames, (_padded_hulls(outside_runs) - origins) @ frames
    )
    # t = α·s + β in a side's frame is the line n'·p = c' with n' ∝ n − α·along
    norms = np.hypot(1.0, alphas)
    refined = (fits.normals - alphas[:, None] * alongs) / norms[:, None]
    refined_offsets = betas / norms + np.sum(refined * fits.centres_px, axis=1)
    oks &= ~unbounded
    normals = np.where(oks[:, None], refined, fits.normals)
    offsets = np.where(oks, refined_offsets, fits.offsets_px)
    return normals, offsets, fits.max_residual_px


def _intersect_lines(n1: FloatArray, c1: float, n2: FloatArray, c2: float) -> FloatArray | None:
    det = n1[0] * n2[1] - n1[1] * n2[0]
    if abs(det) < math.sin(MIN_CORNER_ANGLE_RAD / 2.0):  # near-parallel sides
        return None
    return np.array([(c1 * n2[1] - c2 * n1[1]) / det, (n1[0] * c2 - n2[0] * c1) / det])


def _corners_from_lines(
    normals: FloatArray, offsets: list[float], rough_px: FloatArray
) -> FloatArray | None:
    """Corner i = side (i-1) ∩ side i; None if two sides are nearly parallel or meet far from
    the rough corner (the fit went wrong)."""
    corners = np.empty((4, 2))
    for i in range(4):
        p = _intersect_lines(normals[i - 1], offsets[i - 1], normals[i], offsets[i])
        if p is None or math.dist(p, rough_px[i]) > MAX_CORNER_SHIFT_PX:
            return None
        corners[i] = p
    return corners


def _blob_candidate(mask: np.ndarray, min_area_px: int, roi: Roi | None) -> _Blob | _QuadResult:
    """The largest blob of ``mask`` if it passes the cheap checks, else the failed result.
    ``roi``: the part of the mask that can be non-zero (searched alone, for speed)."""
    rows, cols = roi if roi is not None else (slice(0, mask.shape[0]), slice(0, mask.shape[1]))
    contours, _ = cv2.findContours(
        mask[rows, cols], cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE, offset=(cols.start, rows.start)
    )
    if not contours:
        return _QuadResult(None, "no blob", 0.0)
    contour = max(contours, key=cv2.contourArea)
    area_px = _blob_pixel_count(contour)
    if area_px < min_area_px:
        return _QuadResult(None, "blob too small", area_px)
    if _touches_border(contour, mask.shape):
        return _QuadResult(None, "touches image border", area_px)
    contour = contour.reshape(-1, 2)
    rough = _rough_quad(contour)
    runs = None
    if rough is not None and _is_plausible_quad(rough[0]):
        runs = _side_runs(contour, *rough)
    if runs is None or min(len(run) for run in runs) < MIN_POINTS_PER_SIDE:
        return _QuadResult(None, "not a quadrilateral", area_px)
    return _Blob(rough[0], runs, mask, area_px)


def _find_quads(masks: list[tuple[np.ndarray, Roi | None]], min_area_px: int) -> list[_QuadResult]:
    """The largest blob of each mask as a sub-pixel quadrilateral, or None with the reason.

    Corners: one edge line per side from its boundary pixels away from the rough corners,
    adjacent lines intersected. Rejected if a side is not straight or the refined corners do
    not form a plausible quadrilateral. All blobs' sides are refined in one batch.
    """
    candidates = [_blob_candidate(mask, min_area_px, roi) for mask, roi in masks]
    blobs = [c for c in candidates if isinstance(c, _Blob)]
    if not blobs:
        return [c for c in candidates if isinstance(c, _QuadResult)]
    normals, offsets, residuals = _edge_lines(blobs)
    offsets, residuals = offsets.tolist(), residuals.tolist()
    results, b = [], 0
    for candidate in candidates:
        if isinstance(candidate, _QuadResult):
            results.append(candidate)
            continue
        sides = slice(4 * b, 4 * b + 4)
        b += 1
        corners = None
        if max(residuals[sides]) <= MAX_SIDE_RESIDUAL_PX:
            corners = _corners_from_lines(normals[sides], offsets[sides], candidate.rough_px)
        if corners is None or not _is_plausible_quad(corners):
            results.append(_QuadResult(None, "not a quadrilateral", candidate.area_px))
        else:
            results.append(_QuadResult(order_corners(corners), "", candidate.area_px))
    return results


def square_corners(mask: np.ndarray, min_area_px: int) -> np.ndarray | None:
    """Sub-pixel corners (4, 2) float64 (u, v) of the largest blob of a 0/255 uint8 mask.

    The corners estimate the vertices of the rendered polygon (pixel-centre sampling), in
    canonical order (:func:`order_corners` without a previous frame). None when there is no
    blob, it has fewer than ``min_area_px`` pixels, touches the image border, or is not a
    convex quadrilateral with straight sides.
    """
    return _find_quads([(mask, None)], min_area_px)[0].corners_px


# --- depth -------------------------------------------------------------------------------------
def _bounding_box(
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


def mask_bounds(mask: np.ndarray, pad_px: int) -> tuple[int, int, int, int] | None:
    """(row0, row1, col0, col1) of the non-zero pixels of ``mask`` grown by ``pad_px`` and
    clipped to it; None for an empty mask (cv2.boundingRect: far faster than np.nonzero)."""
    x, y, w, h = cv2.boundingRect(mask)
    if w == 0 or h == 0:
        return None
    rows, cols = mask.shape[:2]
    return (
        max(y - pad_px, 0),
        min(y + h + pad_px, rows),
        max(x - pad_px, 0),
        min(x + w + pad_px, cols),
    )


def _quad_area_px2(corners_px: FloatArray) -> float:
    q = corners_px.tolist()
    return 0.5 * abs(sum(q[i - 1][0] * q[i][1] - q[i][0] * q[i - 1][1] for i in range(4)))


def _marker_depth_pixels(
    depth_m: np.ndarray, mask: np.ndarray, corners_px: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """(uv (N, 2) px, Z (N,) m) of the valid depth pixels well inside the marker.

    Only the mask inside the corners' quadrilateral counts (other blobs stay out), eroded
    (radius 10 % of the side, at least 2 px) so that the outline and the pixels next to
    occluders, where depth jumps to what lies behind or in front, are dropped.
    """
    side_px = math.sqrt(max(_quad_area_px2(corners_px), 1.0))
    radius_px = max(DEPTH_ERODE_MIN_PX, round(DEPTH_ERODE_FRACTION * side_px))
    r0, r1, c0, c1 = _bounding_box(corners_px, 1, mask.shape)
    if r1 <= r0 or c1 <= c0:
        return np.zeros((0, 2)), np.zeros(0)
    quad = np.zeros((r1 - r0, c1 - c0), np.uint8)
    shift_bits = 4  # sub-pixel vertices for fillConvexPoly, 1/16 px
    vertices = np.round((corners_px - (c0, r0)) * (1 << shift_bits)).astype(np.int32)
    cv2.fillConvexPoly(quad, vertices, 255, cv2.LINE_8, shift_bits)
    inner = cv2.erode(
        cv2.bitwise_and(quad, mask[r0:r1, c0:c1]),
        cv2.getStructuringElement(cv2.MORPH_RECT, (2 * radius_px + 1, 2 * radius_px + 1)),
        borderType=cv2.BORDER_CONSTANT,
        borderValue=0,
    )
    # A regular grid of about DEPTH_MAX_PLANE_PIXELS samples is plenty for a plane; all
    # pixels only if that leaves too few (sparse depth).
    step = _grid_step(int(side_px * side_px))
    while True:
        z = depth_m[r0:r1:step, c0:c1:step]
        vv, uu = np.nonzero((inner[::step, ::step] > 0) & (z > 0) & (z < np.inf))  # NaN: neither
        if step == 1 or len(vv) >= DEPTH_MIN_PLANE_PIXELS:
            break
        step = 1
    uv = np.column_stack([uu * step + c0, vv * step + r0]).astype(float)
    return uv, z[vv, uu].astype(float)


def _grid_step(pixel_count: int) -> int:
    """Sampling step (px, both directions) that leaves about :data:`DEPTH_MAX_PLANE_PIXELS` of
    ``pixel_count`` pixels: plenty for a plane, and fast."""
    return max(1, math.isqrt(pixel_count // DEPTH_MAX_PLANE_PIXELS))


def _median(values: FloatArray) -> float:
    """Median (upper median for even sizes); np.partition is several times faster than
    np.median on these small arrays."""
    k = len(values) // 2
    return float(np.partition(values, k)[k])


def _outlier_threshold(values: FloatArray, floor: float) -> float:
    """max(3 robust σ (from the median absolute deviation), floor)."""
    sigma = MAD_TO_SIGMA * _median(np.abs(values - _median(values)))
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
    near = np.abs(z_m - _median(z_m)) <= _outlier_threshold(z_m, DEPTH_GATE_MIN_M)
    if np.count_nonzero(near) >= DEPTH_MIN_PLANE_PIXELS:
        xy, z_m = xy[near], z_m[near]
    if len(z_m) < DEPTH_MIN_PLANE_PIXELS:
        return None
    rays = np.column_stack([xy, np.ones(len(xy))])
    fit = _least_squares_plane(rays, 1.0 / z_m)
    if fit is None:
        return None
    residuals_m = z_m - 1.0 / (rays @ fit[0])
    inliers = np.abs(residuals_m) <= _outlier_threshold(residuals_m, DEPTH_OUTLIER_MIN_M)
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


def registered_mask(mask: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """A colour-resolution 0/255 mask at the depth image's resolution (pixels at least half
    covered), for a depth image registered to the colour one at a lower resolution."""
    if mask.shape[:2] == shape[:2]:
        return mask
    small = cv2.resize(mask, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
    return np.where(small >= 128, 255, 0).astype(np.uint8)


def to_depth_pixels(corners_px: FloatArray, k: CameraIntrinsics, k_depth: CameraIntrinsics):
    """Colour-image pixels → the registered depth image's pixels (same rays)."""
    xy = pixel_to_normalized(corners_px, k)
    return np.column_stack(
        [k_depth.fx_px * xy[:, 0] + k_depth.cx_px, k_depth.fy_px * xy[:, 1] + k_depth.cy_px]
    )


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
    resolution ``k_depth`` (default: the same). With fewer than 20 valid pixels (but at least
    3) all corners get the median depth and the samples' spread as uncertainty; with fewer than
    3, or a plane seen edge-on, the result is None.
    """
    corners = np.asarray(corners_px, dtype=float).reshape(4, 2)
    k_depth = k_depth or k
    depth_corners = corners if k_depth == k else to_depth_pixels(corners, k, k_depth)
    uv, z = _marker_depth_pixels(depth_m, registered_mask(mask, depth_m.shape), depth_corners)
    if len(z) < DEPTH_MIN_PIXELS:
        return None
    corner_xy = pixel_to_normalized(corners, k)
    plane = None
    if len(z) >= DEPTH_MIN_PLANE_PIXELS:
        plane = fit_inverse_depth_plane(pixel_to_normalized(uv, k_depth), z)
    if plane is None:
        if len(z) >= DEPTH_MIN_PLANE_PIXELS:
            return None  # enough samples, but no plane: seen edge-on
        depths = np.full(4, _median(z))
        sigmas = np.full(4, MAD_TO_SIGMA * _median(np.abs(z - _median(z))) / math.sqrt(len(z)))
    else:
        depths = plane.depths_m(corner_xy)
        sigmas = plane.depth_sigmas_m(corner_xy)
    if not np.all((depths > 0) & (depths < np.inf)):
        return None
    return CornerDepths(depths, sigmas, back_project(corners, depths, k), plane)


# --- per frame ---------------------------------------------------------------------------------
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
        occluded = quad.area_px > 0 and _blob_occluded(quad.mask, depth_m, k_depth or k, ring_px)
        return not_visible(quad.reason, quad.area_px, occluded)
    corners, mask = quad.corners_px, quad.mask
    depth = corner_depths(depth_m, mask, corners, k, k_depth)
    if depth is None:
        return not_visible("no valid depth", quad.area_px)
    k_depth = k_depth or k
    depth_corners = corners if k_depth == k else to_depth_pixels(corners, k, k_depth)
    bounds = _bounding_box(depth_corners, ring_px + 3, depth_m.shape)
    r0, r1, c0, c1 = bounds
    crop_mask = registered_mask(mask, depth_m.shape)[r0:r1, c0:c1]
    surface = marker_surface(depth.plane, depth.depths_m, k_depth, bounds)
    if is_occluded(depth_m[r0:r1, c0:c1], crop_mask, surface, ring_px):
        return not_visible("occluded", quad.area_px, occluded=True)
    return MarkerMeasurement(
        "visible",
        corners,
        depth.depths_m,
        depth.sigmas_m,
        depth.points_m,
        quad.area_px,
        "",
        plane=depth.plane,
    )


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


def _blob_occluded(
    mask: np.ndarray, depth_m: np.ndarray, k_depth: CameraIntrinsics, ring_px: int
) -> bool:
    """Is something in front of a blob that did not make a whole square? The ring around it
    against the plane of its own depth (else its nearest depth: a tilted marker spans
    centimetres)."""
    small = registered_mask(mask, depth_m.shape)
    bounds = mask_bounds(small, ring_px + 3)
    if bounds is None:
        return False
    r0, r1, c0, c1 = bounds
    crop_mask, crop_depth = small[r0:r1, c0:c1], depth_m[r0:r1, c0:c1]
    eroded = cv2.erode(crop_mask, MORPH_KERNEL)
    step = _grid_step(cv2.countNonZero(eroded))
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
    _check_rgb(rgb)
    expected = rgb.shape[:2] if k_depth is None else (k_depth.height_px, k_depth.width_px)
    if depth_m.shape != expected:
        raise ValueError(f"depth {depth_m.shape} does not match the expected {expected}")


def measure_marker(
    rgb: np.ndarray,
    depth_m: np.ndarray,
    k: CameraIntrinsics,
    color: Color,
    cfg: VisionConfig,
    previous_corners_px: np.ndarray | None = None,
    k_depth: CameraIntrinsics | None = None,
) -> MarkerMeasurement:
    """Corners (px), corner depths (m) and 3-D corners (m, optical frame) of one marker, from a
    colour image and the depth image taken with it (``k_depth``: its intrinsics when its
    resolution differs).

    ``previous_corners_px``: the same marker's corners from the previous frame, to keep the
    corner labelling stable (see :func:`order_corners`).
    """
    _check_frame(rgb, depth_m, k_depth)
    region = _blob_region(_coarse_image(rgb, cfg), color, cfg, rgb.shape)
    mask, roi = _marker_mask(rgb, region, color, cfg)
    (quad,) = _find_quads([(mask, roi)], cfg.min_area_px)
    corners = quad.corners_px
    if corners is not None:
        corners = order_corners(corners, previous_corners_px)
    return _measure(
        MarkerQuad(corners, quad.reason, quad.area_px, mask),
        depth_m,
        k,
        k_depth,
        cfg.occlusion_ring_px,
    )


@dataclass(frozen=True)
class MarkerQuad:
    """A marker found in colour alone: corners (canonical order) or why not, and its mask."""

    corners_px: FloatArray | None
    reason: str
    area_px: float
    mask: np.ndarray


def find_marker_quads(
    rgb: np.ndarray, cfg: VisionConfig, previous: dict[str, np.ndarray] | None = None
) -> dict[str, MarkerQuad]:
    """Both markers in a colour image, keyed ``"hand"`` (green) and ``"target"`` (red);
    ``previous`` maps the same keys to last frame's corners (to keep their order)."""
    _check_rgb(rgb)
    previous = previous or {}
    masks = _marker_masks(rgb, cfg, previous)
    quads = _find_quads(masks, cfg.min_area_px)  # both markers' sides refined in one batch
    out = {}
    for name, quad, (mask, _) in zip(MARKERS, quads, masks, strict=True):
        corners = None
        if quad.corners_px is not None:
            corners = order_corners(quad.corners_px, previous.get(name))
        out[name] = MarkerQuad(corners, quad.reason, quad.area_px, mask)
    return out


def measure_markers(
    rgb: np.ndarray,
    depth_m: np.ndarray,
    k: CameraIntrinsics,
    cfg: VisionConfig,
    previous: dict[str, np.ndarray] | None = None,
    k_depth: CameraIntrinsics | None = None,
) -> dict[str, MarkerMeasurement]:
    """Both markers, keyed ``"hand"`` (green) and ``"target"`` (red), from a colour image and
    the depth image taken with it; ``previous`` maps the same keys to last frame's corners
    (missing keys: no previous)."""
    _check_frame(rgb, depth_m, k_depth)
    return {
        name: measure_quad(quad, depth_m, k, cfg, k_depth)
        for name, quad in find_marker_quads(rgb, cfg, previous).items()
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
