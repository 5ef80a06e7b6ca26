"""Scenario events and camera settings: validation, the timeline as scene state, the sim acting
on it, and the --set syntax for nested tables and the events list."""

from __future__ import annotations

import numpy as np
import pytest

from common.config import Event, ScenarioError, load_scenario
from common.runtime import parse_overrides
from services.sim.events import scene_state


def event(**kw) -> Event:
    return Event.model_validate(kw)


def test_timeline_gives_the_scene_at_each_instant() -> None:
    events = [
        event(at_s=1.0, action="hide_target", duration_s=0.5),
        event(at_s=2.0, action="hide_target"),
        event(at_s=3.0, action="show_target"),
        event(at_s=1.0, action="move_target", duration_s=2.0, velocity_m_s=[0.02, 0.0, 0.0]),
        event(at_s=2.5, action="move_target", duration_s=1.0, velocity_m_s=[0.0, 0.0, -0.01]),
        event(at_s=4.0, action="occlude_hand", duration_s=1.0),
    ]
    hidden = {t: scene_state(events, t).target_hidden for t in (0.9, 1.0, 1.49, 1.5, 2.5, 3.0)}
    assert hidden == {0.9: False, 1.0: True, 1.49: True, 1.5: False, 2.5: True, 3.0: False}
    np.testing.assert_allclose(scene_state(events, 0.5).target_offset_m, 0.0)
    np.testing.assert_allclose(scene_state(events, 2.0).target_offset_m, [0.02, 0.0, 0.0])
    np.testing.assert_allclose(scene_state(events, 10.0).target_offset_m, [0.04, 0.0, -0.01])
    assert scene_state(events, 3.9).hand_occluded_since_s is None
    assert scene_state(events, 4.5).hand_occluded_since_s == 4.0
    assert scene_state(events, 5.0).hand_occluded_since_s is None


@pytest.mark.parametrize(
    "fields, fragment",
    [
        ({"action": "move_target", "duration_s": 1.0}, "needs velocity_m_s"),
        ({"action": "move_target", "velocity_m_s": [0.01, 0, 0]}, "needs duration_s"),
        ({"action": "move_target", "duration_s": 1, "velocity_m_s": [0.3, 0, 0]}, "0.2 m/s"),
        ({"action": "hide_target", "velocity_m_s": [0.01, 0, 0]}, "only for move_target"),
        ({"action": "show_target", "duration_s": 1.0}, "no duration_s"),
        ({"action": "occlude_hand"}, "needs duration_s"),
        ({"action": "teleport"}, "action"),
    ],
)
def test_bad_events_are_refused_with_the_reason(fields: dict, fragment: str) -> None:
    with pytest.raises(ScenarioError, match=fragment):
        load_scenario(None, {"events": [{"at_s": 1.0, **fields}]})


@pytest.mark.parametrize(
    "camera, fragment",
    [
        ({"depth_hz": 60.0}, "above rgb_hz"),
        ({"depth_width_px": 320}, "both"),
        ({"depth_width_px": 320, "depth_height_px": 200}, "aspect ratio"),
        ({"near_m": 6.0}, "below far_m"),
        ({"look_at": [0.02, 0.08, -0.13]}, "look_at equals position"),
        ({"position": [0.28, 0.4, 0.04], "look_at": [0.28, -0.4, 0.04]}, "straight above or"),
        ({"kinect": {"min_range_m": 3.0, "max_range_m": 1.0}}, "min_range_m .3.0. must be"),
    ],
)
def test_bad_camera_settings_are_refused_with_the_reason(camera: dict, fragment: str) -> None:
    with pytest.raises(ScenarioError, match=fragment):
        load_scenario(None, {"camera": camera})


@pytest.mark.parametrize(
    "fields, fragment",
    [
        ({"vision": {"red_hsv": []}}, "vision.red_hsv: List should have at least 1 item"),
        ({"vision": {"cue_hsv": []}}, "vision.cue_hsv: List should have at least 1 item"),
        (
            {"vision": {"green_hsv": [{"lower": [75, 120, 30], "upper": [45, 255, 255]}]}},
            r"lower \[75, 120, 30\] above upper",
        ),
        ({"vision": {"red_rgb": [300, 5, 12]}}, "vision.red_rgb.0: Input should be less"),
        ({"target": {"approach_height_m": 0.015}}, r"below 0.0271 m, the hand box"),
        (
            {"actuation": {"deadman_timeout_s": 0.04}, "run": {"clock": "realtime"}},
            "not above 1.5 camera frames",
        ),
        ({"events": [{"at_s": 100.0, "action": "hide_target"}]}, r"events\[0\] ends at 100 s"),
        ({"name": "../escape"}, "letters, digits"),
        ({"sim": {"physics_hz": 30.0}, "camera": {"rgb_hz": 120.0}}, "makes 30 frames/s"),
        (
            {
                "events": [
                    {
                        "at_s": 1.0,
                        "action": "move_target",
                        "duration_s": 2.0,
                        "velocity_m_s": [0.15, 0.0, 0.0],
                    },
                    {
                        "at_s": 2.0,
                        "action": "move_target",
                        "duration_s": 2.0,
                        "velocity_m_s": [0.15, 0.0, 0.0],
                    },
                ]
            },
            r"events\[1\]: with the moves it overlaps the object slides at 0.300 m/s at 2 s",
        ),
        ({"name": ".."}, "letters, digits"),
    ],
)
def test_settings_that_would_fail_the_run_later_are_refused_now(
    fields: dict, fragment: str
) -> None:
    """Each was once accepted and then crashed a service, stalled the run, claimed a run
    converged far off its goal, or wrote outside the results' folder."""
    with pytest.raises(ScenarioError, match=fragment):
        load_scenario(None, fields)


def test_the_limits_of_those_checks_are_accepted() -> None:
    scenario = load_scenario(
        None,
        {
            "target": {"approach_height_m": 0.028},
            "actuation": {"deadman_timeout_s": 0.06},
            "run": {"clock": "realtime"},
            "events": [{"at_s": 29.0, "action": "hide_target", "duration_s": 1.0}],
            "name": "a-b_c.1",
        },
    )
    assert scenario.events_end_s == scenario.run.timeout_s == 30.0
    lowered = load_scenario(
        None, {"target": {"approach_height_m": 0.0}, "controller": {"keep_above_target": False}}
    )
    assert lowered.target.approach_height_m == 0.0
    lockstep = load_scenario(None, {"actuation": {"deadman_timeout_s": 0.005}})
    assert lockstep.actuation.deadman_timeout_s == 0.005  # lockstep: it changes nothing


def test_set_reaches_nested_tables_and_the_events_list() -> None:
    overrides = parse_overrides(
        [
            "camera.kinect.enabled=true",
            "camera.depth_hz=1",
            'events=[{at_s = 1.0, action = "hide_target", duration_s = 1.0}]',
        ]
    )
    scenario = load_scenario(None, overrides)
    assert scenario.camera.kinect.enabled and scenario.camera.kinect.seed == 0  # rest kept
    assert scenario.camera.depth_rate_hz == 1.0 and scenario.camera.rgb_hz == 30.0
    assert scenario.events[0].end_s == 2.0 and scenario.events_end_s == 2.0
    with pytest.raises(ScenarioError, match=r"TABLE\.FIELD"):
        parse_overrides(["camera.=3"])


def test_the_assumed_camera_pose_carries_the_calibration_error() -> None:
    s = load_scenario(
        None,
        {"camera": {"calibration_error": {"position_m": [0.02, 0, 0], "rotation_deg": [0, 2, 0]}}},
    )
    true, assumed = s.camera.pose(), s.camera.assumed_pose()
    np.testing.assert_allclose(assumed[:3, 3] - true[:3, 3], [0.02, 0.0, 0.0])
    angle = np.degrees(np.arccos((np.trace(true[:3, :3].T @ assumed[:3, :3]) - 1) / 2))
    assert abs(angle - 2.0) < 1e-9
    np.testing.assert_array_equal(
        load_scenario().camera.assumed_pose(), load_scenario().camera.pose()
    )


def small_scenario(events: list[dict]):
    return load_scenario(None, {"camera": {"width_px": 320, "height_px": 240}, "events": events})


def colour_pixels(rgb: np.ndarray, channel: int) -> int:
    image = rgb.astype(int)
    others = image[:, :, [c for c in range(3) if c != channel]].max(axis=2)
    strong = image[:, :, channel]
    return int(np.count_nonzero((strong > 60) & (strong > 2 * others)))


def test_the_sim_acts_on_the_timeline() -> None:
    from services.sim.world import World

    scenario = small_scenario(
        [
            {"at_s": 0.1, "action": "hide_target", "duration_s": 0.1},
            {"at_s": 0.3, "action": "move_target", "duration_s": 0.5, "velocity_m_s": [0.02, 0, 0]},
            {"at_s": 1.0, "action": "occlude_hand", "duration_s": 0.2},
        ]
    )
    world = World(scenario)
    try:
        red = {}
        for t in (0.0, 0.15, 0.25):
            world.sim_time_s = t
            world.update_scene()
            red[t] = colour_pixels(world.render(with_depth=False)[0], 0)
        assert red[0.0] > 100 and red[0.15] == 0 and red[0.25] == red[0.0]
        start = world.truth().target_marker_pose[:3, 3].copy()
        world.sim_time_s = 2.0
        world.update_scene()
        np.testing.assert_allclose(world.truth().target_marker_pose[:3, 3] - start, [0.01, 0, 0])
        green_before = colour_pixels(world.render(with_depth=False)[0], 1)
        world.sim_time_s = 1.05  # a panel in front of the hand
        world.update_scene()
        green_hidden = colour_pixels(world.render(with_depth=False)[0], 1)
        world.sim_time_s = 1.25
        world.update_scene()
        green_after = colour_pixels(world.render(with_depth=False)[0], 1)
        assert green_before > 100 and green_hidden == 0 and green_after == green_before
    finally:
        world.close()
