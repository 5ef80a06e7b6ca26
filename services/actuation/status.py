"""Actuation's own status fields (``umay status``; docs/operations.md renders them)."""

from __future__ import annotations

from pydantic import Field

from common.messages import StatusFields


class ActuationStatus(StatusFields):
    deadman: bool = Field(
        description="a valid twist came, none within `actuation.deadman_timeout_s` since: the "
        "motors are commanded to zero (false before the first twist)"
    )
    deadman_stops: int = Field(
        description="zero commands sent because no valid twist came within "
        "`actuation.deadman_timeout_s`"
    )
    hold_stops: int = Field(description="zero commands answering the controller's holds")
    position_limit_clamps: int = Field(
        description="commands slowed near a joint limit (within 10°, zero at it)"
    )
    velocity_clamps: int = Field(description="commands with a joint over its speed limit")
    acceleration_clamps: int = Field(
        description="commands whose change from the previous one was bounded"
    )
    nonfinite_guards: int = Field(
        description="commands that came out NaN or Inf (from the twist, a joint angle or the "
        "previous command): zero was sent instead"
    )
    damped_commands: int = Field(
        description="commands through the damped inverse near a singularity"
    )
    saturated_joints: list[int] = Field(
        description="joints the last command slowed near a position limit or held to their "
        "speed limit"
    )
    manipulability: float = Field(
        description="√det(J Jᵀ) at the last command (none before one: NaN)"
    )
