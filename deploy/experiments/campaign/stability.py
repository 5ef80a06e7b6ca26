"""The constant strategy's stability at a start's goal, from the true geometry.

Where the frozen matrix makes the goal unstable (:mod:`services.controller.stability`) the
constant law drives the hand away from its goal; the campaign reports each start's value and
success on the stable and on the unstable goals apart (docs/campaign.md). Computed from the
simulator's geometry (the hand marker's corners at its goal, seen by the true camera), like
the failure causes: to judge, never to control. The controller computes the same value from
what the camera measured when it freezes its matrix.
"""

from __future__ import annotations

import numpy as np

from common import kinematics as kin
from common.config import Scenario
from common.marker import Marker
from deploy.launch.reachability import goal_pose
from services.controller.stability import constant_goal_stability


def goal_stability_of(scenario: Scenario) -> float:
    """:func:`~services.controller.stability.constant_goal_stability` at the scenario's goal,
    with its ``controller.constant_depth``."""
    corners_base = kin.marker_corners(goal_pose(scenario), scenario.marker.size_m)
    base_to_cam = np.linalg.inv(scenario.camera.pose())
    points = corners_base @ base_to_cam[:3, :3].T + base_to_cam[:3, 3]
    k = scenario.camera.intrinsics()
    goal = Marker.seen_at(points, k, np.zeros(len(points)))
    return constant_goal_stability(goal, k, scenario.controller.constant_depth)
