"""The scenario's event timeline as scene state at a given simulated time. Pure functions.

Events (``[[events]]`` in the scenario, :class:`common.config.Event`) change the scene only:
the target marker disappears and comes back, a panel hides the hand's marker, the object
slides. Perception and control learn of them through the camera, as they would.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from common.config import Event, EventAction

# A start time this close to the current time counts as reached (sim time is a sum of steps).
TIME_EPSILON_S = 1e-9


@dataclass(frozen=True)
class SceneState:
    """What the events make of the scene at one instant."""

    target_hidden: bool
    target_offset_m: np.ndarray  # (3,) displacement of the object and its marker, base frame
    hand_occluded_since_s: float | None  # start of the active occlude_hand event, if any


def scene_state(events: list[Event], t_s: float) -> SceneState:
    """The scene at simulated time ``t_s``.

    ``hide_target`` hides the red marker for ``duration_s`` (until a ``show_target`` without
    one); a later event overrides an earlier one. ``move_target`` displacements add up, each
    for its own duration. ``occlude_hand`` is active on [at_s, at_s + duration_s).
    """
    now = t_s + TIME_EPSILON_S
    hidden = False
    offset = np.zeros(3)
    occluded_since: float | None = None
    for event in sorted(events, key=lambda e: e.at_s):
        if event.at_s > now:
            break
        if event.action is EventAction.HIDE_TARGET:
            hidden = event.duration_s is None or now < event.end_s
        elif event.action is EventAction.SHOW_TARGET:
            hidden = False
        elif event.action is EventAction.MOVE_TARGET:
            moving_s = min(t_s - event.at_s, event.duration_s or 0.0)
            offset += max(moving_s, 0.0) * np.asarray(event.velocity_m_s, dtype=float)
        elif event.action is EventAction.OCCLUDE_HAND and now < event.end_s:
            occluded_since = event.at_s
    return SceneState(hidden, offset, occluded_since)
