"""Vision against the simulator's ground truth under the sensor conditions of the Kinect model
(deploy/experiments/accuracy.py): a small sample here; docs/vision.md reports a large one."""

from __future__ import annotations

from common.config import load_scenario
from deploy.experiments.accuracy import default_conditions, evaluate, format_table


def test_vision_accuracy_under_sensor_conditions() -> None:
    scenarios = [
        load_scenario(),
        load_scenario(None, {"target": {"position": [0.30, -0.32, 0.08], "yaw": 0.4}}),
    ]
    results = {r.condition: r for r in evaluate(scenarios, 5, default_conditions(seed=1), seed=1)}
    print("\n" + format_table(list(results.values())))
    perfect = results["perfect images, HSV"]
    assert perfect.frames == 10 and perfect.found_both_fraction == 1.0
    assert perfect.corner_rms_px <= 0.3 and perfect.depth_max_m <= 0.001
    kinect = results["Kinect, HSV"]
    assert kinect.corner_rms_px <= 0.5
    assert kinect.within_2_sigma_z >= 0.95
    for brightness in ("0.5x", "1.5x"):  # HSV holds up under exposure changes...
        assert results[f"Kinect, brightness {brightness}, HSV"].seen_both_fraction == 1.0
    assert results["Kinect, RGB"].seen_both_fraction == 1.0  # ... RGB at its calibration only
    assert results["Kinect, brightness 0.5x, RGB"].seen_both_fraction < 0.5
    assert results["Kinect, brightness 1.5x, RGB"].seen_both_fraction < 0.5
    assert results["Kinect, depth 320x240, HSV"].depth_rms_m <= 0.002
