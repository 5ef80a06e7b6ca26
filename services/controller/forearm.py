"""Keep the forearm off the object the hand reaches for. Pure.

The goal puts the hand just above the object's top face, and the forearm comes down beside
the object: at the goal its wrist end is a few millimetres clear of the face's edge. On the
way the image law moves the hand without regard for the forearm, whose wrist end crossed the
face's edge and pressed on it (the random-start campaign counts such runs, docs/campaign.md).
The hand's clearance (:mod:`.clearance`) keeps a whole plane,
which the forearm cannot: at the goal its wrist end is below that plane, beside the object.

So the forearm is kept off the object itself, the square prism under its top face: the face
from vision (the red marker's measured corners through the assumed camera pose), its side from
the scenario's object model (``target.object_side_m``, as vision is given the marker's size).
The point of the forearm's axis nearest the object, from the encoders and the robot model,
keeps its distance ``d`` above ``d_min`` (the limb's radius and a margin) by the same control
barrier as the hand's corners, ``ḋ ≥ −rate · (d − d_min)``, with ``ḋ = g · J_p · J⁺ · V``:
``g`` the unit direction from the object's nearest point, ``J_p`` the point's Jacobian and
``J⁺ V`` the joint rates actuation makes of the twist ``V``. One linear bound on the twist
(:func:`forearm_bounds`), corrected together with the hand's.

At the goal the forearm is only a little farther from the object than ``d_min``, and the
object is where the camera puts it: a calibration error that moves it towards the forearm
would put the goal itself inside the margin, and the bound would hold the hand short of a goal
its image error still reaches. So near the goal the margin is capped by the forearm's distance
at the goal posture (the reach check's, :mod:`.reach`) less :data:`GOAL_SLACK_M`, and rises
back to ``d_min`` as the wrist moves away from where that posture puts it
(:func:`margin_near_goal`): a funnel onto the goal. The bound does not keep the arm from its
own goal, and keeps the whole margin elsewhere, where the same calibration error may put the
object nearer than it is seen (docs/architecture.md). The funnel stops at the limb's radius:
a goal posture that would put the forearm's surface into the object as seen holds the hand
short by that overlap.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from common import kinematics as kin
from common.kinematics import FloatArray
from services.controller.arm import ELBOW_FRAME  # where the forearm starts
from services.controller.clearance import DEGENERATE_SHARE, Plane

WRIST_FRAME = 4  # kinematics.frame_transforms index: DH frame 5, where the forearm ends
FOREARM_JOINTS = 4  # the joints that move it: the shoulder's three and the elbow
NEAR_M = 0.03  # beyond d_min by more than this the forearm is left free: no bound
SAMPLES = 65  # points along the forearm per pass of the nearest-point search
# How much nearer than the goal posture's forearm the bound lets the forearm come (m): the
# goal then lies outside the bound, which slows the approach there by rate · this at most.
GOAL_SLACK_M = 0.5e-3
# Within this of the wrist's place at the goal (m) the margin is lowered, linearly to the
# goal's own: the image error alone drives the last millimetres along the line of sight
# slowly, and a narrower funnel held the hand 5 mm short of its goal that way, out of reach
# of the lowered margin, while its image error had converged.
FUNNEL_RADIUS_M = 0.02
# The first pass's samples along the segment (np.linspace(0, 1, SAMPLES), the same each call).
_FIRST_PASS_T = np.linspace(0.0, 1.0, SAMPLES)
_FIRST_PASS_T.setflags(write=False)
_SAMPLE_INDEX = np.arange(SAMPLES, dtype=float)


@dataclass(frozen=True)
class TopFace:
    """The object's square top face (base frame, m): its centre, unit vectors along its sides
    (``u``, ``w``) and up out of it (``normal``), and half its side."""

    centre_m: FloatArray
    u: FloatArray
    w: FloatArray
    normal: FloatArray
    half_side_m: float


def top_face(plane: Plane, corners_base_m: FloatArray, side_m: float) -> TopFace:
    """The face ``side_m`` wide on the red marker's plane, centred on it, its sides along the
    marker's (corners 0 → 1 and 0 → 3, base frame)."""
    n = plane.normal
    u = corners_base_m[1] - corners_base_m[0]
    u = u - (u @ n) * n
    # The diagonals' difference runs 0 → 1 as well, twice as long on a square, and is not nil
    # when they cross (the wire's check): the axis when corners 0 and 1 (nearly) merge.
    d = (corners_base_m[2] - corners_base_m[0]) - (corners_base_m[3] - corners_base_m[1])
    d = d - (d @ n) * n
    if kin.norm(u) < DEGENERATE_SHARE * kin.norm(d):
        u = d
    u = u / kin.norm(u)
    return TopFace(plane.point_m, u, kin.cross(n, u), n, side_m / 2)


def _in_face_axes(points_m: FloatArray, face: TopFace) -> FloatArray:
    """Each point (k×3) from the face's centre, in its axes ``u``, ``w``, ``normal`` (k×3)."""
    d = np.atleast_2d(np.asarray(points_m, dtype=float)) - face.centre_m
    out = np.empty((len(d), 3))
    out[:, 0], out[:, 1], out[:, 2] = d @ face.u, d @ face.w, d @ face.normal
    return out


def gaps_to_object(points_m: FloatArray, face: TopFace) -> FloatArray:
    """For each point (k×3), how far it lies beyond the object along the face's sides and its
    normal (k×3, in ``u``, ``w``, ``normal``; 0 where it lies within): the vector from the
    object's nearest point, in the face's axes."""
    gaps = _in_face_axes(points_m, face)
    sides = gaps[:, :2]  # a view: both sides at once
    sides[...] = np.sign(sides) * np.maximum(np.abs(sides) - face.half_side_m, 0.0)
    np.maximum(gaps[:, 2], 0.0, out=gaps[:, 2])
    return gaps


def distances_to_object(points_m: FloatArray, face: TopFace) -> FloatArray:
    """The distance (m) from each point (k×3) to the object, the prism under its top face
    (down without end): the length of :func:`gaps_to_object`."""
    return np.sqrt(np.add.reduce(gaps_to_object(points_m, face) ** 2, axis=1))


def distance_to_object(point_m: FloatArray, face: TopFace) -> tuple[float, FloatArray]:
    """:func:`distances_to_object` of one point, and the unit direction from the object's
    nearest point (out through the top from inside)."""
    gap = gaps_to_object(point_m, face)[0]
    dist = float(np.sqrt((gap**2).sum()))
    if dist < 1e-12:
        return 0.0, face.normal
    return dist, (gap[0] * face.u + gap[1] * face.w + gap[2] * face.normal) / dist


def nearest_along(
    a_m: FloatArray, b_m: FloatArray, face: TopFace, beyond_m: float = np.inf
) -> tuple[float, float]:
    """Where on the segment ``a → b`` (0 … 1) it comes nearest the object, and how near (m);
    ``(nan, inf)`` as soon as the whole segment is seen to lie farther than ``beyond_m``.
    The distance to a convex body is convex along a line, so the least of evenly spaced samples
    brackets the minimum between its neighbours; sampled again there, 0.1 mm apart on a 21 cm
    forearm, the least sample is within 0.05 mm of the least distance."""
    along = b_m - a_m
    length_m = kin.norm(along)
    t = _FIRST_PASS_T
    for sweep in range(2):
        dist = distances_to_object(a_m + t[:, None] * along, face)
        i = int(dist.argmin())
        # The distance changes no faster than the point moves: nothing between two samples
        # is nearer than the nearest sample less half their spacing.
        if dist[i] - 0.5 * (t[1] - t[0]) * length_m > beyond_m:
            return float("nan"), float("inf")
        if sweep == 0:  # sampled again between the least sample's neighbours
            t = _samples(t[max(i - 1, 0)], t[min(i + 1, SAMPLES - 1)])
    return float(t[i]), float(dist[i])


def _samples(lo: float, hi: float) -> FloatArray:
    """``np.linspace(lo, hi, SAMPLES)``, bit for bit (the same steps as it takes them), without
    its generic per-call overhead."""
    step = (hi - lo) / (SAMPLES - 1)
    if step == 0:  # np.linspace's own handling of a denormal step
        return np.linspace(lo, hi, SAMPLES)
    t = _SAMPLE_INDEX * step
    t += lo
    t[-1] = hi
    return t


def point_jacobians(frames: Sequence[FloatArray], points_m: FloatArray) -> FloatArray:
    """The linear Jacobian (3×6, base frame) of each point (k×3) carried by the forearm, at
    once (k×3×6): joint k turns a point about frame k's z axis through frame k's origin; the
    wrist's joints do not move it."""
    poses = np.array(frames[:FOREARM_JOINTS])
    z = poses[:, :3, 2]  # joint k's axis
    lever = points_m[:, None, :] - poses[:, :3, 3]  # from joint k's origin to each point
    jp = np.zeros((len(points_m), 3, kin.N_JOINTS))
    # z × lever of each joint and point at once
    jp[:, 0, :FOREARM_JOINTS], jp[:, 1, :FOREARM_JOINTS], jp[:, 2, :FOREARM_JOINTS] = (
        kin.cross_components(z, lever)
    )
    return jp


def forearm_distance_m(frames: Sequence[FloatArray], face: TopFace) -> float:
    """How near the forearm's axis comes to the object (m), the arm at ``frames``."""
    return nearest_along(frames[ELBOW_FRAME][:3, 3], frames[WRIST_FRAME][:3, 3], face)[1]


def margin_near_goal(
    min_distance_m: float, frames: list[FloatArray], goal_q_rad: FloatArray | None, face: TopFace
) -> tuple[float, FloatArray]:
    """The forearm's margin with the arm at ``frames``, and its gradient in the wrist's
    position (base frame): ``min_distance_m`` (gradient 0), or, where the goal posture
    ``goal_q_rad`` puts the forearm's axis nearer the object than that and
    :data:`GOAL_SLACK_M`, a funnel: that distance less the slack with the wrist at its place
    at the goal, rising linearly with the wrist's distance from there to ``min_distance_m``
    at :func:`funnel_radius_m`. Never below the limb's radius: a goal posture that would put
    the forearm's surface into the object as seen is not trusted that far (the hand is then
    held short of it by the overlap)."""
    flat = np.zeros(3)
    if goal_q_rad is None:
        return min_distance_m, flat
    q_key = np.asarray(goal_q_rad, dtype=float).tobytes()
    goal_frames = _frames_at(q_key)
    away = frames[WRIST_FRAME][:3, 3] - goal_frames[WRIST_FRAME][:3, 3]
    off_m = kin.norm(away)
    radius_m = funnel_radius_m(min_distance_m)
    if off_m >= radius_m:  # outside the funnel, whatever the goal's clearance
        return min_distance_m, flat
    at_goal = max(_goal_distance_m(q_key, *_face_key(face)) - GOAL_SLACK_M, kin.LIMB_RADIUS_M)
    if at_goal >= min_distance_m:
        return min_distance_m, flat
    slope = (min_distance_m - at_goal) / radius_m
    return at_goal + slope * off_m, (slope * away / off_m if off_m > 1e-12 else flat)


@functools.lru_cache(maxsize=8)
def _frames_at(q_rad: bytes) -> tuple[FloatArray, ...]:
    """``kinematics.frame_transforms`` of the joint angles ``q_rad`` (float64 bytes), read-only:
    the goal posture stays the same over many frames, its kinematics need not be redone."""
    frames = kin.frame_transforms(np.frombuffer(q_rad, dtype=float))
    for frame in frames:
        frame.setflags(write=False)
    return tuple(frames)


def _face_key(face: TopFace) -> tuple[bytes, bytes, bytes, bytes, float]:
    """The face as :func:`_goal_distance_m` takes it: its vectors' float64 bytes, its half side."""
    vectors = (face.centre_m, face.u, face.w, face.normal)
    centre, u, w, normal = (np.asarray(v, dtype=float).tobytes() for v in vectors)
    return centre, u, w, normal, face.half_side_m


@functools.lru_cache(maxsize=8)
def _goal_distance_m(
    q_rad: bytes, centre: bytes, u: bytes, w: bytes, normal: bytes, half_side_m: float
) -> float:
    """:func:`forearm_distance_m` at the joint angles ``q_rad`` from the face of
    :func:`_face_key`: the goal posture and the face vision measures stay the same, to the
    bit, over many frames (a still target), and the search need not be redone."""
    vectors = (np.frombuffer(b, dtype=float) for b in (centre, u, w, normal))
    return forearm_distance_m(_frames_at(q_rad), TopFace(*vectors, half_side_m))


def funnel_radius_m(min_distance_m: float) -> float:
    """How far from the wrist's place at the goal the funnel reaches (m):
    :data:`FUNNEL_RADIUS_M`, or twice the margin over the limb's radius where that is more,
    so that the funnel's wall never rises faster than half the wrist's motion (a steeper wall
    would let the gap shrink as the forearm moves away from the object)."""
    return max(FUNNEL_RADIUS_M, 2.0 * (min_distance_m - kin.LIMB_RADIUS_M))


def forearm_bounds(
    frames: list[FloatArray],
    face: TopFace,
    min_distance_m: float,
    rate_1_s: float,
    goal_q_rad: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray]:
    """``(A, b)`` from the joint angles' DH frames (``kinematics.frame_transforms``): the
    forearm's bound as ``A · twist ≥ b`` (1×6 and 1 while it is within
    :data:`NEAR_M` of ``min_distance_m``, else empty), the twist (v, ω) at the end-effector
    origin, base frame, as :func:`.clearance.clearance_bounds`: ``A`` the rate of the gap
    ``d − d_min`` for a twist, ``b`` the least rate allowed, ``−rate · (d − d_min)``;
    ``d_min`` is ``min_distance_m``, or near the goal posture ``goal_q_rad`` the funnel's
    (:func:`margin_near_goal`), whose own rate the gap's includes."""
    elbow, wrist = frames[ELBOW_FRAME][:3, 3], frames[WRIST_FRAME][:3, 3]
    t, dist = nearest_along(elbow, wrist, face, beyond_m=min_distance_m + NEAR_M)
    if dist > min_distance_m + NEAR_M:
        return np.zeros((0, 6)), np.zeros(0)
    margin_m, margin_gradient = margin_near_goal(min_distance_m, frames, goal_q_rad, face)
    nearest = elbow + t * (wrist - elbow)
    dist, g = distance_to_object(nearest, face)
    joint_rates = kin.pinv(kin.jacobian_of_frames(frames))  # J⁺: q̇ of a twist
    # ḋ − (the margin's own rate, as the wrist moves through the funnel): the barrier keeps
    # d − margin, which the funnel lets shrink to 0 at the goal.
    jp_nearest, jp_wrist = point_jacobians(frames, np.array([nearest, wrist]))
    gap_rate = g @ jp_nearest - margin_gradient @ jp_wrist
    row = gap_rate @ joint_rates
    return row[None, :], np.array([-rate_1_s * (dist - margin_m)])
