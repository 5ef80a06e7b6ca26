"""Actuation's one step as a pure function of its state: a twist and the joint encoders →
the joint velocity command, under the acceleration limit.

The state (:class:`LimiterState`) is the command the motors follow now and its sim time: the
acceleration limit bounds the change from it over the sim time between consecutive commands, at
most one camera period: the change reaches the motors at once, however long the motors held the
command before (frames skipped in realtime, a stall), so a longer gap must not allow a larger
jump.
Stops (hold) are immediate and leave the motors at rest, so tracking restarts with a ramp. The
actuation node and the in-process pipeline (services/pipeline.py) both step it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from common import kinematics as kin
from common.config import ActuationConfig
from common.kinematics import FloatArray
from services.actuation.inverse import JointCommand, twist_to_joint_velocities


@dataclass(frozen=True)
class LimiterState:
    """The command the motors follow now, and its sim time (None: at rest, no time base)."""

    previous_rad_s: FloatArray = field(default_factory=lambda: np.zeros(kin.N_JOINTS))
    previous_sim_s: float | None = None

    def commanded(self, velocity_rad_s: FloatArray, sim_time_s: float) -> LimiterState:
        """After a command for a camera frame taken at ``sim_time_s``."""
        return LimiterState(velocity_rad_s, sim_time_s)

    @staticmethod
    def at_rest() -> LimiterState:
        """After a stop with no frame to time it (the deadman): from rest, no time base."""
        return LimiterState()

    @staticmethod
    def at_rest_since(sim_time_s: float) -> LimiterState:
        """The motors at rest since ``sim_time_s``: the next command ramps up from zero over
        the time since (a state without a time base would allow no change at all)."""
        return LimiterState(np.zeros(kin.N_JOINTS), sim_time_s)


@dataclass(frozen=True)
class ActuationStep:
    """One frame's command: ``reason`` ``track`` or ``hold``; ``joint`` the inverse's detail
    (clamps, manipulability) when tracking, None on a hold."""

    velocity_rad_s: FloatArray
    reason: Literal["track", "hold"]
    joint: JointCommand | None
    state: LimiterState  # for the next frame


def actuation_step(
    config: ActuationConfig,
    state: LimiterState,
    twist_base_ee: FloatArray,
    valid: bool,
    q_rad: FloatArray,
    sim_time_s: float,
    max_dt_s: float | None = None,
) -> ActuationStep:
    """The command answering the twist of the frame taken at ``sim_time_s`` (``valid`` False:
    a hold, zero velocity at once); ``max_dt_s`` (the camera period): the most sim time the
    acceleration limit counts between two commands."""
    if not valid:
        zero = np.zeros(kin.N_JOINTS)
        return ActuationStep(zero, "hold", None, state.commanded(zero, sim_time_s))
    previous_sim_s = state.previous_sim_s
    cmd = twist_to_joint_velocities(
        twist_base_ee,
        q_rad,
        config.damping,
        config.manipulability_threshold,
        previous_rad_s=state.previous_rad_s,
        max_accel_rad_s2=config.max_joint_acceleration_rad_s2,
        dt_s=0.0 if previous_sim_s is None else elapsed_s(previous_sim_s, sim_time_s, max_dt_s),
    )
    return ActuationStep(
        cmd.velocity_rad_s, "track", cmd, state.commanded(cmd.velocity_rad_s, sim_time_s)
    )


# Sim time accumulates physics steps: consecutive lockstep frames lie one camera period apart
# to within rounding, which must not count as a longer gap.
GAP_ROUNDING = 1e-9


def elapsed_s(previous_sim_s: float, sim_time_s: float, max_dt_s: float | None) -> float:
    """The sim time the acceleration limit counts since the last command: none backwards, at
    most ``max_dt_s`` (one camera period: in lockstep every gap is one, so it never bites)."""
    dt = max(0.0, sim_time_s - previous_sim_s)
    if max_dt_s is None or dt <= max_dt_s * (1.0 + GAP_ROUNDING):
        return dt
    return max_dt_s
