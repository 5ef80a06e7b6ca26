"""The goal in the image: the desired features above the target, where a hidden target has
gone, and whether the hand is what hides it. Pure."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from common.camera import CameraIntrinsics, project
from common.kinematics import centroid, cross, norm
from common.marker import Marker
from common.messages import MIN_USABLE_DEPTH_M
from common.motion import MarkerMotion

FloatArray = NDArray[np.float64]


def desired_observation(target: Marker, approach_height_m: float, k: CameraIntrinsics) -> Marker:
    """Desired features s*: the red marker's measured 3-D corners raised by the approach
    height along the marker's normal (pointing towards the camera), then projected.

    The depth camera makes this possible: the hand stops just above the object instead of
    having to pass through it; with a zero height s* is the red square itself.
    """
    if approach_height_m == 0.0:
        return target
    p = target.points_m
    normal = cross(p[2] - p[0], p[3] - p[1])
    normal /= norm(normal)
    if normal @ centroid(p) > 0:  # make it face the camera (at the origin)
        normal = -normal
    raised = p + approach_height_m * normal
    # Its depths come from the target's, moved by a known height: the same uncertainty.
    return Marker.seen_at(raised, k, target.depth_sigma_m)


GOAL_BEHIND_CAMERA = "goal not in front of the camera"


def in_front_of_camera(marker: Marker) -> bool:
    """Every corner of ``marker`` at least :data:`~common.messages.MIN_USABLE_DEPTH_M` in front
    of the camera, as a usable marker's: a target carried there by its prediction, or a goal
    raised by the approach height from a target that near, projects nowhere, or from behind."""
    return bool(np.all(np.asarray(marker.points_m)[:, 2] >= MIN_USABLE_DEPTH_M))


def carried(last: Marker, shift_m: FloatArray, k: CameraIntrinsics) -> Marker:
    """``last`` moved by ``shift_m`` (camera frame): where a hidden target is by now."""
    if not np.any(shift_m):
        return last
    points = last.points_m + shift_m
    return replace(
        last, corners_px=project(points, k), depth_m=points[:, 2].copy(), points_m=points
    )


# The hand counts as hiding the target when its marker's centre is within this many target
# diagonals of where the target was last seen (the hand box and forearm are larger than the marker).
OCCLUSION_RADIUS_DIAGONALS = 2.0


def hand_hides_target(hand: Marker, last_target: Marker) -> bool:
    """In eye-to-hand servoing the hand must end up in front of the target, hiding it."""
    if not hand.usable:
        return False
    diagonal = norm(last_target.corners_px[0] - last_target.corners_px[2])
    gap = norm(centroid(hand.corners_px) - centroid(last_target.corners_px))
    return bool(gap < OCCLUSION_RADIUS_DIAGONALS * diagonal)


def may_be_behind_the_hand(target: Marker) -> bool:
    """Seen partly, or with something in front, or vision cannot tell: what moving the hand
    away can uncover (a target simply gone, with nothing in front of it, cannot be)."""
    return target.state == "partial" or target.occluded is not False


@dataclass
class TargetMemory:
    """The target's last usable view and its motion estimated from its recent views.

    As the hand closes in it necessarily hides the target from the fixed camera. While vision
    can fit the partly hidden square it is used as seen; when it cannot, the goal comes from
    the last view carried along the target's estimated velocity, but only while vision sees
    something in front of the target (``occluded``), or cannot tell (a restarted vision with
    no view of it yet), and the hand is near it. ``predicted``:
    the goal is where that motion says a hidden target went, unconfirmed since, so not a goal
    to stop on."""

    last: Marker | None = None
    motion: MarkerMotion = field(default_factory=MarkerMotion)
    predicted: bool = False

    def now(
        self, target: Marker, hand: Marker, k: CameraIntrinsics, t_s: float
    ) -> tuple[Marker, bool, bool]:
        """``(target, remembered, seen_again)``: the target as seen (kept as the last view
        when usable), or its last view carried to ``t_s`` where the hand hides it
        (``remembered``); ``seen_again``: usable again after a prediction."""
        if target.usable:
            seen_again = self.predicted
            self.last, self.predicted = target, False
            self.motion = self.motion.seen(t_s, target.points_m)
            return target, False, seen_again
        if target.occluded is not False and self.last is not None:  # hidden, or may be
            shift = self.motion.shift_m(t_s)
            expected = carried(self.last, shift, k)
            if hand_hides_target(hand, expected):
                self.predicted = self.predicted or bool(shift.any())
                return expected, True, False
        return target, False, False
