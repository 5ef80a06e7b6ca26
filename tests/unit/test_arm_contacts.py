"""The simulator names a collision of the arm with the scenery (ground truth, for judging a
run), and the judge reports the first one."""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

import pytest

from common.config import ScenarioError, load_scenario
from common.messages import Header, SimTruth
from common.runtime import parse_overrides
from deploy.launch.evaluate import CONTACT_MIN_N, first_contact
from deploy.launch.reachability import (
    PENETRATION_TOLERANCE_M,
    arm_penetration,
    check_scenario,
    solve_goal,
)
from services.sim.world import World

T = TypeVar("T")
SMALL = ["camera.width_px=160", "camera.height_px=120", "sim.renderer='gl'"]


def at_goal(approach_height_m: float, measure: Callable[[World], T]) -> T:
    """``measure`` of a world whose hand holds its marker ``approach_height_m`` above the
    target (the controller's clearance off: a goal in the object is no run's goal)."""
    height = f"target.approach_height_m={approach_height_m}"
    unguarded = "controller.keep_above_target=false"
    scenario = load_scenario(None, parse_overrides([*SMALL, height, unguarded]))
    solved = solve_goal(scenario)
    assert solved is not None
    world = World(scenario)
    try:
        world.reset(solved[0])
        return measure(world)
    finally:
        world.close()


def contacts_at_goal(approach_height_m: float) -> tuple[float, tuple[str, ...]]:
    """The arm's contacts after one physics step at the goal posture."""

    def contacts(world: World) -> tuple[float, tuple[str, ...]]:
        world.step(1)
        truth = world.truth()
        assert (truth.contact_n, truth.contact_with) == world.arm_contacts()
        return world.arm_contacts()

    return at_goal(approach_height_m, contacts)


def test_a_hand_pushed_into_the_object_is_a_contact_and_one_above_it_is_not() -> None:
    force_n, bodies = contacts_at_goal(0.0)  # the marker on the red one: the hand inside
    assert force_n >= CONTACT_MIN_N and bodies == ("object",)
    assert contacts_at_goal(0.05) == (0.0, ())


def truth_at(seq: int, contact_n: float, bodies: list[str]) -> SimTruth:
    return SimTruth(
        header=Header(seq=seq, sim_time_s=seq / 15, send_time_s=0.0, frame_seq=seq),
        hand_marker_pose=[0.0] * 16, target_marker_pose=[0.0] * 16,
        hand_corners_px=[[0.0, 0.0]] * 4, target_corners_px=[[0.0, 0.0]] * 4,
        ee_position_m=[0.0] * 3, joint_position_rad=[0.0] * 6,
        arm_contact_n=contact_n, arm_contact_with=bodies,
    )  # fmt: skip


def test_the_first_contact_pressing_harder_than_resting_noise_is_reported() -> None:
    truths = {
        0: truth_at(0, 0.0, []),
        1: truth_at(1, 0.1, ["table"]),  # below CONTACT_MIN_N: resting noise
        2: truth_at(2, 40.0, ["object"]),
        3: truth_at(3, 90.0, ["object", "table"]),
    }
    assert first_contact(truths, 3) == (2 / 15, "object")
    assert first_contact(truths, 1) == (None, None)


# A domain-study start (cell 26, draw 0) whose forearm starts 12 mm inside the target's block.
ARM_IN_BLOCK = [
    "robot.q0=[1.637742, -1.689403, 1.999626, 1.807145, 0.146094, -0.302508]",
    "target.position=[0.18264047554538515, -0.32, 0.11600570401288576]",
    "target.yaw=-0.028020330767983347",
]
BASELINE = "deploy/scenarios/suite/01_baseline.toml"


def test_a_start_posture_inside_the_object_is_measured_and_refused_before_launch() -> None:
    inside = load_scenario(BASELINE, parse_overrides(ARM_IN_BLOCK))
    depth_m, into = arm_penetration(inside)
    assert into == "object" and 0.010 < depth_m < 0.015
    with pytest.raises(ScenarioError, match=r"robot\.q0: the arm is 12\.\d mm inside the object"):
        check_scenario(inside)
    clear = load_scenario(BASELINE)
    assert arm_penetration(clear) == (0.0, "")
    check_scenario(clear)  # the suite's baseline is not refused


def test_the_penetration_is_pybullets_closest_points_at_the_posture() -> None:
    """World.arm_penetration at the posture it holds: the hand pushed into the object at its
    goal (approach height 0) reaches into it; lifted 5 cm above, it is clear."""
    for height_m, expect_inside in ((0.0, True), (0.05, False)):
        depth_m, into = at_goal(height_m, World.arm_penetration)
        assert (depth_m > PENETRATION_TOLERANCE_M) == expect_inside
        assert into == ("object" if expect_inside else "")


def test_a_world_and_a_pre_launch_check_print_nothing(capfd: pytest.CaptureFixture[str]) -> None:
    """No stray ``argv[0]=`` from pybullet's connect (services.sim.world.DirectClient): a
    campaign makes hundreds of worlds, umay run one before its live line."""
    capfd.readouterr()
    check_scenario(load_scenario(BASELINE))
    world = World(load_scenario(None, parse_overrides(SMALL)))
    world.close()
    captured = capfd.readouterr()
    assert captured.out == "" and captured.err == ""


def test_a_target_in_the_table_or_a_goal_out_of_view_is_refused_before_launch() -> None:
    """Each was accepted and then left the run acquiring or stuck to its timeout."""
    in_table = load_scenario(None, {"target": {"position": [0.28, -0.42, 0.04]}})
    with pytest.raises(ScenarioError, match=r"target\.position: y -0\.42 m is not above the"):
        check_scenario(in_table)
    high_goal = load_scenario(None, {"target": {"approach_height_m": 0.2}})
    with pytest.raises(ScenarioError, match=r"target\.approach_height_m: the hand marker's goal"):
        check_scenario(high_goal)
