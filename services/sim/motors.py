"""The motors' own limits, whatever a joint command says: their speed limit, the joints' angle
limits, and a watchdog that stops them when commands stop coming. Pure: the sim node and the
in-process pipeline (services/pipeline.py) apply commands through them."""

from __future__ import annotations

import numpy as np

from common import kinematics as kin
from common.kinematics import FloatArray


def motor_velocities(wanted_rad_s: FloatArray | list[float]) -> tuple[FloatArray, bool]:
    """The velocities the motors follow for a commanded ``wanted_rad_s``, and whether any
    joint was beyond the limit (the sim counts those commands)."""
    limit = kin.JOINT_VELOCITY_LIMIT_RAD_S
    wanted = np.array(wanted_rad_s, dtype=float)
    return np.clip(wanted, -limit, limit), bool(np.any(np.abs(wanted) > limit))


def bounded_at_angles(velocity_rad_s: FloatArray, q_rad: FloatArray) -> FloatArray:
    """The velocities the motors follow with the joints at ``q_rad`` now: as commanded, but
    towards a joint limit no faster than the bound at the angle now
    (:func:`common.kinematics.position_bound_rad_s`), as a servo holds its own angle limits.

    Actuation bounds each command at the angles of its frame. In lockstep a command lasts one
    camera period, too short to reach a limit from its bound (``camera.rgb_hz`` is at least
    9 Hz: a frame shorter than the slow-down zone over the speed limit); in realtime it stays
    in force
    until the next one comes, or a deadman or watchdog stop, however late that is (a stalled
    vision, a frozen actuation), and at its speed the joint crossed its limit by degrees and
    met the joint's end stop. Bounded again before each stretch of physics, the joint slows
    down towards the limit on its own, whatever the latency."""
    velocity = np.asarray(velocity_rad_s, dtype=float)
    bound = kin.position_bound_rad_s(velocity, q_rad)
    return np.clip(velocity, -bound, bound)


def watchdog_expired(
    velocity_rad_s: FloatArray, commanded_s: float | None, now_s: float, timeout_s: float
) -> bool:
    """Whether the motors must stop (``sim.command_watchdog_s``): moving on a command given at
    ``commanded_s`` (None: never) more than ``timeout_s`` before ``now_s`` (one clock, seconds).
    The second line of defence behind actuation's deadman: a frozen or dead actuation sends no
    stop, and in realtime a command stays in force until the next one."""
    if commanded_s is None or not np.any(velocity_rad_s):
        return False
    return now_s - commanded_s > timeout_s
