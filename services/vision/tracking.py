"""Marker states from frame to frame: colour in every frame, depth whenever it comes. Pure.

The depth stream may be slower than the colour one (the thesis ran depth at 1 Hz). A colour
frame taken together with a depth image is measured in full (:func:`measure_quad`: corners,
plane-fitted corner depths, occlusion check); each such view is remembered per marker. Between
depth images the corners still come from colour, and the depths from that memory:

- the target lies on the table, so its plane stays where it was (a slide along the table does
  not move it): its corner rays are intersected with the remembered plane, and a square whose
  sides then do not come out at the marker's known size is taken as partly hidden;
- the hand moves, so its corners keep the depths measured last (what the thesis did).

A marker that is not visible is ``occluded`` when something is seen in front of where it must
be by now (its last view carried along its estimated motion): in the depth image when there is
a fresh one, else when the hand's marker is over it (in eye-to-hand servoing the hand is what
comes between the camera and the target). A partly hidden marker is fitted from its visible
edges (:mod:`services.vision.partial`) when they pin its pose down: the target on its
remembered plane, or, never seen whole yet, on the plane of its own depth in this frame
(:mod:`services.vision.own_depth`); the hand always on its own depth's (it moves), and only
when most of its marker shows (its own forearm bordering it), since it is what is servoed.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from common.camera import CameraIntrinsics, back_project, pixel_to_normalized, project
from common.config import VisionConfig
from common.marker import Marker
from common.messages import PIXEL_LIMIT_PX, usable_depths
from common.motion import MarkerMotion
from services.vision.cue import cue_mask, label_corners
from services.vision.depth import (
    FloatArray,
    PlaneFit,
    marker_surface,
    plane_depth_image,
)
from services.vision.measurement import (
    MarkerMeasurement,
    MarkerQuad,
    find_marker_quads,
    measure_quad,
    not_visible,
)
from services.vision.occlusion import hidden_behind, occluder_map
from services.vision.own_depth import blob_plane, on_plane, square_from_outline
from services.vision.partial import (
    MAX_STRAY_FRACTION,
    SquareOnPlane,
    fit_square_to_blob,
    outline,
    stray_fraction,
)
from services.vision.quad import order_corners, quad_area_px2
from services.vision.segmentation import MARKERS, colour_mask, mask_bounds

# How each marker's depth is carried between depth images (see the module docstring).
HELD_DEPTH = {"hand": "corners", "target": "plane"}
# Markers whose partly hidden views are fitted (services.vision.partial): the target, which the
# hand necessarily covers at the end (on its remembered plane, else on its own depth's), and
# the hand, whose own forearm borders its marker (always on its own depth's plane: the hand
# moves, so a remembered plane is not its own).
FITTED = ("target", "hand")
# The hand is servoed on: fitted only when its blob covers this much of the fitted square
# (bordered by its arm, or a corner shaved), never from a few of its edges.
HAND_MIN_SEEN_FRACTION = 0.85
SIZE_TOLERANCE = 0.04  # relative: a side further off the marker's size is not the whole square
NEAR_DIAGONALS = 2.0  # the hand is "over" the target within this many target diagonals


@dataclass(frozen=True)
class DepthImage:
    """A depth image, its intrinsics, and how much older it is than the colour frame (sim s;
    0 when they were taken together)."""

    depth_m: np.ndarray
    intrinsics: CameraIntrinsics
    age_s: float


@dataclass(frozen=True)
class MarkerMemory:
    """A marker's last view with a depth image taken at the same time."""

    corners_px: FloatArray
    depth_m: FloatArray
    depth_sigma_m: FloatArray
    plane: PlaneFit | None
    t_s: float  # sim time of the view

    def carried(self, shift_m: FloatArray, k: CameraIntrinsics) -> MarkerMemory:
        """Where this view is by now if the marker slid by ``shift_m`` (camera frame)."""
        if not shift_m.any():
            return self
        points = back_project(self.corners_px, self.depth_m, k) + shift_m
        plane = None if self.plane is None else self.plane.shifted(shift_m)
        return MarkerMemory(
            project(points, k), points[:, 2].copy(), self.depth_sigma_m, plane, self.t_s
        )


@dataclass(frozen=True)
class TrackerState:
    """What one frame leaves for the next: the last visible corners of each marker (to keep
    their order; with the orientation cue, only of a marker visible in the frame before),
    which markers the frame before saw whole (only theirs are looked for in a window around
    those corners), its last view with depth, and how it has been moving."""

    previous_corners: dict[str, FloatArray] = field(default_factory=dict)
    memory: dict[str, MarkerMemory] = field(default_factory=dict)
    motion: dict[str, MarkerMotion] = field(default_factory=dict)
    seen_last_frame: frozenset[str] = frozenset()  # the markers visible in the last frame

    def expected(self, name: str, t_s: float, k: CameraIntrinsics) -> MarkerMemory | None:
        """The marker's last view with depth, carried along its motion to ``t_s``."""
        memory = self.memory.get(name)
        if memory is None:
            return None
        return memory.carried(self.motion.get(name, MarkerMotion()).shift_m(t_s), k)


def hand_over(hand_corners_px: FloatArray | None, target_corners_px: FloatArray) -> bool:
    """The hand's marker is within a few target diagonals of where the target was seen."""
    if hand_corners_px is None:
        return False
    diagonal = float(np.linalg.norm(target_corners_px[0] - target_corners_px[2]))
    gap = float(np.linalg.norm(hand_corners_px.mean(axis=0) - target_corners_px.mean(axis=0)))
    return gap < NEAR_DIAGONALS * diagonal


def side_lengths_m(points_m: FloatArray) -> FloatArray:
    """Lengths of a polygon's sides, point i to point i+1 (np.linalg.norm's operations along
    axis 1, without its checks)."""
    sides = points_m - np.concatenate([points_m[1:], points_m[:1]])
    return np.sqrt(np.add.reduce(sides * sides, axis=1))


def marker_sized(points_m: FloatArray, marker_size_m: float) -> bool:
    """Whether a quadrilateral's 3-D sides are all the marker's, to :data:`SIZE_TOLERANCE`:
    the whole square, not a part of it cut off by something in front, nor another shape."""
    sides = side_lengths_m(points_m)
    return bool(np.abs(sides / marker_size_m - 1.0).max() <= SIZE_TOLERANCE)


def _region_mask(corners_px: FloatArray, shape: tuple[int, ...]) -> np.ndarray:
    mask = np.zeros(shape[:2], np.uint8)
    shift_bits = 4
    vertices = np.round(corners_px * (1 << shift_bits)).astype(np.int32)
    cv2.fillConvexPoly(mask, vertices, 255, cv2.LINE_8, shift_bits)
    return mask


def _depth_under(
    depth: DepthImage, k: CameraIntrinsics, bounds: tuple[int, int, int, int]
) -> np.ndarray:
    """The depth image's pixel under each colour pixel of ``bounds`` (row0, row1, col0, col1)
    of the colour image: registered images, the same rays."""
    r0, r1, c0, c1 = bounds
    kd = depth.intrinsics
    # to_depth_pixels of the columns and of the rows, each coordinate on its own
    u = kd.fx_px * ((np.arange(c0, c1, dtype=float) - k.cx_px) / k.fx_px) + kd.cx_px
    v = kd.fy_px * ((np.arange(r0, r1, dtype=float) - k.cy_px) / k.fy_px) + kd.cy_px
    h, w = depth.depth_m.shape
    du = np.minimum(np.maximum(np.rint(u).astype(int), 0), w - 1)  # clipped to the image
    dv = np.minimum(np.maximum(np.rint(v).astype(int), 0), h - 1)
    # depth_m[dv[:, None], du[None, :]], gathered one axis at a time (several times faster):
    # the columns of the rows it spans, then its rows
    top, bottom = int(dv.min()), int(dv.max())
    return depth.depth_m[top : bottom + 1].take(du, axis=1).take(dv - top, axis=0)


def _hidden_in_depth(
    name: str,
    memory: MarkerMemory | None,
    rgb: np.ndarray,
    k: CameraIntrinsics,
    depth: DepthImage,
    cfg: VisionConfig,
) -> bool:
    """Is something in front of where the marker was last seen, in a fresh depth image (and
    is the marker hidden there rather than gone)? Checked at the colour resolution."""
    if memory is None:
        return False
    region = _region_mask(memory.corners_px, rgb.shape)
    bounds = mask_bounds(region, 0)
    if bounds is None:
        return False
    r0, r1, c0, c1 = bounds
    depth_crop = _depth_under(depth, k, bounds)
    colour = colour_mask(rgb[r0:r1, c0:c1], MARKERS[name], cfg)
    surface = np.broadcast_to(
        marker_surface(memory.plane, memory.depth_m, k, bounds), depth_crop.shape
    )
    return hidden_behind(depth_crop, region[r0:r1, c0:c1], surface, colour)


@dataclass(frozen=True)
class _PartialFit:
    """A partly hidden marker fitted from its visible edges: corners (px), their depths and
    1-σ on the remembered plane (m), the square's corners (m, optical frame), and whether any
    pixel around it is closer than that plane (something in front of it)."""

    corners_px: FloatArray
    depth_m: FloatArray
    depth_sigma_m: FloatArray
    points_m: FloatArray
    plane: PlaneFit
    occluder_seen: bool

    def measurement(self, reason: str, occluded: bool) -> MarkerMeasurement:
        """As a measurement of a marker seen only in part, for ``reason``."""
        marker = Marker(
            state="partial",
            corners_px=self.corners_px,
            depth_m=self.depth_m,
            depth_sigma_m=self.depth_sigma_m,
            points_m=self.points_m,
            occluded=occluded or self.occluder_seen,
            fitted=True,
            reason=reason,
        )
        return MarkerMeasurement(marker, self.plane)


def dropout_reach_px(ring_px: int, k: CameraIntrinsics, k_depth: CameraIntrinsics) -> int:
    """How far (colour pixels) an invalid depth pixel may lie from a closer surface and still
    be taken as that occluder's dropout, when the depth image is looked at through the colour
    pixels (:func:`_depth_under`): ``ring_px`` depth pixels. The band a depth camera leaves
    invalid along an edge is so many of its own pixels wide, so on a coarser depth image it
    spans more colour pixels: a reach kept at ``ring_px`` colour pixels would leave most of
    that band along the hand unexplained, and the hand's edge among the marker's own."""
    scale = k.width_px / k_depth.width_px
    return ring_px if scale <= 1.0 else round(ring_px * scale)


def _fit_partial(
    quad: MarkerQuad,
    memory: MarkerMemory | None,
    k: CameraIntrinsics,
    depth: DepthImage,
    cfg: VisionConfig,
    marker_size_m: float,
    cue_rgb: np.ndarray | None = None,
) -> _PartialFit | None:
    """A partly hidden marker's corners from its visible edges (see
    :mod:`services.vision.partial`), its known size and remembered plane; None if the fit
    does not hold. ``cue_rgb``: the colour frame, when the markers carry a cue."""
    if memory is None or memory.plane is None or quad.area_px <= 0:
        return None
    points = back_project(memory.corners_px, memory.depth_m, k)
    square = SquareOnPlane.from_corners(points, marker_size_m)
    return _fit_on_plane(quad, memory.plane, [square], False, k, depth, cfg, marker_size_m, cue_rgb)


def _fit_own(
    quad: MarkerQuad,
    k: CameraIntrinsics,
    depth: DepthImage,
    cfg: VisionConfig,
    marker_size_m: float,
    cue_rgb: np.ndarray | None = None,
) -> _PartialFit | None:
    """A partly hidden marker's corners from its visible edges on the plane of its own depth
    in this frame (:mod:`services.vision.own_depth`), starting from its quadrilateral when
    colour found one, else from its outline; None if the fit does not hold. ``cue_rgb``: as
    :func:`_fit_partial`."""
    if quad.area_px <= 0:
        return None
    plane = blob_plane(quad.mask, depth.depth_m, k, depth.intrinsics, quad.region)
    if plane is None:
        return None
    guesses = []
    if quad.corners_px is not None:
        points = on_plane(plane, quad.corners_px, k)
        if points is not None:
            guesses.append(SquareOnPlane.from_corners(points, marker_size_m))
    return _fit_on_plane(quad, plane, guesses, True, k, depth, cfg, marker_size_m, cue_rgb)


def _fit_on_plane(
    quad: MarkerQuad,
    plane: PlaneFit,
    guesses: list[SquareOnPlane],
    from_outline: bool,
    k: CameraIntrinsics,
    depth: DepthImage,
    cfg: VisionConfig,
    marker_size_m: float,
    cue_rgb: np.ndarray | None = None,
) -> _PartialFit | None:
    """The square on ``plane`` fitted to the blob's true edges (those bordering nothing in
    front of that plane), from the first of ``guesses`` that fits (and, ``from_outline``,
    a guess from the blob's outline after them); None if none holds.

    ``cue_rgb`` (markers with a cue): the outline is taken with the cue's pixels counted as
    the marker's. The cue is a hole in the colour's mask; where something in front cuts
    through it, the hole opens into the blob's outline, and its sides are not the square's."""
    reach_px = dropout_reach_px(cfg.occlusion_ring_px, k, depth.intrinsics)
    bounds = mask_bounds(quad.mask, 2 * reach_px + 2, quad.region)
    if bounds is None:
        return None
    r0, r1, c0, c1 = bounds
    depth_crop = _depth_under(depth, k, bounds)
    occluder = occluder_map(depth_crop, plane_depth_image(plane, k, bounds), reach_px)
    mask = quad.mask[r0:r1, c0:c1]
    face = mask if cue_rgb is None else mask | cue_mask(cue_rgb[r0:r1, c0:c1], cfg)
    points, true_edge = outline(face, occluder, (c0, r0))
    edges = points[true_edge]
    moments = cv2.moments(mask, binaryImage=True)
    centre = np.array([moments["m10"], moments["m01"]]) / moments["m00"] + (c0, r0)
    if from_outline:
        square = square_from_outline(plane, points, true_edge, k, marker_size_m)
        guesses = guesses if square is None else [*guesses, square]
    for square in guesses:
        fit = fit_square_to_blob(square, edges, centre, k)
        if fit is not None and stray_fraction(mask, fit.corners_px, (c0, r0)) <= MAX_STRAY_FRACTION:
            break
    else:
        return None
    xy = pixel_to_normalized(fit.corners_px, k)
    (depths_m, sigmas_m), points_m = plane.depths_and_sigmas_m(xy), fit.square.corners_m()
    # A square cut by the border near the camera can be fitted right and still have a hidden
    # corner too near, or too far out, for a usable marker on the wire: not fitted, then.
    if not (
        usable_depths(depths_m)
        and usable_depths(points_m[:, 2])
        and (np.abs(fit.corners_px) <= PIXEL_LIMIT_PX).all()
    ):
        return None
    return _PartialFit(
        fit.corners_px,
        depths_m,
        sigmas_m,
        points_m,
        plane,
        bool(occluder.any()),
    )


def _held(
    name: str,
    quad: MarkerQuad,
    memory: MarkerMemory | None,
    k: CameraIntrinsics,
    marker_size_m: float,
    oldest_s: float,
) -> MarkerMeasurement:
    """A marker found in colour, measured with the depth remembered from its last full view,
    if that view is no older than ``oldest_s`` (sim s): as a depth image, a view older than
    ``max_depth_age_s`` is no measurement (carried along the marker's motion for longer, a
    hand that stopped went on drifting towards the camera)."""
    assert quad.corners_px is not None
    if memory is None:
        return not_visible("no valid depth")
    if memory.t_s < oldest_s:
        return not_visible("depth of it too old")
    corners = quad.corners_px
    if HELD_DEPTH[name] == "plane" and memory.plane is not None:
        xy = pixel_to_normalized(corners, k)
        depths, sigmas = memory.plane.depths_and_sigmas_m(xy)
        if not usable_depths(depths):
            return not_visible("no valid depth")
        points = back_project(corners, depths, k)
        if not marker_sized(points, marker_size_m):
            return not_visible("not the marker's size")
    else:
        depths, sigmas = memory.depth_m.copy(), memory.depth_sigma_m.copy()
        if not usable_depths(depths):
            return not_visible("no valid depth")
        points = back_project(corners, depths, k)
    marker = Marker(
        state="visible", corners_px=corners, depth_m=depths, depth_sigma_m=sigmas, points_m=points
    )
    return MarkerMeasurement(marker, memory.plane)


def _labelled(
    fit: _PartialFit,
    reference_px: FloatArray | None,
    rgb: np.ndarray,
    cfg: VisionConfig,
    orientation_cue: bool,
) -> _PartialFit | None:
    """A fit from the frame alone with its corners in the order a whole view would give
    them: canonical, following ``reference_px`` (the quadrilateral colour found, else last
    frame's corners), or labelled by the marker's cue; None when the cue cannot be told."""
    corners = order_corners(fit.corners_px, reference_px)
    if orientation_cue:
        corners = label_corners(rgb, corners, reference_px, cfg)
        if corners is None:
            return None
    order = [int(np.argmin(np.sum((fit.corners_px - c) ** 2, axis=1))) for c in corners]
    return replace(
        fit,
        corners_px=fit.corners_px[order],
        depth_m=fit.depth_m[order],
        depth_sigma_m=fit.depth_sigma_m[order],
        points_m=fit.points_m[order],
    )


def _fit(
    name: str,
    quad: MarkerQuad,
    memory: Callable[[], MarkerMemory | None],
    previous_px: FloatArray | None,
    rgb: np.ndarray,
    k: CameraIntrinsics,
    depth: DepthImage,
    cfg: VisionConfig,
    marker_size_m: float,
    orientation_cue: bool,
) -> _PartialFit | None:
    """A partly hidden marker (one of :data:`FITTED`) fitted from its visible edges: on the
    target's remembered plane when it has one, else on the plane of its own depth in this
    frame, which for the hand must show most of its marker (:data:`HAND_MIN_SEEN_FRACTION`).
    ``memory``: gives the marker's last view with depth carried to now (see _measure_fresh)."""
    cue_rgb = rgb if orientation_cue else None
    last = memory() if name == "target" else None  # not the hand's: it moves
    if last is not None and last.plane is not None:
        fit = _fit_partial(quad, last, k, depth, cfg, marker_size_m, cue_rgb)
        if fit is not None and orientation_cue and previous_px is None:
            # Its labels come from its last whole view, not from the frame before (it was
            # lost since, and may have turned): with the cue, the cue must tell them.
            return _labelled(fit, None, rgb, cfg, orientation_cue)
        return fit
    fit = _fit_own(quad, k, depth, cfg, marker_size_m, cue_rgb)
    if fit is None:
        return None
    if name == "hand" and quad.area_px < HAND_MIN_SEEN_FRACTION * quad_area_px2(fit.corners_px):
        return None
    reference = quad.corners_px if quad.corners_px is not None else previous_px
    return _labelled(fit, reference, rgb, cfg, orientation_cue)


def _measure_fresh(
    name: str,
    quad: MarkerQuad,
    memory: Callable[[], MarkerMemory | None],
    previous_px: FloatArray | None,
    rgb: np.ndarray,
    k: CameraIntrinsics,
    depth: DepthImage,
    cfg: VisionConfig,
    marker_size_m: float,
    orientation_cue: bool = False,
) -> MarkerMeasurement:
    """A marker in a colour frame taken with the depth image: measured in full, and fitted
    from its visible edges when only part of it shows (a marker in :data:`FITTED`).
    ``memory``: gives the marker's last view with depth carried to now, made only when it is
    needed (a marker seen whole never asks for it)."""
    fit: _PartialFit | None = None
    fit_first = name in FITTED and quad.corners_px is None  # no quadrilateral: partly hidden
    args = (name, quad, memory, previous_px, rgb, k, depth, cfg, marker_size_m, orientation_cue)
    if fit_first:
        fit = _fit(*args)
        if fit is not None and fit.occluder_seen:
            # Occluded whatever the blob's own depth says: its check (measure_quad) is skipped.
            return fit.measurement(quad.reason, occluded=True)
    m = measure_quad(quad, depth.depth_m, k, cfg, depth.intrinsics)
    if m.marker.visible and not marker_sized(m.marker.points_m, marker_size_m):
        # A quadrilateral of the marker's colour whose sides are not the marker's: part of it
        # cut off by something the depth image does not show in front (no valid depth there:
        # nearer than the Kinect's range, dark, or flush with it), or not the marker at all.
        m = not_visible("not the marker's size")
    seen = m.marker
    if not (seen.visible or seen.occluded) and _hidden_in_depth(name, memory(), rgb, k, depth, cfg):
        m = not_visible(seen.reason, occluded=True)
    if name in FITTED and m.marker.state == "partial":
        if not fit_first:  # a quadrilateral, but something in front of it in depth
            fit = _fit(*args)
        if fit is not None:
            m = fit.measurement(m.marker.reason, m.marker.occluded)
    return m


def observe(
    rgb: np.ndarray,
    k: CameraIntrinsics,
    depth: DepthImage | None,
    cfg: VisionConfig,
    marker_size_m: float,
    state: TrackerState,
    t_s: float = 0.0,
    orientation_cue: bool = False,
) -> tuple[dict[str, Marker], TrackerState]:
    """Both markers in one colour frame taken at sim time ``t_s``, with the newest depth image
    (None: none yet), and the state for the next frame. ``orientation_cue``
    (``marker.orientation_cue``): corners labelled by each marker's cue
    (:mod:`services.vision.cue`), carried on by continuity only from the frame before."""
    # Looked for around where they were only if seen whole last frame: the last visible
    # corners of a marker since moved could hold a smaller blob of its colour for ever.
    windows = {n: c for n, c in state.previous_corners.items() if n in state.seen_last_frame}
    quads = find_marker_quads(rgb, cfg, state.previous_corners, orientation_cue, windows)
    fresh = depth is not None and depth.age_s == 0.0
    usable = depth is not None and depth.age_s <= cfg.max_depth_age_s
    measured: dict[str, MarkerMeasurement] = {}

    @functools.cache
    def expected(name: str) -> MarkerMemory | None:
        """The marker's last view with depth carried to ``t_s``: made when first asked for
        (in a frame with depth, a marker seen whole does not ask)."""
        return state.expected(name, t_s, k)

    for name, quad in quads.items():
        if fresh:
            assert depth is not None
            previous = state.previous_corners.get(name)
            memory = functools.partial(expected, name)
            m = _measure_fresh(
                name, quad, memory, previous, rgb, k, depth, cfg, marker_size_m, orientation_cue
            )
        elif quad.corners_px is None:
            m = not_visible(quad.reason)
        elif not usable:
            m = not_visible("no depth image" if depth is None else "depth image too old")
        else:
            m = _held(name, quad, expected(name), k, marker_size_m, t_s - cfg.max_depth_age_s)
        measured[name] = m
    if not fresh:  # no depth to tell: the hand over the target's last place is what hides it
        target, last = measured["target"], expected("target")
        if (
            not target.marker.visible
            and last is not None
            and hand_over(quads["hand"].corners_px, last.corners_px)
        ):
            measured["target"] = not_visible(target.marker.reason, occluded=True)
    for name, m in measured.items():
        if m.marker.state == "lost" and not m.marker.occluded and expected(name) is None:
            # Nothing seen of it, and no view of it to look in front of (none measured with a
            # depth image since this vision started): hidden or gone, it cannot tell.
            measured[name] = replace(m, marker=replace(m.marker, occluded=None))
    markers = {name: m.marker for name, m in measured.items()}
    return markers, _next_state(state, measured, fresh, t_s, orientation_cue)


def _next_state(
    state: TrackerState,
    measured: dict[str, MarkerMeasurement],
    fresh: bool,
    t_s: float,
    orientation_cue: bool = False,
) -> TrackerState:
    previous = dict(state.previous_corners)
    memory = dict(state.memory)
    motion = dict(state.motion)
    for name, m in measured.items():
        seen = m.marker
        if seen.visible or (orientation_cue and seen.usable):  # fitted: labelled too
            previous[name] = seen.corners_px
        elif orientation_cue:  # a labelling is carried on from the frame before only
            previous.pop(name, None)
        if seen.usable and fresh:  # measured with depth (a fitted view keeps its plane)
            memory[name] = MarkerMemory(
                seen.corners_px, seen.depth_m, seen.depth_sigma_m, m.plane, t_s
            )
            motion[name] = motion.get(name, MarkerMotion()).seen(t_s, seen.points_m)
    visible = frozenset(name for name, m in measured.items() if m.marker.visible)
    return TrackerState(previous, memory, motion, visible)
