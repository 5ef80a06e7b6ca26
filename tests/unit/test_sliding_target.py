"""The hand follows a sliding target, lockstep through the in-process pipeline (the
distributed lockstep run to the bit: tests/integration/test_pipeline_vs_distributed.py, whose
moving-target case runs the services)."""

from __future__ import annotations

from common.config import load_scenario
from common.runtime import parse_overrides
from deploy.launch.run_inprocess import run_scenario_inprocess

SLIDING = (
    "events=[{at_s = 1.0, action = 'move_target', duration_s = 4.0, "
    "velocity_m_s = [0.0, 0.0, 0.02]}]"
)


def test_the_hand_follows_a_sliding_target() -> None:
    """move_target at 2 cm/s for 4 s (the hand hides the object most of the time): the hand
    keeps up, the tracking error is reported, and it converges once the object stops."""
    scenario = load_scenario(None, parse_overrides(["controller.mode='dynamic'", SLIDING]))
    r = run_scenario_inprocess(scenario)
    print(f"\nsliding target: {r}")
    assert r.tracking_position_error_m is not None
    assert r.tracking_position_error_m < 0.010  # median while it slides
    assert r.tracking_max_position_error_m is not None
    assert r.tracking_max_position_error_m < 0.030
    assert r.converged and r.final_position_error_m is not None
    assert r.final_position_error_m < 0.005
    assert r.sim_time_s > 5.0  # not before the object stopped
