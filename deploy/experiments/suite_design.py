"""How the comparison suite's start postures were found, and the checks each scenario passed.

A start is described the way the default scenario's was: the hand marker's pose relative to
its goal (the red marker raised by the approach height), as a translation in the base frame
and a turn about the vertical (plus an optional tilt about the base's forward axis);
inverse kinematics then gives ``robot.q0``. :func:`check_start` renders the scene once and
checks what the pre-launch check cannot: both markers wholly visible and untouched by the
rest of the robot, beyond the Kinect's near-mode limit (with a margin, see :func:`min_range_m`),
and apart in the image (vision refuses a target the hand overlaps, and the
controller would then wait for it forever).

Usage: ``python -m deploy.experiments.suite_design [SCENARIO.toml ...]`` prints the report of
each file (default: every file of ``deploy/scenarios/suite``); ``python -m
deploy.experiments.suite_design --solve X Y Z TURN_DEG [TILT_DEG] --scenario F`` prints the q0
of a start offset for F's target.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from common import kinematics as kin
from common.config import Scenario, ScenarioError, load_scenario
from deploy.launch.reachability import check_scenario, goal_pose, square_turns

SUITE_DIR = Path(__file__).resolve().parents[1] / "scenarios" / "suite"
KINECT_RANGE_MARGIN_M = 0.03  # noisy depth: 3 cm clear of the near limit (the brief's 0.43 m)
PERFECT_RANGE_MARGIN_M = 0.01  # exact depth is valid at any range; stay physically plausible
MIN_GAP_PX = 12.0  # hand and target squares this far apart in the image at the start
# The actuation slows a joint within 10° of its limit (services/actuation/inverse.py), which
# stalls the last millimetres of a servo whose goal lies there: keep goals 5° clear of that.
MIN_JOINT_MARGIN_DEG = 15.0
WHOLE = 0.99  # fraction of a marker's square that must show the marker itself


@dataclass(frozen=True)
class StartReport:
    """What the camera sees at the start and at the goal (from the true camera pose)."""

    hand_depth_m: float  # nearest hand-marker corner's depth (along the optical axis), at start
    goal_depth_m: float  # ... at the goal
    target_depth_m: float
    target_centre_px: tuple[float, float]  # (u, v) of the red square's centre
    target_side_px: float  # its mean side length in the image
    gap_px: float  # smallest distance between the two squares' corners in the image
    hand_fraction: float  # share of the hand square seen (1 = wholly visible)
    target_fraction: float
    hand_touched: bool  # another robot part touches the hand marker's outline
    target_touched: bool
    goal_hand_fraction: float  # share of the hand square seen with the hand on its goal
    start_joint_margin_deg: float  # nearest joint limit, at the start
    goal_joint_margin_deg: float  # ... at the goal (the IK solution on the start's branch)
    offset_mm: float  # hand marker to its goal, at the start
    turn_deg: float  # rotation between the hand marker and its goal, at the start
    problems: tuple[str, ...]

    @property
    def ok(self) -> bool:
        return not self.problems


def min_range_m(scenario: Scenario) -> float:
    """How shallow in the image a marker's corner may be: the Kinect model's near limit
    (0.4 m deep) plus 3 cm when it is on (its depth is invalid below the limit), plus 1 cm with
    exact depth, valid at any depth (the default scenario's own start is 0.408 m deep, so the
    check flags it: kept as the thesis's start)."""
    kinect = scenario.camera.kinect
    margin = KINECT_RANGE_MARGIN_M if kinect.enabled else PERFECT_RANGE_MARGIN_M
    return kinect.min_range_m + margin


def start_pose(
    goal: np.ndarray, offset_m: np.ndarray, turn_deg: float, tilt_deg: float = 0.0
) -> np.ndarray:
    """The goal pose turned about the vertical by ``turn_deg`` (then tilted about the base's
    forward axis by ``tilt_deg``) and moved by ``offset_m`` (base frame)."""
    turn = kin.rot_y(np.radians(turn_deg)) @ kin.rot_x(np.radians(tilt_deg))
    return kin.homogeneous(turn @ goal[:3, :3], goal[:3, 3] + np.asarray(offset_m, dtype=float))


def solve_start(
    scenario: Scenario,
    offset_m: np.ndarray,
    turn_deg: float,
    tilt_deg: float = 0.0,
    steps: int = 20,
) -> np.ndarray:
    """Joint angles putting the hand marker at the start pose. IK walks there from the goal's
    solution in ``steps`` small moves, each seeded with the last (a large turn in one jump
    stalls the damped iteration at a joint limit), so the start keeps the goal's elbow and
    wrist branch. Raises ScenarioError."""
    q = check_scenario(scenario)
    goal = goal_pose(scenario)
    tool = kin.hand_marker_in_ee()
    # The branch the goal was solved on: one of the square's four 90° turns about its normal.
    here = kin.forward_kinematics(q) @ tool
    turns = square_turns(goal)
    k_best = min(range(4), key=lambda k: kin.rotation_error_rad(here[:3, :3], turns[k][:3, :3]))
    symmetric = kin.homogeneous(kin.rot_z(k_best * np.pi / 2), np.zeros(3))
    for i in range(1, steps + 1):
        f = i / steps
        wanted = start_pose(goal, f * np.asarray(offset_m), f * turn_deg, f * tilt_deg)
        q, pos_err, rot_err = kin.inverse_kinematics(wanted @ symmetric, q, tool)
    if pos_err > 1e-5 or rot_err > 1e-4:
        raise ScenarioError(
            f"start pose out of reach or beyond the joint limits ({1000 * pos_err:.1f} mm, "
            f"{np.degrees(rot_err):.1f} deg off)"
        )
    return q


def joint_margin_deg(q_rad: np.ndarray) -> float:
    """Distance of the joint nearest to one of its limits (degrees)."""
    margin = np.minimum(q_rad - kin.JOINT_LOWER_RAD, kin.JOINT_UPPER_RAD - q_rad)
    return float(np.degrees(np.min(margin)))


def goal_on_start_branch(scenario: Scenario) -> np.ndarray:
    """The goal's IK solution seeded from ``robot.q0`` (where the servo is likely to end: the
    same elbow and wrist branch), else the pre-launch check's."""
    q0 = np.array(scenario.robot.q0)
    goal = goal_pose(scenario)
    tool = kin.hand_marker_in_ee()
    for wanted in square_turns(goal):
        q, pos_err, rot_err = kin.inverse_kinematics(wanted, q0, tool)
        if pos_err < 1e-5 and rot_err < 1e-4 and np.linalg.norm(q - q0) < np.pi:
            return q
    return check_scenario(scenario)


def nearest_depth_m(pose: np.ndarray, scenario: Scenario) -> float:
    """The smallest depth of a marker's corners at ``pose``: the distance along the camera's
    optical axis, which the Kinect's near limit bounds (its depth image is cut by depth, not
    by the distance from the lens, which is larger off the axis)."""
    corners = kin.marker_corners(pose, scenario.marker.size_m)
    camera = scenario.camera.pose()
    return float(np.min((corners - camera[:3, 3]) @ camera[:3, 2]))


def check_start(scenario: Scenario) -> StartReport:
    """Render the start once and judge it (see the module docstring). Raises ScenarioError
    when the pre-launch check already refuses the scenario."""
    from deploy.launch.evaluate import square_orientation_error_deg
    from services.sim.world import World

    check_scenario(scenario)
    goal = goal_pose(scenario)
    q_goal = goal_on_start_branch(scenario)
    world = World(scenario)
    try:
        truth = world.truth()
        seen = world.marker_visibility()
        world.reset(q_goal)  # the arm must not hide its own marker once there
        seen_at_goal = world.marker_visibility()["hand"].fraction
    finally:
        world.close()
    hand = truth.hand_marker_pose
    gap = float(
        np.min(
            np.linalg.norm(
                truth.hand_corners_px[:, None, :] - truth.target_corners_px[None, :, :], axis=2
            )
        )
    )
    sides = np.linalg.norm(
        np.diff(truth.target_corners_px, axis=0, append=truth.target_corners_px[:1]), axis=1
    )
    report = {
        "target_centre_px": tuple(float(v) for v in truth.target_corners_px.mean(axis=0)),
        "target_side_px": float(np.mean(sides)),
        "hand_depth_m": nearest_depth_m(hand, scenario),
        "goal_depth_m": nearest_depth_m(goal, scenario),
        "target_depth_m": nearest_depth_m(truth.target_marker_pose, scenario),
        "gap_px": gap,
        "hand_fraction": seen["hand"].fraction,
        "target_fraction": seen["target"].fraction,
        "hand_touched": seen["hand"].touched,
        "target_touched": seen["target"].touched,
        "goal_hand_fraction": seen_at_goal,
        "start_joint_margin_deg": joint_margin_deg(np.array(scenario.robot.q0)),
        "goal_joint_margin_deg": joint_margin_deg(q_goal),
        "offset_mm": 1000.0 * float(np.linalg.norm(hand[:3, 3] - goal[:3, 3])),
        "turn_deg": square_orientation_error_deg(hand, goal),
    }
    problems = []
    nearest = min_range_m(scenario)
    for name in ("hand_depth_m", "goal_depth_m", "target_depth_m"):
        if report[name] < nearest:
            problems.append(f"{name} {report[name]:.3f} m below {nearest:.2f} m")
    if gap < MIN_GAP_PX:
        problems.append(f"hand and target only {gap:.1f} px apart in the image")
    for name in ("hand", "target"):
        if report[f"{name}_fraction"] < WHOLE:
            problems.append(f"{name} marker {100 * report[f'{name}_fraction']:.1f} % visible")
        if report[f"{name}_touched"]:
            problems.append(f"another part of the robot touches the {name} marker's outline")
    if report["goal_joint_margin_deg"] < MIN_JOINT_MARGIN_DEG:
        problems.append(
            f"at the goal a joint is {report['goal_joint_margin_deg']:.1f}° from its limit"
        )
    problems += moved_target_problems(scenario)
    if seen_at_goal < WHOLE:
        problems.append(f"at the goal the hand marker is {100 * seen_at_goal:.1f} % visible")
    return StartReport(**report, problems=tuple(problems))


def moved_target_problems(scenario: Scenario) -> list[str]:
    """A target moved by ``move_target`` events must still be reachable and in view where it
    ends (the pre-launch check only looks at where it starts)."""
    from services.sim.events import scene_state

    offset = scene_state(scenario.events, scenario.events_end_s).target_offset_m
    if not np.any(offset):
        return []
    moved = [float(v) for v in np.array(scenario.target.position) + offset]
    update = {"target": scenario.target.model_copy(update={"position": moved})}
    ended = scenario.model_copy(update=update)
    try:
        check_scenario(ended)
    except ScenarioError as exc:
        return [f"after its move to {np.round(moved, 3).tolist()}: {exc}"]
    nearest = nearest_depth_m(goal_pose(ended), ended)
    if nearest < min_range_m(ended):
        return [f"after its move the goal is {nearest:.3f} m deep in the image"]
    return []


def format_report(name: str, r: StartReport) -> str:
    verdict = "ok" if r.ok else "PROBLEM: " + "; ".join(r.problems)
    return (
        f"{name:28s} start {r.offset_mm:5.0f} mm {r.turn_deg:5.1f} deg from goal | depth hand "
        f"{r.hand_depth_m:.3f} goal {r.goal_depth_m:.3f} target {r.target_depth_m:.3f} m | "
        f"target at ({r.target_centre_px[0]:.0f}, {r.target_centre_px[1]:.0f}) px, side "
        f"{r.target_side_px:.0f} px | gap {r.gap_px:5.0f} px | seen hand {r.hand_fraction:.3f} "
        f"target {r.target_fraction:.3f} at goal {r.goal_hand_fraction:.3f} | joint margin "
        f"start {r.start_joint_margin_deg:.0f}° goal {r.goal_joint_margin_deg:.0f}° | {verdict}"
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m deploy.experiments.suite_design", description=__doc__
    )
    p.add_argument("files", nargs="*", help="scenario TOML files (default: the suite)")
    p.add_argument("--solve", nargs="+", type=float, metavar="X Y Z TURN [TILT]")
    p.add_argument("--scenario", default=None, help="for --solve: whose target")
    args = p.parse_args(argv)
    if args.solve:
        if len(args.solve) not in (4, 5):
            p.error("--solve takes X Y Z TURN_DEG [TILT_DEG]")
        scenario = load_scenario(args.scenario)
        q = solve_start(scenario, np.array(args.solve[:3]), *args.solve[3:])
        print("q0 = [" + ", ".join(f"{v:.3f}" for v in q) + "]")
        rounded = [round(float(v), 3) for v in q]
        update = {"robot": scenario.robot.model_copy(update={"q0": rounded})}
        print(format_report("(solved)", check_start(scenario.model_copy(update=update))))
        return 0
    files = [Path(f) for f in args.files] or sorted(SUITE_DIR.glob("*.toml"))
    bad = 0
    for f in files:
        try:
            report = check_start(load_scenario(f))
        except ScenarioError as exc:
            print(f"{f.stem:28s} REFUSED: {exc}")
            bad += 1
            continue
        print(format_report(f.stem, report))
        bad += not report.ok
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
