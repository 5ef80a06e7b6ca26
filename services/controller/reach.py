"""Which corner pairings the arm can reach: the goal posture of each, solved from the encoders
and the measured corners. Pure.

A plain square looks the same turned by 90°, so the hand may end in any of four postures, and
the controller takes the one needing the least turn (:mod:`.pairing`). For some starts that
posture lies beyond a joint limit while a quarter turn the other way is well inside them: the
law then drives the hand into the limit and stops there. Here each pairing's goal is carried
into a posture of the arm: the rigid motion taking the hand's measured corners onto the
target's paired goal corners (Kabsch), applied to the end effector's pose from the encoders,
then a damped least-squares inverse kinematics seeded at the joints' present angles, so that
the posture found is the nearby one the servo's path would lead to.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from common import kinematics as kin
from common.marker import Marker
from services.controller.twist import camera_points_to_base

FloatArray = NDArray[np.float64]
T = TypeVar("T")

# Iterations of the inverse kinematics per pairing: from the present posture the nearby solution
# is found within a few tens; more only polish one that is already inside the tolerances.
IK_ITERATIONS = 100
# A posture counts as reached when it puts the end effector this close to its goal: the goal
# comes from measured corners, and a posture beyond a limit misses by centimetres (the IK
# clips every step at the limits).
REACH_TOLERANCE_M = 2e-3
REACH_TOLERANCE_RAD = np.deg2rad(1.0)
# The inverse kinematics stops once no joint moves by more than this in a step: held at a limit
# (it clips every step), or settled short of the goal, it gets no further.
IK_STALL_RAD = 1e-6


def rigid_motion(source: FloatArray, destination: FloatArray) -> FloatArray:
    """The 4×4 proper rigid motion taking the points ``source`` (N×3) onto ``destination``
    (N×3) in the least-squares sense (Kabsch's algorithm, the reflection excluded)."""
    src_c, dst_c = source.mean(axis=0), destination.mean(axis=0)
    u, _, vt = np.linalg.svd((source - src_c).T @ (destination - dst_c))
    flip = np.sign(np.linalg.det(vt.T @ u.T))
    rotation = vt.T @ np.diag([1.0, 1.0, flip]) @ u.T
    return kin.homogeneous(rotation, dst_c - rotation @ src_c)


def goal_poses_ee(
    hand: Marker,
    goal: Marker,
    t_base_cam: FloatArray,
    t_base_ee: FloatArray,
    pairings: Sequence[int] = range(4),
) -> FloatArray:
    """For each of the four cyclic pairings k (hand corner i → goal corner (i + k) % 4), the
    end effector's pose (4×4×4, base frame) that puts the hand's corners on the goal's (both
    markers' 3-D corners, camera frame; the end effector at ``t_base_ee``, from the encoders).
    The hand rides rigidly on the end effector, so each depends on the physical pairing only,
    not on where the hand is now: their orientations tell the pairings apart whatever the
    corners' labels. ``pairings``: only these k, in this order (the poses of the others are
    not computed)."""
    hand_base = camera_points_to_base(hand.points_m, t_base_cam)
    goal_base = camera_points_to_base(goal.points_m, t_base_cam)
    return np.array(
        [rigid_motion(hand_base, np.roll(goal_base, -k, axis=0)) @ t_base_ee for k in pairings]
    )


def goal_posture(t_goal_ee: FloatArray, q_rad: FloatArray) -> tuple[FloatArray, bool]:
    """The joint angles putting the end effector at ``t_goal_ee`` (one of
    :func:`goal_poses_ee`), found by an inverse kinematics from the posture ``q_rad`` clipped
    at the joint limits, and whether it reached the goal. Local: a posture on another branch
    of the arm, beyond a limit from here, is not looked for."""
    q, position_error_m, rotation_error_rad = kin.inverse_kinematics(
        t_goal_ee, np.asarray(q_rad, dtype=float), iterations=IK_ITERATIONS, stall_rad=IK_STALL_RAD
    )
    reached = bool(
        position_error_m < REACH_TOLERANCE_M and rotation_error_rad < REACH_TOLERANCE_RAD
    )
    return q, reached


def goal_postures(poses_ee: FloatArray, q_rad: FloatArray) -> tuple[FloatArray, list[bool]]:
    """For each pairing's goal pose (:func:`goal_poses_ee`), its goal posture (4×6, rad;
    :func:`goal_posture` from ``q_rad``) and whether the inverse kinematics reaches it within
    the joint limits."""
    solved = [goal_posture(pose, q_rad) for pose in poses_ee]
    return np.array([q for q, _ in solved]), [reached for _, reached in solved]


def carried_over(
    values: Sequence[T], rotations_then: FloatArray, rotations_now: FloatArray
) -> list[T]:
    """``values`` (one per pairing, indexed as when ``rotations_then`` were computed: a verdict,
    a goal posture) for the pairings as indexed now: vision may have labelled a marker's
    corners afresh since (it lost the hand, say), which shifts the indices. Each pairing now
    takes the value of the one then whose goal orientation is nearest its own (the four lie
    a quarter turn apart)."""
    out = []
    for now in rotations_now:
        angles = [kin.rotation_error_rad(then, now) for then in rotations_then]
        out.append(values[int(np.argmin(angles))])
    return out
