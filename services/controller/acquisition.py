"""Target acquisition: move the hand out of the camera's line of sight to the target. Pure.

Eye-to-hand, the hand can stand between the fixed camera and the target: vision then sees the
red square only partly, cannot fit it (its plane is known only once it has been seen whole),
and there is nothing to servo on. Or the hand sits on a *prediction* of where a hidden,
moving target went, which no view has confirmed. No motion towards the target can help; a
motion of the hand's own image away from where it is can.

The law uses only the camera (the hand marker's corners and depths) and the encoders (forward
kinematics and the assumed camera pose give the elbow's image): it asks the hand marker's four
image points to slide, unchanged in shape, by a clearance of a few marker diagonals along one
image direction, through the same interaction-matrix machinery as the servo but with a
translation only (``v = λ · L_v⁺ · e``, L at the current points and depths, ``ω = 0``; ``e``
the offset from the goal plus a pull away from the image border for corners near it), so the
twist goes to actuation like any other and meets its whole safety chain (deadman, joint
limits, speed and acceleration limits). λ is the acquisition's own (``acquire_gain``), above
the servo's: the twist's clamp sets the speed, and the hand slows only near the attempt's goal
(at the servo's 1/s an attempt spent most of its time creeping up to it). Directions, in
order:

1. and 2. across the forearm's image, the side where the hand rises first: the hand and the
   forearm behind it both leave the image area they covered;
3. up in the image (the world's vertical at the hand, from the assumed camera pose);
4. and 5. towards the elbow's image (the hand slides back along its own forearm), and away;
6. and 7. up and to either side, diagonally.

Directions more downward than sideways are left out: at constant depth they would press the
hand onto the table the target lies on. Those with any downward share come after the others,
in the same order: what the hand hides, and the object under it, lie below the hand, and a
slide down and sideways can run the hand into the object's side.

Each attempt ends when the hand reaches its goal, comes near the image border, or after
``acquire_attempt_s``; the next one starts from wherever the hand is. After
``acquire_attempts`` (counted over the run by the controller) the acquisition has failed. A
goal is pulled in so that the hand marker stays inside the image (a margin), each image axis
by itself (up and a little right, beside the right border, is up); a direction that leaves
less than 30 % of the clearance, or is bent more than 45° by the border, is skipped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from common.camera import CameraIntrinsics, pixel_to_normalized
from services.controller.interaction import interaction_matrix

FloatArray = NDArray[np.float64]

# How far the hand marker's image slides in one attempt, in its own image diagonals: the hand
# box (9 × 8 cm) around the 6 cm marker reaches about 0.7 diagonals from the marker's centre,
# a target of the same size another 0.5 at most; the rest is margin.
CLEARANCE_DIAGONALS = 1.6
# The hand marker's goal stays this far inside the image (at least, or this share of the
# image's smaller side): the motion there is not a straight image line, and a hand marker
# cut by the border is lost to vision.
IMAGE_MARGIN_PX = 10.0
IMAGE_MARGIN_FRACTION = 0.08
REACHED_PX = 3.0  # an attempt is over when every corner is this close to its goal
BORDER_HYSTERESIS_PX = 4.0  # nearer the border than at its start by this much: the attempt ends
MIN_SHARE = 0.3  # a direction allowing less than this share of the clearance is skipped
MAX_BEND_DEG = 45.0  # ... or turned further than this from its direction by the image border
DOWN_LIMIT = 0.7  # directions more downward than this (cosine with the image's down) are left out
# A corner inside the image's margin band is pulled back in as if its goal were this many times
# its depth into the band further in (acquisition_error).
BORDER_GAIN = 3.0


@dataclass(frozen=True)
class Acquisition:
    """One acquisition in progress: why it started (what the target was, e.g. ``target
    partial``), when (sim s), its attempt (0-based), when that attempt started, the goal of
    the hand marker's corners (4×2 px), the image directions left to try (unit, px) and how
    far the hand was from the image border when the attempt began."""

    why: str
    started_s: float
    attempt: int
    attempt_started_s: float
    goal_px: FloatArray
    directions: tuple[tuple[float, float], ...]
    start_border_px: float  # the hand's distance from the image border when it began
    every: tuple[tuple[float, float], ...] = ()  # all the directions, in their order

    def describe(self, attempt: int, attempts: int) -> str:
        """For the status and the twist's reason: ``acquiring: target partial, attempt 1/4``
        (``attempt`` counted over the run, 1-based)."""
        return f"acquiring: {self.why}, attempt {attempt}/{attempts}"


def uncover_directions(
    hand_centre_px: FloatArray, elbow_px: FloatArray | None, up_px: FloatArray | None = None
) -> list[FloatArray]:
    """Unit image directions to try, best first (see the module doc). ``up_px``: the image
    direction of the world's vertical at the hand; a direction going down (towards the table
    the target lies on) more than sideways is left out, since at constant depth it would press
    the hand onto the table, and one going down at all comes after the rest; near-duplicates
    are dropped. Without the elbow's image, up, left, right (then the diagonals, given
    ``up_px``)."""
    up = None
    if up_px is not None and np.linalg.norm(up_px) > 1e-9:
        up = np.asarray(up_px, dtype=float) / np.linalg.norm(up_px)
    candidates: list[FloatArray] = []
    if elbow_px is not None:
        back = np.asarray(elbow_px, dtype=float) - np.asarray(hand_centre_px, dtype=float)
        norm = float(np.linalg.norm(back))
        if norm > 1.0:
            back = back / norm
            across = np.array([-back[1], back[0]])
            if up is not None and across @ up < 0:
                across = -across  # the rising side first
            candidates = [across, -across, back, -back]
    if not candidates:
        candidates = [np.array(d, dtype=float) for d in ((0.0, -1.0), (-1.0, 0.0), (1.0, 0.0))]
    if up is not None:
        side = candidates[0] - (candidates[0] @ up) * up
        side = side / np.linalg.norm(side) if np.linalg.norm(side) > 1e-9 else np.zeros(2)
        diagonals = [
            (up + side) / np.linalg.norm(up + side),
            (up - side) / np.linalg.norm(up - side),
        ]
        candidates = [*candidates[:2], up, *candidates[2:], *diagonals]
        candidates = [d for d in candidates if d @ up >= -DOWN_LIMIT]
        # What the hand hides lies below it: slides with a downward share come last.
        candidates = sorted(candidates, key=lambda d: bool(d @ up < -1e-9))
    distinct: list[FloatArray] = []
    for d in candidates:
        if all(d @ e < 0.99 for e in distinct):
            distinct.append(d)
    return distinct


def diagonal_px(corners_px: FloatArray) -> float:
    """Mean length of the square's two image diagonals."""
    c = np.asarray(corners_px, dtype=float)
    return 0.5 * float(np.linalg.norm(c[0] - c[2]) + np.linalg.norm(c[1] - c[3]))


def image_margin_px(k: CameraIntrinsics) -> float:
    """How far inside the image border an acquisition goal stays."""
    return max(IMAGE_MARGIN_PX, IMAGE_MARGIN_FRACTION * min(k.width_px, k.height_px))


def border_distance_px(corners_px: FloatArray, k: CameraIntrinsics) -> float:
    """How far the corner nearest the image border is from it (px)."""
    c = np.asarray(corners_px, dtype=float)
    return float(min(c.min(), (k.width_px - 1 - c[:, 0]).min(), (k.height_px - 1 - c[:, 1]).min()))


def near_border(corners_px: FloatArray, k: CameraIntrinsics, start_px: float) -> bool:
    """A corner within half the goal margin of the border, and nearer it than when the
    attempt began (``start_px``, :func:`border_distance_px` then): the attempt stops there."""
    now = border_distance_px(corners_px, k)
    return now < 0.5 * image_margin_px(k) and now < start_px - BORDER_HYSTERESIS_PX


def goal_corners(
    corners_px: FloatArray, direction: FloatArray, distance_px: float, k: CameraIntrinsics
) -> FloatArray | None:
    """``corners_px`` slid along ``direction`` by ``distance_px``, each image axis's share of
    the slide cut to the room the image leaves (every corner :func:`image_margin_px` inside
    it); None when less than :data:`MIN_SHARE` of the distance is left, or the slide so cut
    points more than :data:`MAX_BEND_DEG` away from ``direction``.

    Cut per axis, not as a whole: a hand near the right border asked to go up and a little to
    the right goes straight up. Scaled down as a whole, the same slide would end after the few
    pixels the right border leaves, and that direction would be skipped; yet going up is what
    lifts the hand and its forearm off a target beside the border (the domain study's starts
    with the hand on the target's right-hand part)."""
    c = np.asarray(corners_px, dtype=float)
    d = np.asarray(direction, dtype=float)
    margin = image_margin_px(k)
    room_low = np.maximum(c.min(axis=0) - margin, 0.0)  # how far each axis may go down
    room_high = np.maximum(
        np.array([k.width_px - 1, k.height_px - 1]) - margin - c.max(axis=0), 0.0
    )
    slide = np.clip(distance_px * d, -room_low, room_high)
    length = float(np.linalg.norm(slide))
    if length < MIN_SHARE * distance_px:
        return None
    if slide @ d < math.cos(math.radians(MAX_BEND_DEG)) * length * float(np.linalg.norm(d)):
        return None
    return c + slide


def start(
    why: str,
    t_s: float,
    corners_px: FloatArray,
    elbow_px: FloatArray | None,
    k: CameraIntrinsics,
    up_px: FloatArray | None = None,
) -> Acquisition | None:
    """A new acquisition from the hand's corners now, or None when no direction is open."""
    directions = [
        tuple(d) for d in uncover_directions(np.mean(corners_px, axis=0), elbow_px, up_px)
    ]
    return _next_attempt(why, t_s, t_s, -1, corners_px, directions, tuple(directions), k)


def _next_attempt(
    why: str,
    started_s: float,
    t_s: float,
    attempt: int,
    corners_px: FloatArray,
    directions: list[tuple[float, float]],
    every: tuple[tuple[float, float], ...],
    k: CameraIntrinsics,
) -> Acquisition | None:
    """The next attempt: the first untried direction with room in the image; once every
    direction has been tried, the first with room from where the hand is now."""
    distance = CLEARANCE_DIAGONALS * diagonal_px(corners_px)
    for pool in (directions, list(every)):  # the untried ones, then any from where it is now
        pool = list(pool)
        while pool:
            d = pool.pop(0)
            goal = goal_corners(corners_px, np.array(d), distance, k)
            if goal is not None:
                border = border_distance_px(corners_px, k)
                return Acquisition(
                    why, started_s, attempt + 1, t_s, goal, tuple(pool), border, tuple(every)
                )
    return None


def advance(
    acq: Acquisition,
    corners_px: FloatArray,
    t_s: float,
    attempt_s: float,
    k: CameraIntrinsics,
) -> Acquisition | None:
    """The acquisition at ``t_s`` with the hand's corners there: the same attempt, the next
    one when this one reached its goal, came near the image border (:func:`near_border`) or
    ran out of time, or None when no direction is left
    (it failed). The caller bounds the number of attempts."""
    reached = bool(np.all(np.linalg.norm(corners_px - acq.goal_px, axis=1) < REACHED_PX))
    near = near_border(corners_px, k, acq.start_border_px)
    over = reached or near or t_s - acq.attempt_started_s >= attempt_s
    if not over:
        return acq
    return _next_attempt(
        acq.why, acq.started_s, t_s, acq.attempt, corners_px, list(acq.directions), acq.every, k
    )


def border_push(corners_px: FloatArray, k: CameraIntrinsics) -> FloatArray:
    """How far each corner lies inside the image's margin band (px, 4×2, pointing towards the
    border; zero for a corner the band does not hold): the extra error that pulls such corners
    back in (:func:`acquisition_error`)."""
    c = np.asarray(corners_px, dtype=float)
    margin = image_margin_px(k)
    inside = np.clip(c, [margin, margin], [k.width_px - 1 - margin, k.height_px - 1 - margin])
    return c - inside


def acquisition_error(
    corners_px: FloatArray, goal_px: FloatArray, k: CameraIntrinsics
) -> FloatArray:
    """The error the acquisition servoes to zero (normalized, 8): the corners' offset from
    their goal, plus :data:`BORDER_GAIN` times how far they are inside the margin band. The
    slide is not a straight image line (the law may turn the square on the way), and a hand
    that starts near the border could otherwise curve out of the image, where vision loses it
    (a goal inside the image alone does not prevent that)."""
    c = np.asarray(corners_px, dtype=float)
    target = np.asarray(goal_px, dtype=float) - BORDER_GAIN * border_push(c, k)
    return (pixel_to_normalized(c, k) - pixel_to_normalized(target, k)).reshape(-1)


def acquisition_twist_cam(
    corners_px: FloatArray,
    depth_m: FloatArray,
    goal_px: FloatArray,
    k: CameraIntrinsics,
    gain: float,
) -> FloatArray:
    """The hand twist (camera frame, at the camera origin) that slides the hand marker's image
    towards ``goal_px`` and keeps it off the border: a translation only, ``v = λ · L_v⁺ · e``
    with ``e`` :func:`acquisition_error` and ``L_v`` the translational columns of L at the
    current points and measured depths (the eye-to-hand sign, as in
    :mod:`services.controller.interaction`), ``ω = 0``. A slide needs no turn, and a turn swings
    the square's corners, the outer ones towards the border: with all six degrees of freedom
    the law answered a corner near the border by spinning the square about the optical axis."""
    s = pixel_to_normalized(np.asarray(corners_px, dtype=float), k)
    error = acquisition_error(corners_px, goal_px, k)
    l_v = interaction_matrix(s, np.asarray(depth_m, dtype=float))[:, :3]
    return np.concatenate([gain * np.linalg.pinv(l_v) @ error, np.zeros(3)])
