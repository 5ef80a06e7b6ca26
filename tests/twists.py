"""The inverse of the controller's twist transform, for tests that predict feature motion from a
joint motion (the controller itself only goes camera → base)."""

from __future__ import annotations

import numpy as np

from common.kinematics import skew


def base_ee_twist_to_camera(
    twist_base_ee: np.ndarray, t_base_cam: np.ndarray, p_ee_base_m: np.ndarray
) -> np.ndarray:
    """Inverse of :func:`services.controller.ibvs.camera_twist_to_base_ee`: a twist in the base
    frame referenced at the end effector, carried to the camera frame at the camera origin."""
    rot, origin = t_base_cam[:3, :3], t_base_cam[:3, 3]
    omega_b = twist_base_ee[3:]
    v_origin = twist_base_ee[:3] + skew(omega_b) @ (origin - p_ee_base_m)
    return np.concatenate([rot.T @ v_origin, rot.T @ omega_b])
