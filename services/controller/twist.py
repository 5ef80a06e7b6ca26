"""The hand's twist between frames (and points, camera to base), and its clamp. Pure.

The law computes the hand's twist in the camera frame, referenced at the camera origin (as the
interaction matrices give it, :mod:`.interaction`); actuation wants it in the base frame,
referenced at the end-effector origin (the manipulator Jacobian's). Both through the
*assumed* camera pose (the calibration), never the simulator's.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from common.kinematics import cross, norm, skew

FloatArray = NDArray[np.float64]


def camera_points_to_base(points_cam_m: FloatArray, t_base_cam: FloatArray) -> FloatArray:
    """Camera-frame points (N×3, m) in the base frame, through the assumed camera pose."""
    return np.asarray(points_cam_m, dtype=float) @ t_base_cam[:3, :3].T + t_base_cam[:3, 3]


def camera_twist_to_base_ee(
    twist_cam: FloatArray, t_base_cam: FloatArray, p_ee_base_m: FloatArray
) -> FloatArray:
    """Carry a hand twist from the camera frame (referenced at the camera origin) to the base
    frame, referenced at the end-effector origin: ``ω_b = R ω``, ``v_e = R v + ω_b × (p_e - t)``.
    """
    rot, origin = t_base_cam[:3, :3], t_base_cam[:3, 3]
    omega_b = rot @ twist_cam[3:]
    v_e = rot @ twist_cam[:3] + cross(omega_b, p_ee_base_m - origin)
    return np.concatenate([v_e, omega_b])


def twist_matrix_base_ee_to_cam(t_base_cam: FloatArray, p_ee_base_m: FloatArray) -> FloatArray:
    """The 6×6 inverse of :func:`camera_twist_to_base_ee` as a matrix: a hand twist in the base
    frame at the end-effector origin to the camera frame at the camera origin,
    ``ω = Rᵀ ω_b``, ``v = Rᵀ (v_e + [p_e − t]× ω_b)``."""
    rot, origin = t_base_cam[:3, :3], t_base_cam[:3, 3]
    out = np.zeros((6, 6))
    out[:3, :3] = rot.T
    out[:3, 3:] = rot.T @ skew(np.asarray(p_ee_base_m, dtype=float) - origin)
    out[3:, 3:] = rot.T
    return out


def clamp_twist(twist: FloatArray, max_linear_m_s: float, max_angular_rad_s: float) -> FloatArray:
    """Scale the whole twist down (direction kept) so both norms respect their limits."""
    scale = 1.0
    lin, ang = norm(twist[:3]), norm(twist[3:])
    if lin > max_linear_m_s:
        scale = min(scale, max_linear_m_s / lin)
    if ang > max_angular_rad_s:
        scale = min(scale, max_angular_rad_s / ang)
    return twist * scale
