"""The constant strategy's stability at a scenario's goal, judged before launch.

Where the frozen matrix makes the goal unstable (:mod:`services.controller.stability`) the
constant law drives the hand away from a goal it has nearly reached. ``umay run`` and ``umay
up`` warn of it before they launch; the campaign reports each start's value and success on
the stable and on the unstable goals apart (docs/campaign.md). Computed from the scenario's
geometry (the hand marker's corners at its goal, seen by the camera's true mount), like the
pre-launch checks: to judge, never to control. The controller computes the same value from
what the camera measured when it freezes its matrix.
"""

from __future__ import annotations

import numpy as np

from common import kinematics as kin
from common.config import JacobianMode, Scenario
from common.marker import Marker
from deploy.launch.reachability import camera_points, goal_pose
from services.controller.stability import constant_goal_stability, unstable_goal_consequence


def goal_stability_of(scenario: Scenario) -> float:
    """:func:`~services.controller.stability.constant_goal_stability` at the scenario's goal,
    with its ``controller.constant_depth``."""
    corners_base = kin.marker_corners(goal_pose(scenario), scenario.marker.size_m)
    points = camera_points(corners_base, scenario)
    k = scenario.camera.intrinsics()
    goal = Marker.seen_at(points, k, np.zeros(len(points)))
    return constant_goal_stability(goal, k, scenario.controller.constant_depth)


def unstable_goal_warning(scenario: Scenario) -> str:
    """What to say before launching a constant run whose goal its frozen matrix makes
    unstable ("": another strategy, or a goal it holds)."""
    if scenario.controller.mode is not JacobianMode.CONSTANT:
        return ""
    stability = goal_stability_of(scenario)
    if stability > 0.0:
        return ""
    return (
        f"controller.mode: constant's frozen matrix ({scenario.controller.constant_depth.value} "
        f"depth) makes this goal unstable {unstable_goal_consequence(stability)}"
    )
