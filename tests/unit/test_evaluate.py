"""deploy.launch.evaluate: how a run's end is judged against the ground truth."""

from __future__ import annotations

import numpy as np

from common import kinematics as kin
from deploy.launch.evaluate import square_orientation_error_deg


def test_a_half_turned_square_is_on_goal_unless_its_corner_is_marked() -> None:
    """A plain square turned 180° about its normal looks unturned; with the orientation cue the
    error is the whole turn."""
    target = kin.homogeneous(kin.rot_x(0.3), np.array([0.1, 0.2, 0.3]))
    for turn_deg, plain_deg in ((0.0, 0.0), (30.0, 30.0), (100.0, 10.0), (180.0, 0.0)):
        hand = target @ kin.homogeneous(kin.rot_z(np.radians(turn_deg)), np.zeros(3))
        assert abs(square_orientation_error_deg(hand, target) - plain_deg) < 1e-6
        assert abs(square_orientation_error_deg(hand, target, oriented=True) - turn_deg) < 1e-6


def test_a_run_ending_while_acquiring_reports_no_final_image_error() -> None:
    """An acquisition's twists are valid but carry no image error (0 stands for none): a run
    that timed out while acquiring had reported a final error of 0.000 px, under the 1 px of
    'close at the end', with the hand centimetres off."""
    from pathlib import Path

    from common.config import load_scenario
    from common.runtime import parse_overrides
    from deploy.launch.run_inprocess import run_scenario_inprocess

    suite = Path(__file__).resolve().parents[2] / "deploy/scenarios/suite"
    overrides = parse_overrides(["controller.mode='pmj'", "run.timeout_s=7.4"])
    result = run_scenario_inprocess(load_scenario(suite / "12_moving_target.toml", overrides))
    assert result.reason == "timeout" and "still acquiring" in result.detail, result.detail
    assert result.final_pixel_rms is None
