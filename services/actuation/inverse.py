"""End-effector twist → joint velocities: damped least squares, limits, deadman. Pure functions."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from common import kinematics as kin
from common.kinematics import position_bound_rad_s

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
        return kin.pinv(j)
    return j.T @ np.linalg.inv(j @ j.T + damping**2 * np.eye(j.shape[0]))


def redistribute_at_limits(
    jacobian: FloatArray,
    twist_base_ee: FloatArray,
    qdot_rad_s: FloatArray,
    q_rad: FloatArray,
    damping: float,
    slow_zone_rad: float = kin.POSITION_LIMIT_ZONE_RAD,
) -> tuple[FloatArray, list[int]]:
    """Joints asked to move towards a limit faster than :func:`position_bound_rad_s` allows
    are held at their bound (inside the slow-down zone only: the speed limit outside it scales
    the whole vector, later), and the rest of the twist (``V − J_held q̇_held``) is given to
    the other joints by least squares (``q̇_free = J_free⁺ (…)``), until no free joint is over
    its bound: the saturation-in-the-null-space idea (Flacco, De Luca & Khatib, 2012) without
    a null space to use (six joints, six task rows). Clipping the joint alone lost that share
    of the twist, so the hand drifted off its line and a goal beside a limit was never
    reached. Returns the rates and the joints held at their bound."""
    jac = np.asarray(jacobian, dtype=float)
    twist = np.asarray(twist_base_ee, dtype=float)
    qdot = np.array(qdot_rad_s, dtype=float)
    held = np.zeros(len(qdot), dtype=bool)
    for _ in range(len(qdot)):
        bound = position_bound_rad_s(qdot, q_rad, slow_zone_rad=slow_zone_rad)
        in_zone = bound < kin.JOINT_VELOCITY_LIMIT_RAD_S  # the speed limit is not this one's
        over = (np.abs(qdot) > bound) & in_zone & ~held
        if not over.any():
            break
        qdot[over] = np.clip(qdot[over], -bound[over], bound[over])
        held |= over
        free = ~held
        if not free.any():
            break
        rest = twist - jac[:, held] @ qdot[held]
        qdot[free] = damped_pinv(jac[:, free], damping) @ rest
    return qdot, held.nonzero()[0].tolist()


def limit_joint_positions(
    qdot_rad_s: FloatArray,
    q_rad: FloatArray,
    lower_rad: FloatArray = kin.JOINT_LOWER_RAD,
    upper_rad: FloatArray = kin.JOINT_UPPER_RAD,
    slow_zone_rad: float = kin.POSITION_LIMIT_ZONE_RAD,
    vmax_rad_s: FloatArray = kin.JOINT_VELOCITY_LIMIT_RAD_S,
) -> tuple[FloatArray, list[int]]:
    """Inside ``slow_zone_rad`` of a joint limit, the speed towards it is bounded by the
    joint's speed limit times the fraction of the zone left, down to zero at the limit (the
    joint approaches its limit exponentially and never crosses it); motion away from it, and
    motion slower than the bound, are untouched. Only the joint over its bound is slowed: the
    others keep moving and the closed loop steers round the limit (slowing the whole vector
    kept the hand's direction but left it blocked where it could have got past). A bound, not a
    scale: scaling every speed by the fraction left made a goal posture inside the zone crawl
    for its last millimetres. Returns the rates and the joints slowed."""
    qdot = np.array(qdot_rad_s, dtype=float)
    bound = position_bound_rad_s(qdot, q_rad, lower_rad, upper_rad, slow_zone_rad, vmax_rad_s)
    slowed = (np.abs(qdot) > bound).nonzero()[0].tolist()
    return qdot.clip(-bound, bound), slowed


def limit_speed(
    qdot_rad_s: FloatArray, vmax_rad_s: FloatArray = kin.JOINT_VELOCITY_LIMIT_RAD_S
) -> tuple[FloatArray, list[int]]:
    """Scale the whole vector so no joint exceeds its speed limit (the direction of the
    end-effector motion is kept). Returns the rates and the joints that were over."""
    qdot = np.array(qdot_rad_s, dtype=float)
    over = (np.abs(qdot) > vmax_rad_s).nonzero()[0].tolist()
    if over:
        qdot /= np.max(np.abs(qdot) / vmax_rad_s)
    return qdot, over


def limit_acceleration(
    qdot_rad_s: FloatArray,
    previous_rad_s: FloatArray,
    max_accel_rad_s2: float,
    dt_s: float,
) -> tuple[FloatArray, bool]:
    """Bound the change from the previous command to ``max_accel_rad_s2 · dt_s`` per joint,
    scaling the whole change (so the joint-space direction of the change is kept).
    Returns the rates and whether they were limited."""
    qdot = np.asarray(qdot_rad_s, dtype=float)
    change = qdot - np.asarray(previous_rad_s, dtype=float)
    ratio = np.abs(change).max() / (max_accel_rad_s2 * dt_s) if dt_s > 0 else np.inf
    if ratio <= 1.0:
        return qdot.copy(), False
    if not np.isfinite(ratio):  # no time has passed: keep the previous command
        return np.asarray(previous_rad_s, dtype=float).copy(), True
    return np.asarray(previous_rad_s, dtype=float) + change / ratio, True


def limit_joint_velocities(
    qdot_rad_s: FloatArray,
    q_rad: FloatArray,
    lower_rad: FloatArray = kin.JOINT_LOWER_RAD,
    upper_rad: FloatArray = kin.JOINT_UPPER_RAD,
    vmax_rad_s: FloatArray = kin.JOINT_VELOCITY_LIMIT_RAD_S,
    slow_zone_rad: float = kin.POSITION_LIMIT_ZONE_RAD,
) -> tuple[FloatArray, list[int], list[int]]:
    """The hard limits, which always hold: speed limits (the whole vector scaled), then
    position limits (each joint's speed towards its limit bounded; below the speed limit, so
    they only act inside a slow-down zone). Returns the rates, the joints slowed near a
    position limit and the joints that were over speed."""
    qdot, over = limit_speed(qdot_rad_s, vmax_rad_s)
    qdot, slowed = limit_joint_positions(
        qdot, q_rad, lower_rad, upper_rad, slow_zone_rad, vmax_rad_s
    )
    return qdot, slowed, over


@dataclass(frozen=True)
class Clamps:
    """Which safety limits acted on one command (for the status counters)."""

    position: list[int] = field(default_factory=list)  # joints slowed near a position limit
    velocity: list[int] = field(default_factory=list)  # joints over their speed limit
    acceleration: bool = False  # the change from the previous command was bounded
    nonfinite: bool = False  # the command came out NaN/Inf: zero was commanded instead


@dataclass(frozen=True)
class JointCommand:
    velocity_rad_s: FloatArray
    clamps: Clamps
    manipulability: float
    damping: float

    @property
    def saturated(self) -> list[int]:
        return sorted(set(self.clamps.position + self.clamps.velocity))


def twist_to_joint_velocities(
    twist_base_ee: FloatArray,
    q_rad: FloatArray,
    damping_max: float,
    threshold: float,
    previous_rad_s: FloatArray | None = None,
    max_accel_rad_s2: float = np.inf,
    dt_s: float = 0.0,
) -> JointCommand:
    """``q̇ = J⁺_δ(q) · V_e`` (thesis eq. 5.36) with the joints held back by a near limit
    leaving their share of the twist to the others (:func:`redistribute_at_limits`), then the
    safety limits in order of authority: acceleration (soft: shapes the motion), then joint
    position and speed limits (hard: always hold, even if that means a sharper change); last,
    a finite-value guard on the command (a zero command instead)."""
    if not np.isfinite(q_rad).all():  # encoders' angles no kinematics can take
        return _nonfinite(float("nan"), 0.0)
    # A NaN or Inf in the twist or the previous command is caught once, on what would reach
    # the motors (after every limit: the acceleration limit hands the previous command back).
    with np.errstate(invalid="ignore", over="ignore"):
        jac = kin.geometric_jacobian(q_rad)
        w = kin.manipulability(jac)
        delta = damping_for(w, damping_max, threshold)
        qdot = damped_pinv(jac, delta) @ np.asarray(twist_base_ee, dtype=float)
        qdot, held = redistribute_at_limits(jac, twist_base_ee, qdot, q_rad, delta)
        accelerated = False
        if previous_rad_s is not None and np.isfinite(max_accel_rad_s2):
            qdot, accelerated = limit_acceleration(qdot, previous_rad_s, max_accel_rad_s2, dt_s)
        qdot, slowed, over = limit_joint_velocities(qdot, q_rad)
    if not np.isfinite(qdot).all():  # never let NaN/Inf reach the motors
        return _nonfinite(w, delta)
    position = sorted(set(held) | set(slowed))
    return JointCommand(qdot, Clamps(position, over, accelerated), w, delta)


def _nonfinite(manipulability: float, damping: float) -> JointCommand:
    """The zero command the finite-value guard sends instead of a non-finite one."""
    return JointCommand(np.zeros(kin.N_JOINTS), Clamps(nonfinite=True), manipulability, damping)


def deadman_expired(now_s: float, last_twist_s: float | None, timeout_s: float) -> bool:
    """True when no fresh valid twist arrived within ``timeout_s`` (or none ever did)."""
    return last_twist_s is None or now_s - last_twist_s > timeout_s
