"""Twist → joint velocities: damped inverse, limits, deadman."""

from __future__ import annotations

import numpy as np
import pytest

from common import kinematics as kin
from services.actuation.inverse import (
    damped_pinv,
    damping_for,
    deadman_expired,
    limit_acceleration,
    limit_joint_positions,
    limit_joint_velocities,
    position_bound_rad_s,
    redistribute_at_limits,
    twist_to_joint_velocities,
)


def test_undamped_inverse_reproduces_the_twist() -> None:
    q = np.array([-1.5, 0.9, -2.0, 1.6, 0.8, -0.3])
    twist = np.array([0.02, -0.01, 0.03, 0.1, -0.2, 0.05])
    cmd = twist_to_joint_velocities(twist, q, damping_max=0.02, threshold=0.0)
    np.testing.assert_allclose(kin.geometric_jacobian(q) @ cmd.velocity_rad_s, twist, atol=1e-9)
    assert cmd.saturated == []


def test_damping_grows_as_manipulability_falls_and_bounds_the_rates() -> None:
    assert damping_for(0.01, 0.05, 0.002) == 0.0
    assert 0.0 < damping_for(0.001, 0.05, 0.002) < damping_for(0.0001, 0.05, 0.002) <= 0.05
    q_singular = np.zeros(6)  # joints 1 and 3 aligned
    jac = kin.geometric_jacobian(q_singular)
    twist = np.array([0.0, 0.0, 0.05, 0.0, 0.0, 0.0])
    damped = damped_pinv(jac, 0.05) @ twist
    assert np.all(np.isfinite(damped)) and np.abs(damped).max() < 10.0


def test_speed_limit_scales_the_whole_vector() -> None:
    q = np.zeros(6)
    qdot = np.array([3.0, 1.0, 0.0, 0.0, 0.0, 0.0])
    out, slowed, over = limit_joint_velocities(qdot, q)
    assert np.abs(out).max() <= kin.JOINT_VELOCITY_LIMIT_RAD_S.max() + 1e-12
    np.testing.assert_allclose(out[1] / out[0], 1.0 / 3.0)
    assert slowed == [] and over == [0]


def test_position_limit_stops_motion_towards_it_only() -> None:
    q = kin.JOINT_UPPER_RAD.copy()
    out, slowed, over = limit_joint_velocities(np.full(6, 0.5), q)
    np.testing.assert_allclose(out, 0.0)
    assert slowed == list(range(6)) and over == []
    out, slowed, _ = limit_joint_velocities(np.full(6, -0.5), q)
    np.testing.assert_allclose(out, -0.5)
    assert slowed == []


def test_near_a_limit_speed_towards_it_is_bounded_not_scaled() -> None:
    """5° inside the 10° zone of joint 2's upper limit: at most half its speed limit towards
    it, a slow motion towards it untouched (a goal inside the zone is not crawled to), any
    speed away from it untouched."""
    q = np.zeros(6)
    q[1] = kin.JOINT_UPPER_RAD[1] - np.deg2rad(5.0)
    half = 0.5 * kin.JOINT_VELOCITY_LIMIT_RAD_S[1]
    out, slowed, _ = limit_joint_velocities(np.array([0.0, 1.4, 0, 0, 0, 0]), q)
    assert out[1] == pytest.approx(half) and slowed == [1]
    out, slowed, _ = limit_joint_velocities(np.array([0.0, 0.01, 0, 0, 0, 0]), q)
    assert out[1] == 0.01 and slowed == []
    out, slowed, _ = limit_joint_velocities(np.array([0.0, -1.4, 0, 0, 0, 0]), q)
    assert out[1] == -1.4 and slowed == []
    wanted = np.array([0.3, 1.2, -0.4, 0.1, 0.0, 0.2])  # joint 2 over its bound: it alone
    out, slowed, _ = limit_joint_velocities(wanted, q)
    assert slowed == [1] and out[1] == pytest.approx(half)
    np.testing.assert_array_equal(np.delete(out, 1), np.delete(wanted, 1))


def test_nan_twist_never_reaches_the_motors() -> None:
    cmd = twist_to_joint_velocities(np.full(6, np.nan), np.full(6, 0.5), 0.02, 0.002)
    np.testing.assert_array_equal(cmd.velocity_rad_s, np.zeros(6))


def test_deadman() -> None:
    assert deadman_expired(10.0, None, 0.25)
    assert not deadman_expired(10.0, 9.9, 0.25)
    assert deadman_expired(10.0, 9.7, 0.25)


def test_acceleration_limit_bounds_the_change_and_keeps_its_direction() -> None:
    previous = np.array([0.1, 0.0, 0.0, 0.0, 0.0, 0.0])
    wanted = np.array([1.1, 0.5, 0.0, 0.0, 0.0, 0.0])
    out, limited = limit_acceleration(wanted, previous, max_accel_rad_s2=10.0, dt_s=0.02)
    assert limited
    change = out - previous
    assert np.abs(change).max() == pytest.approx(10.0 * 0.02)
    np.testing.assert_allclose(change[1] / change[0], 0.5)
    out, limited = limit_acceleration(previous + 0.1, previous, 10.0, 0.02)
    assert not limited
    np.testing.assert_allclose(out, previous + 0.1)
    out, limited = limit_acceleration(wanted, previous, 10.0, 0.0)  # no time base yet
    assert limited
    np.testing.assert_allclose(out, previous)


def test_position_and_speed_limits_hold_after_the_acceleration_limit() -> None:
    q = kin.JOINT_UPPER_RAD.copy()
    q[1:] = 0.0
    twist = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    previous = np.full(6, 1.0)  # moving towards joint 1's upper limit
    cmd = twist_to_joint_velocities(
        twist, q, 0.02, 0.002, previous_rad_s=previous, max_accel_rad_s2=1.0, dt_s=0.01
    )
    assert cmd.clamps.acceleration and cmd.clamps.position == [0]
    assert cmd.velocity_rad_s[0] == 0.0  # the hard limit wins over the soft ramp
    cmd = twist_to_joint_velocities(np.array([5.0, 0, 0, 0, 0, 0]), np.full(6, 0.4), 0.02, 0.002)
    assert cmd.clamps.velocity and not cmd.clamps.acceleration
    assert np.abs(cmd.velocity_rad_s).max() <= kin.JOINT_VELOCITY_LIMIT_RAD_S.max() + 1e-12


@pytest.mark.filterwarnings("error")  # handled, so no RuntimeWarning in the service log
def test_nonfinite_inverse_is_flagged() -> None:
    cmd = twist_to_joint_velocities(np.full(6, np.inf), np.full(6, 0.5), 0.02, 0.002)
    assert cmd.clamps.nonfinite
    np.testing.assert_array_equal(cmd.velocity_rad_s, np.zeros(6))


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("angle", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("joint", range(6))
def test_a_nonfinite_joint_angle_gives_a_zero_command(joint: int, angle: float) -> None:
    """A NaN or infinite angle of any joint, the last one included (a NaN there leaves the
    Jacobian at the end effector's origin finite and entered only through the limits' bounds),
    never reaches the motors nor raises: a zero command, flagged, whatever the previous
    command."""
    q = np.array([-1.559, 0.952, -1.832, 1.487, 0.600, -0.070])
    q[joint] = angle
    twist = np.array([0.01, 0.0, 0.0, 0.0, 0.0, 0.1])
    for previous in (None, np.zeros(6), np.full(6, 0.2)):
        cmd = twist_to_joint_velocities(
            twist, q, 0.02, 0.002, previous_rad_s=previous, max_accel_rad_s2=10.0, dt_s=1 / 30
        )
        assert cmd.clamps.nonfinite
        np.testing.assert_array_equal(cmd.velocity_rad_s, np.zeros(6))


@pytest.mark.filterwarnings("error")
def test_a_nonfinite_previous_command_is_not_passed_on() -> None:
    """The acceleration limit hands back the previous command when the change cannot be
    judged: a NaN there must not become the next command (it would then stick)."""
    q = np.array([-1.559, 0.952, -1.832, 1.487, 0.600, -0.070])
    twist = np.array([0.01, 0.0, 0.0, 0.0, 0.0, 0.1])
    previous = np.array([0.1, np.nan, 0.0, 0.0, 0.0, 0.0])
    cmd = twist_to_joint_velocities(
        twist, q, 0.02, 0.002, previous_rad_s=previous, max_accel_rad_s2=10.0, dt_s=1 / 30
    )
    assert cmd.clamps.nonfinite
    np.testing.assert_array_equal(cmd.velocity_rad_s, np.zeros(6))


def test_a_joint_held_at_its_limit_leaves_its_share_of_the_twist_to_the_others() -> None:
    """Joint 2 two degrees from its upper limit and asked to move towards it: held at its
    bound, the other joints give the twist's rest, and the hand's twist is closer to the one
    asked for than with joint 2 only clipped; a joint outside every zone is left alone."""
    q = np.array([-0.5, kin.JOINT_UPPER_RAD[1] - np.radians(2.0), -1.2, 1.4, 0.2, -0.3])
    jac = kin.geometric_jacobian(q)
    rates = np.zeros(6)
    rates[1] = 0.8  # towards the limit
    rates[0] = -0.3
    twist = jac @ rates
    qdot = damped_pinv(jac, 0.0) @ twist
    held_qdot, held = redistribute_at_limits(jac, twist, qdot, q, 0.0)
    clipped, _ = limit_joint_positions(qdot, q)
    bound = position_bound_rad_s(held_qdot, q)
    assert held == [1] and held_qdot[1] == pytest.approx(bound[1])
    assert np.linalg.norm(jac @ held_qdot - twist) < 0.5 * np.linalg.norm(jac @ clipped - twist)
    free = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    free_q = np.zeros(6)
    free_twist = kin.geometric_jacobian(free_q) @ np.full(6, 0.2)
    same, none = redistribute_at_limits(
        kin.geometric_jacobian(free_q), free_twist, free + 0.2, free_q, 0.0
    )
    assert none == [] and np.allclose(same, 0.2)


def test_at_a_singular_posture_the_inverse_is_damped_and_the_rates_stay_small() -> None:
    """All joints at zero (joints 1 and 3 aligned: the manipulability is nil) and 5 cm/s
    asked along z: the command reports the damping ramped in, and its rates are the damped
    least squares ``Jᵀ (J Jᵀ + δ² I)⁻¹ V`` (computed here with numpy), finite and under every
    joint's speed limit with no limit having to act, where the plain pseudo-inverse asks over
    five times the joints' speed limit; the hand still moves the way it was asked. Without the
    damping the speed limit would have to scale down rates in a direction the singularity
    chose, not the twist."""
    q = np.zeros(6)
    jac = kin.geometric_jacobian(q)
    damping_max, threshold = 0.02, 0.002
    assert kin.manipulability(jac) < threshold  # singular: the damping must ramp in
    twist = np.array([0.0, 0.0, 0.05, 0.0, 0.0, 0.0])
    cmd = twist_to_joint_velocities(twist, q, damping_max, threshold)
    assert 0.0 < cmd.damping <= damping_max
    qdot = cmd.velocity_rad_s
    assert np.all(np.isfinite(qdot)) and not cmd.clamps.nonfinite
    assert cmd.clamps.velocity == [] and cmd.clamps.position == []
    assert np.all(np.abs(qdot) < kin.JOINT_VELOCITY_LIMIT_RAD_S)
    dls = jac.T @ np.linalg.solve(jac @ jac.T + cmd.damping**2 * np.eye(6), twist)
    np.testing.assert_allclose(qdot, dls, rtol=1e-9, atol=1e-12)
    undamped = np.linalg.pinv(jac) @ twist
    print(
        f"damping {cmd.damping:.3f}: |q_dot| {np.linalg.norm(qdot):.3f} rad/s, "
        f"undamped {np.linalg.norm(undamped):.1f} rad/s"
    )
    assert np.abs(undamped).max() > 5.0 * kin.JOINT_VELOCITY_LIMIT_RAD_S.max()
    assert np.linalg.norm(undamped) > 20.0 * np.linalg.norm(qdot)
    assert float((jac @ qdot) @ twist) > 0.0  # the hand still moves the way it was asked
