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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common import kinematics as kin
from common.kinematics import FloatArray
from services.controller.arm import ELBOW_FRAME  # where the forearm starts
from services.controller.clearance import Plane

WRIST_FRAME = 4  # kinematics.frame_transforms index: DH frame 5, where the forearm ends
FOREARM_JOINTS = 4  # the joints that move it: the shoulder's three and the elbow
NEAR_M = 0.03  # beyond d_min by more than this the forearm is left free: no bound
SAMPLES = 65  # points along the forearm per pass of the nearest-point search


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
    u = u / np.linalg.norm(u)
    return TopFace(plane.point_m, u, kin.cross(n, u), n, side_m / 2)


def gaps_to_object(points_m: FloatArray, face: TopFace) -> FloatArray:
    """For each point (k×3), how far it lies beyond the object along the face's sides and its
    normal (k×3, in ``u``, ``w``, ``normal``; 0 where it lies within): the vector from the
    object's nearest point, in the face's axes."""
    d = np.atleast_2d(np.asarray(points_m, dtype=float)) - face.centre_m
    x, y, z = d @ face.u, d @ face.w, d @ face.normal
    return np.column_stack(
        [
            np.sign(x) * np.maximum(np.abs(x) - face.half_side_m, 0.0),
            np.sign(y) * np.maximum(np.abs(y) - face.half_side_m, 0.0),
            np.maximum(z, 0.0),
        ]
    )


def distances_to_object(points_m: FloatArray, face: TopFace) -> FloatArray:
    """The distance (m) from each point (k×3) to the object, the prism under its top face
    (down without end)."""
    return np.sqrt(np.sum(gaps_to_object(points_m, face) ** 2, axis=1))


def distance_to_object(point_m: FloatArray, face: TopFace) -> tuple[float, FloatArray]:
    """:func:`distances_to_object` of one point, and the unit direction from the object's
    nearest point (out through the top from inside)."""
    gap = gaps_to_object(point_m, face)[0]
    dist = float(np.sqrt(np.sum(gap**2)))
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
    lo, hi = 0.0, 1.0
    for _ in range(2):
        t = np.linspace(lo, hi, SAMPLES)
        dist = distances_to_object(a_m + t[:, None] * (b_m - a_m), face)
        i = int(np.argmin(dist))
        # The distance changes no faster than the point moves: nothing between two samples
        # is nearer than the nearest sample less half their spacing.
        if dist[i] - 0.5 * (t[1] - t[0]) * float(np.linalg.norm(b_m - a_m)) > beyond_m:
            return float("nan"), float("inf")
        lo, hi = t[max(i - 1, 0)], t[min(i + 1, SAMPLES - 1)]
    return float(t[i]), float(dist[i])


def point_jacobian(frames: list[FloatArray], point_m: FloatArray) -> FloatArray:
    """The linear Jacobian (3×6, base frame) of a point carried by the forearm: joint k turns
    it about frame k's z axis through frame k's origin; the wrist's joints do not move it."""
    jp = np.zeros((3, kin.N_JOINTS))
    for k in range(FOREARM_JOINTS):
        jp[:, k] = kin.cross(frames[k][:3, 2], point_m - frames[k][:3, 3])
    return jp


def forearm_bounds(
    frames: list[FloatArray], face: TopFace, min_distance_m: float, rate_1_s: float
) -> tuple[FloatArray, FloatArray]:
    """``(A, b)`` from the joint angles' DH frames (``kinematics.frame_transforms``): the
    forearm's bound as ``A · twist ≥ b`` (1×6 and 1 while it is within
    :data:`NEAR_M` of ``min_distance_m``, else empty), the twist (v, ω) at the end-effector
    origin, base frame, as :func:`.clearance.clearance_bounds`: ``A`` its nearest point's
    ``ḋ`` for a twist, ``b`` the least ``ḋ`` allowed, ``−rate · (d − d_min)``."""
    elbow, wrist = frames[ELBOW_FRAME][:3, 3], frames[WRIST_FRAME][:3, 3]
    t, dist = nearest_along(elbow, wrist, face, beyond_m=min_distance_m + NEAR_M)
    if dist > min_distance_m + NEAR_M:
        return np.zeros((0, 6)), np.zeros(0)
    nearest = elbow + t * (wrist - elbow)
    dist, g = distance_to_object(nearest, face)
    joint_rates = np.linalg.pinv(kin.jacobian_of_frames(frames))  # J⁺: q̇ of a twist
    row = g @ point_jacobian(frames, nearest) @ joint_rates
    return row[None, :], np.array([-rate_1_s * (dist - min_distance_m)])
