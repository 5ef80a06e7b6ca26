"""A marker's square in a colour mask: the largest blob, a rough quadrilateral, one straight
edge estimated per side (sub-pixel, under pixel-centre sampling), adjacent edges intersected,
corners in canonical order. Pure functions.

A renderer without anti-aliasing marks a pixel when its CENTRE is inside a polygon; the
corners returned here estimate the TRUE polygon vertices under that model, not the outermost
pixel centres (which lie up to one pixel inside). Canonical order: clockwise in the image,
starting at the top-left corner, or following the previous frame's order when one is given.
"""

from __future__ import annotations

import functools
import itertools
import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from common.kinematics import centroid
from common.messages import quad_area
from services.vision.segmentation import Roi

FloatArray = NDArray[np.float64]

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
def _interior_angles_rad(quad_px: FloatArray | list[list[float]]) -> list[float]:
    q = quad_px if isinstance(quad_px, list) else np.asarray(quad_px, dtype=float).tolist()
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

    along = offsets(corner_index)
    if not along[1] < along[2] < along[3]:
        contour = contour[::-1]  # the contour runs the other way round: walk it backwards
        corner_index = [n - 1 - i for i in corner_index]
        along = offsets(corner_index)
        if not along[1] < along[2] < along[3]:
            return None
    twice = np.concatenate([contour, contour])  # so that the last side need not wrap
    ends = [corner_index[0] + r for r in [*along, n]]
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
    normals *= np.sign(np.add.reduce(normals * (centres - inward_px), axis=1) + 1e-300)[:, None]
    residuals = np.abs(du * normals[side, 0] + dv * normals[side, 1])
    max_residual_px = np.maximum.reduceat(residuals, starts)
    half_step_px = 0.5 * np.abs(normals).max(axis=1)
    offsets = np.add.reduce(normals * centres, axis=1) + half_step_px
    return _EdgeFits(normals, offsets, centres, max_residual_px)


def _outside_neighbours(
    points: np.ndarray, side: np.ndarray, normals: FloatArray, mask: np.ndarray
) -> list[np.ndarray]:
    """Per side, the 4-neighbours one step out along the normal's dominant axis of its
    boundary pixels (outside the blob for a straight edge), keeping those the mask says
    are outside."""
    steps = [  # one pixel along the normal's dominant axis, outwards
        (_sign(nu), 0) if abs(nu) >= abs(nv) else (0, _sign(nv)) for nu, nv in normals.tolist()
    ]
    outside = points + np.array(steps, np.int32)[side]
    keep = mask[outside[:, 1], outside[:, 0]] == 0
    kept, kept_side = outside[keep], side[keep]
    ends = [0, *np.searchsorted(kept_side, np.arange(1, len(normals))).tolist(), len(kept)]
    return [kept[a:b] for a, b in itertools.pairwise(ends)]  # np.split's parts


def _sign(x: float) -> int:
    """-1, 0 or 1 as np.sign gives them, of a plain float."""
    return (x > 0.0) - (x < 0.0)


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
def _pair_indices(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column indices of the n·(n-1)/2 entries above the diagonal of an n×n matrix
    (memoised, so read-only: pure, and np.triu_indices is slow for its size)."""
    rows, cols = np.triu_indices(n, 1)
    rows.setflags(write=False)
    cols.setflags(write=False)
    return rows, cols


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
    s_in, t_in, s_out, t_out = inside[..., 0], inside[..., 1], outside[..., 0], outside[..., 1]
    s_both, t_both = np.concatenate([s_in, s_out], axis=1), np.concatenate([t_in, t_out], axis=1)
    i, j = _pair_indices(s_both.shape[1])  # every pair of points once
    ds, dt = s_both[:, i] - s_both[:, j], t_both[:, i] - t_both[:, j]
    valid = np.abs(dt) < limit * np.abs(ds)  # |slope| < limit, and ds ≠ 0
    alphas = np.full((n_edges, len(i) + 2), limit)  # repeats harmless
    alphas[:, -2] = -limit
    np.divide(dt, ds, out=alphas[:, :-2], where=valid)
    alphas.sort(axis=1)
    lower = np.maximum.reduce(t_in[:, :, None] - s_in[:, :, None] * alphas[:, None, :], axis=1)
    upper = np.minimum.reduce(t_out[:, :, None] - s_out[:, :, None] * alphas[:, None, :], axis=1)
    gap = upper - lower
    feasible = gap >= -1e-9  # U − L is concave: the feasible α form an interval
    lo = np.where(feasible, alphas, np.inf).min(axis=1)
    hi = np.where(feasible, alphas, -np.inf).max(axis=1)
    span = (alphas >= lo[:, None]) & (alphas <= hi[:, None])
    # width; a tiny floor keeps a zero-width preimage (a segment of lines) well defined
    w = np.where(span, np.maximum(gap, 0.0) + 1e-12, 0.0)
    w0, w1 = w[:, :-1], w[:, 1:]
    da = (alphas[:, 1:] - alphas[:, :-1]) * (span[:, 1:] & span[:, :-1])

    def integral(f0: FloatArray | float, f1: FloatArray | float) -> FloatArray:
        """∫ f·w dα (×6), exact for f and w linear between breakpoints (f0, f1: f at each
        interval's ends)."""
        return np.add.reduce(da * ((2 * f0 + f1) * w0 + (f0 + 2 * f1) * w1), axis=-1)

    middle = 0.5 * (upper + lower)  # β of the region's middle line at each α
    area = integral(1.0, 1.0)
    ok = (lo > -limit) & (hi < limit) & (area > 0)  # bounded, non-empty, not a point
    area = np.where(ok, area, 1.0)
    alpha = integral(alphas[:, :-1], alphas[:, 1:]) / area
    return alpha, integral(middle[:, :-1], middle[:, 1:]) / area, ok


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
    inward = np.repeat([centroid(blob.rough_px) for blob in blobs], 4, axis=0)
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


def _intersect_lines(
    n1: list[float], c1: float, n2: list[float], c2: float
) -> tuple[float, float] | None:
    det = n1[0] * n2[1] - n1[1] * n2[0]
    if abs(det) < math.sin(MIN_CORNER_ANGLE_RAD / 2.0):  # near-parallel sides
        return None
    return (c1 * n2[1] - c2 * n1[1]) / det, (n1[0] * c2 - n2[0] * c1) / det


def _corners_from_lines(
    normals: FloatArray, offsets: list[float], rough_px: FloatArray
) -> FloatArray | None:
    """Corner i = side (i-1) ∩ side i; None if two sides are nearly parallel or meet far from
    the rough corner (the fit went wrong). On plain floats: four corners, where numpy's
    per-call overhead would be the whole cost."""
    n, rough = normals.tolist(), rough_px.tolist()
    corners = []
    for i in range(4):
        p = _intersect_lines(n[i - 1], offsets[i - 1], n[i], offsets[i])
        if p is None or math.dist(p, rough[i]) > MAX_CORNER_SHIFT_PX:
            return None
        corners.append(p)
    return np.array(corners)


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


def find_quads(masks: list[tuple[np.ndarray, Roi | None]], min_area_px: int) -> list[_QuadResult]:
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
    return find_quads([(mask, None)], min_area_px)[0].corners_px


def quad_area_px2(corners_px: FloatArray) -> float:
    return quad_area(corners_px.tolist())
