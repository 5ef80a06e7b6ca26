"""End-effector twist → joint velocities: damped least squares, limits, deadman. Pure functions."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from common import kinematics as kin

FloatArray = NDArray[np.float64]


def damping_for(manipulability: float, damping_max: float, threshold: float) -> float:
    """Damping factor: zero away from singularities, growing to ``damping_max`` as the
    manipulability falls to zero (Nakamura & Hanafusa's schedule)."""
    if manipulability >= threshold or threshold <= 0.0:
        return 0.0
    return damping_max * (1.0 - manipulability / threshold)


def damped_pinv(jacobian: FloatArray, damping: float) -> FloatArray:
    """``Jᵀ (J Jᵀ + δ² I)⁻¹``; the pseudo-inverse when ``δ = 0`` (J of full row rank)."""
    j = np.asarray(jacobian, dtype=float)
    if damping == 0.0:
        return np.linalg.pinv(j)
    return j.T @ np.linalg.inv(j @ j.T + damping**2 * np.eye(j.shape[0]))


def limit_joint_velocities(
    qdot_rad_s: FloatArray,
    q_rad: FloatArray,
    lower_rad: FloatArray = kin.JOINT_LOWER_RAD,
    upper_rad: FloatArray = kin.JOINT_UPPER_RAD,
    vmax_rad_s: FloatArray = kin.JOINT_VELOCITY_LIMIT_RAD_S,
    slow_zone_rad: float = np.deg2rad(10.0),
) -> tuple[FloatArray, list[int]]:
    """Apply position and speed limits; returns the limited rates and the saturated joints.

    Motion towards a joint limit slows linearly inside ``slow_zone_rad`` and stops at the
    limit; then the whole vector is scaled so no joint exceeds its speed limit (the direction of
    the end-effector motion is kept).
    """
    qdot = np.array(qdot_rad_s, dtype=float)
    q = np.asarray(q_rad, dtype=float)
    saturated: list[int] = []
    to_upper = np.clip((upper_rad - q) / slow_zone_rad, 0.0, 1.0)
    to_lower = np.clip((q - lower_rad) / slow_zone_rad, 0.0, 1.0)
    factor = np.where(qdot > 0, to_upper, to_lower)
    saturated += [i for i in range(len(q)) if factor[i] < 1.0 and qdot[i] != 0.0]
    qdot *= factor
    ratio = np.max(np.abs(qdot) / vmax_rad_s) if len(qdot) else 0.0
    if ratio > 1.0:
        saturated += [int(i) for i in np.flatnonzero(np.abs(qdot) > vmax_rad_s)]
        qdot /= ratio
    return qdot, sorted(set(saturated))


@dataclass(frozen=True)
class JointCommand:
    velocity_rad_s: FloatArray
    saturated: list[int]
    manipulability: float
    damping: float


def twist_to_joint_velocities(
    twist_base_ee: FloatArray, q_rad: FloatArray, damping_max: float, threshold: float
) -> JointCommand:
    """``q̇ = J⁺_δ(q) · V_e`` followed by the joint limits (thesis eq. 5.36)."""
    jac = kin.geometric_jacobian(q_rad)
    w = kin.manipulability(jac)
    delta = damping_for(w, damping_max, threshold)
    qdot = damped_pinv(jac, delta) @ np.asarray(twist_base_ee, dtype=float)
    if not np.all(np.isfinite(qdot)):  # last guard: never let NaN/Inf reach the motors
        return JointCommand(np.zeros(kin.N_JOINTS), list(range(kin.N_JOINTS)), w, delta)
    limited, saturated = limit_joint_velocities(qdot, q_rad)
    return JointCommand(limited, saturated, w, delta)


def deadman_expired(now_s: float, last_twist_s: float | None, timeout_s: float) -> bool:
    """True when no fresh valid twist arrived within ``timeout_s`` (or none ever did)."""
    return last_twist_s is None or now_s - last_twist_s > timeout_s
