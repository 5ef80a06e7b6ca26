"""Vision's warm-up frame: of the scenario's sizes, and measured in full (both markers wholly
seen, with depth, and labelled by their cue when they carry one), so that it runs the code
paths the camera's first frame would."""

from __future__ import annotations

import numpy as np
import pytest

from common.config import load_scenario
from common.runtime import parse_overrides
from services.vision.warmup import WARMUP_DEPTH_M, synthetic_frame, warm_up


@pytest.mark.parametrize(
    "overrides",
    [
        [],
        ["camera.depth_width_px=320", "camera.depth_height_px=240"],
        ["vision.segmentation='rgb'"],
        ["marker.orientation_cue=true"],  # each square with its cue: labelled, visible
    ],
)
def test_the_warm_up_frame_is_measured_in_full(overrides: list[str]) -> None:
    scenario = load_scenario(None, parse_overrides(overrides))
    camera, size_m = scenario.camera, scenario.marker.size_m
    k, depth_k = camera.intrinsics(), camera.depth_intrinsics()
    cue = scenario.marker.orientation_cue
    rgb, depth_m = synthetic_frame(k, depth_k, scenario.vision, size_m, cue)
    assert rgb.shape == (k.height_px, k.width_px, 3) and rgb.dtype == np.uint8
    assert depth_m.shape == (depth_k.height_px, depth_k.width_px)
    step = warm_up(k, depth_k, scenario.vision, size_m, cue)
    for name in ("hand", "target"):
        marker = step.measured[name]
        assert marker.state == "visible", (name, marker.reason)
        np.testing.assert_allclose(marker.depth_m, WARMUP_DEPTH_M, atol=1e-6)
        side_m = np.linalg.norm(marker.points_m[1] - marker.points_m[0])
        assert side_m == pytest.approx(size_m, rel=0.05)
