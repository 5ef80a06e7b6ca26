"""The simulator's ground truth: the markers' poses and image corners, the arm's contacts, how
much of each marker the camera sees, and all of it in the wire format. For evaluation only:
nothing in vision or control may read it. The world (:mod:`services.sim.world`) measures it,
the sim node publishes it; the in-process pipeline (services/pipeline.py) hands it to the run's
judge the same way."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from common.camera import CameraIntrinsics, project
from common.kinematics import FloatArray
from common.messages import PIXEL_LIMIT_PX, Header, SimTruth

LARGEST_BOX_PX = 16  # a quad's bounding box this many images large is measured, not drawn


@dataclass(frozen=True)
class MarkerView:
    """What the camera sees of a marker (ground truth, for evaluation): the fraction of its
    square showing the marker itself (0 outside the image or hidden, 1 wholly in view), and
    whether another part of the robot or the image border touches its outline (within a few
    pixels: a depth camera's invalid band along edges and its lateral noise hide whether it
    overlaps; a blob at the border may go on beyond it), where a measurement may fairly refuse
    it."""

    fraction: float
    touched: bool


def square_pixels(
    corners_px: FloatArray, grow_px: float, shape: tuple[int, ...]
) -> tuple[np.ndarray, int]:
    """Mask (of ``shape``) of the pixels of a convex quadrilateral grown (or, negative, shrunk)
    by about ``grow_px``, and how many pixels it has in all, outside the image included."""
    centre = corners_px.mean(axis=0)
    radius = max(float(np.linalg.norm(corners_px - centre, axis=1).min()), 2.0)
    quad = centre + (corners_px - centre) * (1.0 + grow_px / radius)
    lo = np.floor(quad.min(axis=0)).astype(int) - 1
    hi = np.ceil(quad.max(axis=0)).astype(int) + 2
    if (hi[1] - lo[1]) * (hi[0] - lo[0]) > LARGEST_BOX_PX * shape[0] * shape[1]:
        # A quad far larger than the image (its corners far out of view): the pixels in the
        # image drawn alone, its size counted as its area, not a box of 10⁸ pixels drawn.
        mask = np.zeros(shape[:2], np.uint8)
        cv2.fillConvexPoly(mask, np.round(quad * 16).astype(np.int32), 1, cv2.LINE_8, 4)
        return mask > 0, round(cv2.contourArea(quad.astype(np.float32)))
    box = np.zeros((hi[1] - lo[1], hi[0] - lo[0]), np.uint8)
    cv2.fillConvexPoly(box, np.round((quad - lo) * 16).astype(np.int32), 1, cv2.LINE_8, 4)
    mask = np.zeros(shape[:2], bool)
    r0, c0 = max(lo[1], 0), max(lo[0], 0)
    r1, c1 = min(hi[1], shape[0]), min(hi[0], shape[1])
    if r1 > r0 and c1 > c0:
        mask[r0:r1, c0:c1] = box[r0 - lo[1] : r1 - lo[1], c0 - lo[0] : c1 - lo[0]] > 0
    return mask, int(np.count_nonzero(box))


# A corner this near the camera's plane, or behind it, has no image point: it is placed as if
# this deep, far out on its own side of the image, then within the wire's pixel range.
NEAREST_PROJECTED_M = 1e-3


def truth_corners_px(corners_cam_m: FloatArray, k: CameraIntrinsics) -> FloatArray:
    """The image points of a marker's corners (N×3, optical frame) for judging a run, also
    when the marker is far out of view or behind the camera (as a random posture can put it):
    beyond the image on the side it lies, within :data:`PIXEL_LIMIT_PX` of the wire, never a
    projection through the camera's centre that would fall back inside the image."""
    c = np.asarray(corners_cam_m, dtype=float)
    in_front = np.column_stack([c[:, :2], np.maximum(c[:, 2], NEAREST_PROJECTED_M)])
    return np.clip(project(in_front, k), -PIXEL_LIMIT_PX, PIXEL_LIMIT_PX)


@dataclass(frozen=True)
class Truth:
    hand_marker_pose: FloatArray
    target_marker_pose: FloatArray
    hand_corners_px: FloatArray
    target_corners_px: FloatArray
    ee_position_m: FloatArray
    # What the arm touches after the last physics step: the summed normal force (N) and the
    # bodies ("object", "table", "floor"), for naming a collision; the robot's own links do
    # not collide with each other.
    contact_n: float = 0.0
    contact_with: tuple[str, ...] = ()


def truth_message(truth: Truth, header: Header, q_rad: FloatArray) -> SimTruth:
    """``truth`` of the frame ``header`` names, with the joints at ``q_rad``."""
    return SimTruth(
        header=header,
        hand_marker_pose=truth.hand_marker_pose.reshape(-1).tolist(),
        target_marker_pose=truth.target_marker_pose.reshape(-1).tolist(),
        hand_corners_px=truth.hand_corners_px.tolist(),
        target_corners_px=truth.target_corners_px.tolist(),
        ee_position_m=truth.ee_position_m.tolist(),
        joint_position_rad=q_rad.tolist(),
        arm_contact_n=truth.contact_n,
        arm_contact_with=list(truth.contact_with),
    )
