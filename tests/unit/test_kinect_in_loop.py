"""The thesis's sensor conditions in the loop: the Kinect model on and depth at 1 Hz, every
strategy on the default scenario, run lockstep through the in-process pipeline (the
distributed lockstep run to the bit: tests/integration/test_pipeline_vs_distributed.py)."""

from __future__ import annotations

import pytest

from common.config import load_scenario
from common.runtime import parse_overrides
from deploy.launch.run_inprocess import run_scenario_inprocess
from tests.unit.test_compare import MODES

KINECT_AT_1_HZ = [
    "camera.kinect.enabled=true",
    "camera.depth_hz=1.0",
    "controller.converged_px=0.5",  # the noise leaves a few tenths of a pixel of jitter
]


@pytest.mark.parametrize("mode", MODES)
def test_kinect_noise_and_depth_at_1hz_the_strategy_converges(mode: str) -> None:
    scenario = load_scenario(None, parse_overrides([*KINECT_AT_1_HZ, f"controller.mode='{mode}'"]))
    r = run_scenario_inprocess(scenario)
    print(f"\nKinect noise, depth at 1 Hz, {mode}: {r.reason} {r.frames} frames, "
          f"{r.final_pixel_rms} px, {r.final_position_error_m} m")  # fmt: skip
    assert r.converged and r.reason == "converged", r
    assert r.final_pixel_rms is not None and r.final_pixel_rms < 1.5, r
    assert r.final_position_error_m is not None and r.final_position_error_m < 0.010, r
