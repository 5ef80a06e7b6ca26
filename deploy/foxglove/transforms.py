"""Time stamps and the transform tree: simulation time as Foxglove timestamps, rotations as
quaternions, the arm's DH frames and the camera frames (see :mod:`deploy.foxglove.convert`)."""

from __future__ import annotations

import math

import numpy as np
from foxglove.messages import FrameTransform, Pose, Quaternion, Timestamp, Vector3

from common import kinematics as kin
from common.config import Scenario
from deploy.foxglove.topics import BASE, CAMERA, CAMERA_TRUE, DH_FRAMES, EE, HAND_MARKER, WORLD

FloatArray = np.ndarray


def time_ns(sim_time_s: float) -> int:
    return round(sim_time_s * 1e9)


def stamp(sim_time_s: float) -> Timestamp:
    ns = time_ns(sim_time_s)
    return Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)


def quaternion_xyzw(rotation: FloatArray) -> tuple[float, float, float, float]:
    """Unit quaternion (x, y, z, w) of a 3×3 rotation matrix, w ≥ 0 (one of its two signs, so
    that a still frame's quaternion does not flip between messages)."""
    q = kin.quaternion_xyzw(rotation)
    n = math.sqrt(sum(c * c for c in q))
    x, y, z, w = (c / n for c in q)
    return (-x, -y, -z, -w) if w < 0 else (x, y, z, w)


rotation_from_quaternion = kin.rotation_from_quaternion


def pose(transform: FloatArray) -> Pose:
    x, y, z, w = quaternion_xyzw(transform[:3, :3])
    p = transform[:3, 3]
    return Pose(
        position=Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
        orientation=Quaternion(x=x, y=y, z=z, w=w),
    )


def frame_transform(parent: str, child: str, transform: FloatArray, t_s: float) -> FrameTransform:
    x, y, z, w = quaternion_xyzw(transform[:3, :3])
    p = transform[:3, 3]
    return FrameTransform(
        timestamp=stamp(t_s),
        parent_frame_id=parent,
        child_frame_id=child,
        translation=Vector3(x=float(p[0]), y=float(p[1]), z=float(p[2])),
        rotation=Quaternion(x=x, y=y, z=z, w=w),
    )


def arm_transforms(q_rad: FloatArray, t_s: float) -> list[FrameTransform]:
    """``base`` → ``dh_1`` → … → ``dh_6`` (one DH link transform each), ``dh_6`` →
    ``end_effector`` (identity) → ``hand_marker``: composed, they give forward kinematics."""
    out = []
    parent = BASE
    for i, (row, qi) in enumerate(zip(kin.UMAY_DH, q_rad, strict=True)):
        out.append(
            frame_transform(parent, DH_FRAMES[i], kin.dh_link_transform(row, float(qi)), t_s)
        )
        parent = DH_FRAMES[i]
    out.append(frame_transform(parent, EE, np.eye(4), t_s))
    out.append(frame_transform(EE, HAND_MARKER, kin.hand_marker_in_ee(), t_s))
    return out


# base → world: the base's y (up) becomes the world's z.
WORLD_FROM_BASE = kin.homogeneous(kin.rot_x(math.pi / 2), np.zeros(3))


def camera_transforms(scenario: Scenario, t_s: float) -> list[FrameTransform]:
    """``world`` → ``base``, the assumed camera pose (calibration: ``camera``) and the true
    mount (``camera_true``)."""
    cam = scenario.camera
    return [
        frame_transform(WORLD, BASE, WORLD_FROM_BASE, t_s),
        frame_transform(BASE, CAMERA, cam.assumed_pose(), t_s),
        frame_transform(BASE, CAMERA_TRUE, cam.pose(), t_s),
    ]
