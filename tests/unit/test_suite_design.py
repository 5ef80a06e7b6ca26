"""The suite's start checks: how near the camera a marker counts as."""

from __future__ import annotations

import numpy as np
import pytest

from common import kinematics as kin
from common.config import load_scenario
from deploy.experiments.suite_design import nearest_depth_m


def test_a_markers_nearness_is_its_depth_along_the_optical_axis_not_its_distance() -> None:
    """The Kinect cuts its depth image by depth: a marker facing the camera 0.5 m deep and
    20 cm off the axis is 0.5 m near, though its corners are over 0.52 m from the lens."""
    scenario = load_scenario()
    camera = scenario.camera.pose()
    centre = camera[:3, 3] + 0.5 * camera[:3, 2] + 0.2 * camera[:3, 0]
    pose = kin.homogeneous(camera[:3, :3], centre)  # its face in a plane square to the axis
    corners = kin.marker_corners(pose, scenario.marker.size_m)
    assert np.min(np.linalg.norm(corners - camera[:3, 3], axis=1)) > 0.52
    assert nearest_depth_m(pose, scenario) == pytest.approx(0.5, abs=1e-12)
    tilted = pose @ kin.homogeneous(kin.rot_x(np.radians(30.0)), np.zeros(3))
    half = scenario.marker.size_m / 2
    expected = 0.5 - half * np.sin(np.radians(30.0))  # its near edge tilted toward the camera
    assert nearest_depth_m(tilted, scenario) == pytest.approx(expected, abs=1e-12)
