"""The motors' own speed limit, whatever a joint command says. Pure: the sim node and the
in-process pipeline (services/pipeline.py) apply commands through it."""

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
