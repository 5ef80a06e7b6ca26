"""The scenario's ``[actuation]`` table: twist to joint velocities, and the deadman."""

from __future__ import annotations

from pydantic import Field

from common.config.base import Strict


class ActuationConfig(Strict):
    deadman_timeout_s: float = Field(
        0.2,
        gt=0.0,
        le=5.0,
        description="zero velocity without a fresh valid twist this long (wall s): 6 camera "
        "periods at 30 Hz, and room within the 300 ms stop budget for the stop to reach the "
        "motors on a loaded machine; below sim.command_watchdog_s",
    )
    damping: float = Field(0.02, ge=0.0, le=1.0, description="DLS damping near singularities")
    manipulability_threshold: float = Field(
        0.002, ge=0.0, description="below this the DLS damping ramps in"
    )
    max_joint_acceleration_rad_s2: float = Field(
        10.0, gt=0.0, le=1000.0, description="bound on the change between commands (rad/s²)"
    )
