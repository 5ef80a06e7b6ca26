"""UMay arm kinematics from the thesis's modified (Craig) Denavit-Hartenberg table (Table 1.1).

Conventions
-----------
- Base frame = DH frame 0 = the arm base (right shoulder) frame, which is also the simulated
  world frame: **x forward** (towards the table), **y up** (vertical), **z to the robot's
  right**. Joint 1 is thus the shoulder pitch (axis through both shoulders), and at q = 0 the
  upper arm points sideways with the forearm folded back onto it. This mounting keeps the
  shoulder's singularity (joint 1 and joint 3 axes aligned when q2 = 0) away from the reaching
  workspace in front of the robot; with z up instead, half the table is unreachable.
- Link transform: ``T(i-1, i) = Rx(alpha[i-1]) · Tx(a[i-1]) · Rz(theta[i]) · Tz(d[i])``.
- Joint i rotates about the z axis of DH frame i. The end-effector frame is DH frame 6.
- The geometric Jacobian maps joint rates (rad/s) to the end-effector twist ``(v, ω)`` in the
  base frame, ``v`` being the velocity of the frame-6 origin (m/s), ``ω`` the angular velocity
  (rad/s).

All functions are pure: they take and return numpy arrays, lengths in metres, angles in radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

N_JOINTS = 6


@dataclass(frozen=True)
class DHRow:
    """One row of the modified DH table (lengths in metres, angles in radians)."""

    alpha_prev_rad: float
    a_prev_m: float
    d_m: float
    theta_offset_rad: float = 0.0


# Table 1.1 of the thesis, millimetres converted to metres.
UMAY_DH: tuple[DHRow, ...] = (
    DHRow(0.0, 0.0, 0.0),
    DHRow(-np.pi / 2, 0.0, 0.020),
    DHRow(np.pi / 2, 0.005, 0.264),
    DHRow(-np.pi / 2, 0.0, 0.0),
    DHRow(-np.pi / 2, 0.0, 0.212),
    DHRow(np.pi / 2, 0.0, 0.0),
)

# Joint limits (rad). The thesis gives none; these follow a child's right arm mapped onto the
# DH joints (shoulder pitch/roll/yaw, elbow, forearm twist, wrist), kept a little wider than
# the ranges the default scenarios use. The elbow's is not a human's: folded at 0, straight at
# ±180°, it bends either way here (docs/architecture.md, "Joint limits").
JOINT_LOWER_RAD: FloatArray = np.deg2rad([-150.0, -100.0, -150.0, -150.0, -150.0, -100.0])
JOINT_UPPER_RAD: FloatArray = np.deg2rad([150.0, 100.0, 150.0, 150.0, 150.0, 100.0])
# Joint speed limits (rad/s), servo-class values for a child-sized arm.
JOINT_VELOCITY_LIMIT_RAD_S: FloatArray = np.full(N_JOINTS, 1.5)
# Within this of a joint limit the speed towards it falls to zero at the limit.
POSITION_LIMIT_ZONE_RAD = float(np.deg2rad(10.0))


def position_bound_rad_s(
    qdot_rad_s: FloatArray,
    q_rad: FloatArray,
    lower_rad: FloatArray = JOINT_LOWER_RAD,
    upper_rad: FloatArray = JOINT_UPPER_RAD,
    slow_zone_rad: float = POSITION_LIMIT_ZONE_RAD,
    vmax_rad_s: FloatArray = JOINT_VELOCITY_LIMIT_RAD_S,
) -> FloatArray:
    """Each joint's speed bound in the direction it is asked to move: its speed limit times
    the fraction of the slow-down zone left before the limit that way (1 outside the zone, 0
    at the limit). Actuation bounds its commands with it, at the angles of their frame; the
    sim's motors bound what they follow with it again, at the angles the joints have now."""
    q = np.asarray(q_rad, dtype=float)
    to_upper = ((upper_rad - q) / slow_zone_rad).clip(0.0, 1.0)  # np.clip's own method
    to_lower = ((q - lower_rad) / slow_zone_rad).clip(0.0, 1.0)
    qdot = np.asarray(qdot_rad_s, dtype=float)
    return np.asarray(vmax_rad_s, dtype=float) * np.where(qdot > 0, to_upper, to_lower)


def rot_x(angle_rad: float) -> FloatArray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle_rad: float) -> FloatArray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle_rad: float) -> FloatArray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def homogeneous(rotation: FloatArray, translation: FloatArray) -> FloatArray:
    """4×4 homogeneous transform from a 3×3 rotation and a 3-vector."""
    t = np.eye(4)
    t[:3, :3] = rotation
    t[:3, 3] = translation
    return t


def quaternion_xyzw(rotation: FloatArray) -> tuple[float, float, float, float]:
    """Quaternion (x, y, z, w), pybullet's and Foxglove's order, of a 3×3 rotation matrix
    (Shepperd's method: the largest of the trace and the diagonal picks the branch, so no
    division by a small number). Unit up to rounding; its sign is the branch's."""
    m = np.asarray(rotation, dtype=float)
    trace = np.trace(m)
    if trace > 0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4]
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + m[i, i] - m[j, j] - m[k, k])
        q = [0.0, 0.0, 0.0, (m[k, j] - m[j, k]) / s]
        q[i] = s / 4
        q[j] = (m[j, i] + m[i, j]) / s
        q[k] = (m[k, i] + m[i, k]) / s
    x, y, z, w = (float(v) for v in q)
    return x, y, z, w


def rotation_from_quaternion(x: float, y: float, z: float, w: float) -> FloatArray:
    """3×3 rotation of a unit quaternion (x, y, z, w): the inverse of :func:`quaternion_xyzw`."""
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def dh_link_transform(row: DHRow, q_rad: float) -> FloatArray:
    """``T(i-1, i) = Rx(alpha) · Tx(a) · Rz(theta) · Tz(d)`` as a 4×4 matrix.

    Written out, each entry a single product as the four-matrix product gives it;
    :func:`frame_transforms` writes the same entries for every link of a table at once."""
    theta = q_rad + row.theta_offset_rad
    ct, st = math.cos(theta), math.sin(theta)
    ca, sa = math.cos(row.alpha_prev_rad), math.sin(row.alpha_prev_rad)
    return np.array(
        [
            [ct, -st, 0.0, row.a_prev_m],
            [ca * st, ca * ct, -sa, -sa * row.d_m],
            [sa * st, sa * ct, ca, ca * row.d_m],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


LinkConstants = tuple[float, float, float, float, float, float]


def _link_constants(dh: tuple[DHRow, ...]) -> tuple[LinkConstants, ...]:
    """Each row's joint-independent factors of :func:`dh_link_transform`: ``cos α``, ``sin α``,
    ``a``, ``−sin α · d``, ``cos α · d`` and the θ offset, computed as it computes them."""
    out = []
    for row in dh:
        ca, sa = math.cos(row.alpha_prev_rad), math.sin(row.alpha_prev_rad)
        out.append((ca, sa, row.a_prev_m, -sa * row.d_m, ca * row.d_m, row.theta_offset_rad))
    return tuple(out)


_UMAY_LINK_CONSTANTS = _link_constants(UMAY_DH)  # the arm's, without hashing its table each call
_EYE4 = np.eye(4)
_EYE4.setflags(write=False)


def frame_transforms(q_rad: FloatArray, dh: tuple[DHRow, ...] = UMAY_DH) -> list[FloatArray]:
    """Poses of DH frames 1..6 in the base frame (list of six 4×4 matrices).

    Every link's :func:`dh_link_transform` is written into one array at once, its entries
    the same products (the per-link array constructions were most of this function's cost);
    the poses are the same chain of matrix products."""
    q = np.asarray(q_rad, dtype=float)
    if q.shape != (len(dh),):
        raise ValueError(f"q_rad must have shape ({len(dh)},), got {q.shape}")
    entries: list[float] = []
    constants = _UMAY_LINK_CONSTANTS if dh is UMAY_DH else _link_constants(dh)
    for (ca, sa, a, sa_d, ca_d, offset), qi in zip(constants, q.tolist(), strict=True):
        theta = qi + offset
        ct, st = math.cos(theta), math.sin(theta)
        entries += (ct, -st, 0.0, a, ca * st, ca * ct, -sa, sa_d, sa * st, sa * ct, ca, ca_d)
        entries += (0.0, 0.0, 0.0, 1.0)
    links = np.array(entries).reshape(len(dh), 4, 4)
    poses = []
    t = _EYE4
    for link in links:
        t = t @ link
        poses.append(t)
    return poses


def forward_kinematics(q_rad: FloatArray, dh: tuple[DHRow, ...] = UMAY_DH) -> FloatArray:
    """Pose of the end-effector frame (DH frame 6) in the base frame, 4×4."""
    return frame_transforms(q_rad, dh)[-1]


def geometric_jacobian(q_rad: FloatArray, dh: tuple[DHRow, ...] = UMAY_DH) -> FloatArray:
    """6×n geometric Jacobian in the base frame at the end-effector origin.

    Rows 0-2: linear velocity of the frame-6 origin (m/s per rad/s); rows 3-5: angular velocity.
    """
    return jacobian_of_frames(frame_transforms(q_rad, dh))


def jacobian_of_frames(frames: list[FloatArray]) -> FloatArray:
    """:func:`geometric_jacobian` from the joint angles' DH frames (:func:`frame_transforms`),
    for a caller that has them already."""
    poses = np.array(frames)
    z = poses[:, :3, 2]  # joint axes
    lever = poses[-1, :3, 3] - poses[:, :3, 3]  # joint origin → end-effector origin
    # z × lever for all joints at once (np.cross per joint has a large per-call overhead).
    out = np.empty((6, len(frames)))
    out[0], out[1], out[2] = cross_components(z, lever)
    out[3:] = z.T
    return out


def manipulability(jacobian: FloatArray) -> float:
    """Yoshikawa's manipulability measure sqrt(det(J Jᵀ))."""
    return float(np.sqrt(max(np.linalg.det(jacobian @ jacobian.T), 0.0)))


def cross_components(a: FloatArray, b: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The three components of ``a × b`` over the last axis, broadcast (many cross products
    at once, each with np.cross's arithmetic), for the caller to write where it needs them."""
    return (
        a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
        a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
        a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0],
    )


def cross(a: FloatArray, b: FloatArray) -> FloatArray:
    """``a × b`` of two 3-vectors: np.cross's arithmetic, bit for bit, without its generic
    per-call overhead (many times the arithmetic): for per-frame work in the controller and
    vision."""
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


def centroid(points: FloatArray) -> FloatArray:
    """``points.mean(axis=0)`` of a float array, bit for bit (the same sum, divided by the same
    count), without its generic per-call overhead."""
    return np.add.reduce(points, axis=0) / len(points)


def norm(v: FloatArray) -> float:
    """``np.linalg.norm(v)`` of a float vector, bit for bit (the square root of its dot with
    itself, as that computes it), without its generic per-call overhead."""
    flat = v.ravel(order="K")
    return math.sqrt(flat.dot(flat))


# np.linalg.pinv's default cut-off: singular values below this share of the largest count as 0.
PINV_RCOND = 1e-15


def pinv(a: FloatArray) -> FloatArray:
    """``np.linalg.pinv(a)`` of a real 2-D matrix, bit for bit (the same SVD and the same
    operations on it), without its generic per-call overhead: for the per-frame laws."""
    if a.size == 0:  # no singular values: numpy's answer, an empty matrix the other way round
        return np.zeros(a.shape[::-1])
    u, s, vt = np.linalg.svd(a.conjugate(), full_matrices=False)
    large = s > PINV_RCOND * np.maximum.reduce(s)
    if large.all():  # full rank: every singular value inverted
        s = np.divide(1, s, out=s)
    else:
        s = np.divide(1, s, where=large, out=s)
        s[~large] = 0
    return np.matmul(np.transpose(vt), np.multiply(s[..., np.newaxis], np.transpose(u)))


def skew(v: FloatArray) -> FloatArray:
    """Cross-product matrix: ``skew(a) @ b == cross(a, b)``."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def rotation_error_rad(r_a: FloatArray, r_b: FloatArray) -> float:
    """Angle of the rotation taking ``r_a`` to ``r_b`` (rad, in [0, π])."""
    cos_angle = ((r_a.T @ r_b).trace() - 1.0) / 2.0  # np.trace's and np.clip's own methods
    return float(np.arccos(cos_angle.clip(-1.0, 1.0)))


_EYE3 = np.eye(3)
_EYE3.setflags(write=False)


def rotation_log(r: FloatArray) -> FloatArray:
    """Axis-angle vector θ·u of a rotation matrix (rad)."""
    angle = rotation_error_rad(_EYE3, r)
    if angle < 1e-9:
        return np.zeros(3)
    if np.pi - angle < 1e-6:
        # Near π the antisymmetric part vanishes; take the axis from the symmetric part.
        m = (r + np.eye(3)) / 2.0
        axis = m[:, int(np.argmax(np.diag(m)))]
        return angle * axis / np.linalg.norm(axis)
    w = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    return angle * w / (2.0 * np.sin(angle))


def inverse_kinematics(
    target_pose: FloatArray,
    q_seed_rad: FloatArray,
    tool_in_ee: FloatArray | None = None,
    iterations: int = 200,
    damping: float = 1e-2,
    tolerance: float = 1e-7,
    stall_rad: float = 0.0,
) -> tuple[FloatArray, float, float]:
    """Damped least-squares IK for the pose of a tool frame rigidly attached to frame 6.

    Returns ``(q_rad, position_error_m, orientation_error_rad)``; joint limits are enforced by
    clipping at each step. Used to check that a scenario's target is reachable before launch,
    and by the controller for its corner pairings' goal postures. ``stall_rad``: stop once no
    joint moved by more than this in a step (held at a limit, or settled short of the goal);
    0 runs every iteration.
    """
    tool = np.eye(4) if tool_in_ee is None else tool_in_ee
    q = np.clip(np.asarray(q_seed_rad, dtype=float).copy(), JOINT_LOWER_RAD, JOINT_UPPER_RAD)
    damping_term = damping**2 * np.eye(6)  # the same every iteration
    for _ in range(iterations):
        frames = frame_transforms(q)  # the pose and the Jacobian from one forward kinematics
        ee = frames[-1]
        pose = ee @ tool
        e_pos = target_pose[:3, 3] - pose[:3, 3]
        e_rot = pose[:3, :3] @ rotation_log(pose[:3, :3].T @ target_pose[:3, :3])
        err = np.concatenate([e_pos, e_rot])
        if norm(err) < tolerance:
            break
        jac = jacobian_of_frames(frames)
        # Twist at the tool origin: v_tool = v_ee + ω × (p_tool - p_ee).
        lever = pose[:3, 3] - ee[:3, 3]
        jac_tool = jac.copy()
        jac_tool[:3] = jac[:3] - skew(lever) @ jac[3:]
        dq = jac_tool.T @ np.linalg.solve(jac_tool @ jac_tool.T + damping_term, err)
        q_next = (q + dq).clip(JOINT_LOWER_RAD, JOINT_UPPER_RAD)
        stalled = float(np.maximum.reduce(np.abs(q_next - q))) <= stall_rad  # np.max's
        q = q_next
        if stalled:
            break
    pose = forward_kinematics(q) @ tool
    return (
        q,
        float(np.linalg.norm(target_pose[:3, 3] - pose[:3, 3])),
        rotation_error_rad(pose[:3, :3], target_pose[:3, :3]),
    )


# --- the limbs, the hand and its green marker (shared by the sim's URDF, the reachability
# check, the controller's clearance of the hand box and the live view) ---
# The upper arm and the forearm: cylinders of this radius between their joints' origins.
LIMB_RADIUS_M = 0.022
# The hand is a box rigidly attached to DH frame 6: fingers along +y6 (the forearm direction at
# q6 = 0), wrist flexion about z6, so the palm's normal is ±x6. The green marker lies on the back
# of the hand (+x6 side).
HAND_THICKNESS_M = 0.025
HAND_LENGTH_M = 0.09
HAND_WIDTH_M = 0.08
HAND_OFFSET_M = 0.01  # gap between the wrist centre and the hand box along +y6
MARKER_THICKNESS_M = 0.0001  # thin: its side faces would widen the square by ~1 px


def hand_marker_in_ee() -> FloatArray:
    """Pose of the green marker frame in DH frame 6 (4×4).

    Marker frame: origin at the centre of the square's visible face, z along its outward normal,
    x towards the fingertips. The red target marker uses the same convention (z up), so the task
    is "bring the green marker frame onto the red one" (modulo the square's 90° symmetry).
    """
    z_m = np.array([1.0, 0.0, 0.0])
    x_m = np.array([0.0, 1.0, 0.0])
    y_m = np.cross(z_m, x_m)
    centre = np.array(
        [HAND_THICKNESS_M / 2 + MARKER_THICKNESS_M, HAND_OFFSET_M + HAND_LENGTH_M / 2, 0.0]
    )
    return homogeneous(np.column_stack([x_m, y_m, z_m]), centre)


def marker_corners(pose: FloatArray, size_m: float) -> FloatArray:
    """4×3 corners of a square marker (visible face) in the pose's parent frame.

    Physical order in the marker frame: (-,-), (+,-), (+,+), (-,+).
    """
    h = size_m / 2.0
    local = np.array([[-h, -h, 0.0, 1.0], [h, -h, 0.0, 1.0], [h, h, 0.0, 1.0], [-h, h, 0.0, 1.0]])
    return (pose @ local.T).T[:, :3]


# The orientation cue (config marker.orientation_cue): a small square of a third colour inside
# the marker, centred at this fraction of the diagonal from corner 0 (the (-,-) corner of
# marker_corners) towards corner 2, its side this fraction of the marker's. The sim draws it
# there and vision looks for it there: the marker's outline stays a whole square.
CUE_CENTRE_DIAGONAL_FRACTION = 0.25
CUE_SIDE_FRACTION = 0.2


def cue_centre_in_marker(size_m: float) -> FloatArray:
    """Centre (x, y, 0) of the orientation cue in the marker frame (m)."""
    h = size_m / 2.0
    corner0 = np.array([-h, -h, 0.0])
    return corner0 + CUE_CENTRE_DIAGONAL_FRACTION * (np.array([h, h, 0.0]) - corner0)


BASE_UP = np.array([0.0, 1.0, 0.0])  # the vertical, in the base frame


def goal_marker_pose(target_pose: FloatArray, approach_height_m: float) -> FloatArray:
    """Where the green marker must end: the red marker's frame raised along its normal."""
    return target_pose @ homogeneous(np.eye(3), np.array([0.0, 0.0, approach_height_m]))


def target_marker_pose(position_m: FloatArray, yaw_rad: float) -> FloatArray:
    """Red marker frame: centre of its visible face at ``position_m``, normal (z) up.

    At yaw 0 the marker x axis points forward (base x) and y to the robot's left (base -z);
    positive yaw turns it counter-clockwise seen from above.
    """
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    x_m = np.array([c, 0.0, -s])
    z_m = BASE_UP
    return homogeneous(
        np.column_stack([x_m, np.cross(z_m, x_m), z_m]), np.asarray(position_m, dtype=float)
    )
