"""The scenario's ``[[events]]`` timeline: what the sim does to the scene, and when."""

from __future__ import annotations

from enum import StrEnum

import numpy as np
from pydantic import Field, model_validator

from common.config.base import Strict, Vec3


class EventAction(StrEnum):
    HIDE_TARGET = "hide_target"  # the red marker disappears (for duration_s, or until shown)
    SHOW_TARGET = "show_target"
    OCCLUDE_HAND = "occlude_hand"  # a panel comes between the camera and the hand's marker
    MOVE_TARGET = "move_target"  # the object slides at velocity_m_s for duration_s


MAX_TARGET_SPEED_M_S = 0.2  # how fast a move_target event may slide the object


class Event(Strict):
    """One entry of the scenario's ``[[events]]`` timeline (simulated time). Only the sim acts
    on events: perception and control learn of them through the camera, as they would."""

    at_s: float = Field(ge=0.0, le=3600.0, description="simulated time it starts (s)")
    action: EventAction = Field(
        description="hide_target (for duration_s, or until a show_target), show_target, "
        "occlude_hand (a panel before the hand's marker for duration_s) or move_target (the "
        "object slides at velocity_m_s for duration_s)"
    )
    duration_s: float | None = Field(
        None, gt=0.0, le=3600.0, description="how long it lasts (simulated s)"
    )
    velocity_m_s: Vec3 | None = Field(None, description="move_target: base frame (m/s)")

    @model_validator(mode="after")
    def _fields_fit_the_action(self) -> Event:
        moving = self.action is EventAction.MOVE_TARGET
        if moving and self.velocity_m_s is None:
            raise ValueError("move_target needs velocity_m_s")
        if not moving and self.velocity_m_s is not None:
            raise ValueError(f"velocity_m_s is only for move_target, not {self.action.value}")
        if moving and float(np.linalg.norm(self.velocity_m_s)) > MAX_TARGET_SPEED_M_S:
            raise ValueError(f"move_target: speed above {MAX_TARGET_SPEED_M_S:g} m/s")
        timed = self.action in (EventAction.MOVE_TARGET, EventAction.OCCLUDE_HAND)
        if timed and self.duration_s is None:
            raise ValueError(f"{self.action.value} needs duration_s")
        if self.action is EventAction.SHOW_TARGET and self.duration_s is not None:
            raise ValueError("show_target takes no duration_s")
        return self

    @property
    def end_s(self) -> float:
        return self.at_s + (self.duration_s or 0.0)
