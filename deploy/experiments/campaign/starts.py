"""A campaign's random starts: the distribution (``deploy/campaigns/random_starts.toml``) and
:func:`draw_start`, which draws start ``i`` from its own generator (``default_rng([seed, i])``)
and draws again, counting why, what is no start of this distribution (a marker outside the
image, a pose out of reach, the arm inside the scenery)."""

from __future__ import annotations

import math
import tomllib
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TypeVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from common import kinematics as kin
from common.config import Scenario, ScenarioError
from deploy.experiments.compare import CompareError
from deploy.launch.goal_stability import goal_stability_of
from deploy.launch.reachability import (
    MAX_VIEW_ANGLE_DEG,
    ArmInsideScenery,
    arm_hides_hand_marker,
    check_scenario,
    goal_pose,
    marker_in_image,
    solve_goal,
    square_turns,
    view_angle_deg,
)

D = TypeVar("D", bound=BaseModel)  # a definition with a base_scenario field
DEFAULT_DISTRIBUTION = Path(__file__).resolve().parents[2] / "campaigns" / "random_starts.toml"
IK_STEPS = 20  # the start is reached from the goal in this many small IK moves


class Distribution(BaseModel):
    """The random-start distribution (see ``deploy/campaigns/random_starts.toml``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    seed: int = Field(ge=0)
    base_scenario: str
    target_x_m: tuple[float, float]
    target_z_m: tuple[float, float]
    target_y_m: float
    max_offset_m: float = Field(gt=0.0, le=0.5)
    max_turn_deg: float = Field(ge=0.0, le=180.0)
    max_draws: int = Field(200, ge=1)
    timeout_s: float | None = Field(
        None, gt=0.0, le=3600.0, description="run.timeout_s of every run (None: the base's)"
    )


def load_definition(
    path: Path, model: type[D], option: str, changes: dict[str, object] | None = None
) -> tuple[D, Path]:
    """A TOML definition of random starts (a campaign's distribution, a domain study) validated
    as ``model``, with ``changes`` (fields from the command line, None: kept), and the absolute
    path of its ``base_scenario``; raises CompareError naming ``option``."""
    try:
        data = tomllib.loads(path.read_text())
        data.update({k: v for k, v in (changes or {}).items() if v is not None})
        definition = model.model_validate(data)
    except (OSError, tomllib.TOMLDecodeError, ValidationError) as exc:
        raise CompareError(f"{option}: {path}: {exc}") from exc
    base = (path.parent / definition.base_scenario).resolve()
    if not base.is_file():
        raise CompareError(f"{option}: {path}: base_scenario {base}: no such file")
    return definition, base


def load_distribution(path: Path) -> tuple[Distribution, Path]:
    """The distribution and the absolute path of its base scenario; raises CompareError."""
    return load_definition(path, Distribution, "--distribution")


def start_overrides(
    name: str, q0_rad: Sequence[float], target_position_m: Sequence[float], target_yaw_rad: float
) -> tuple[str, ...]:
    """The scenario overrides that make a base scenario a drawn start: its name, the arm's
    start posture and the target's placement (``repr``: the floats exactly)."""
    q0 = ", ".join(repr(v) for v in q0_rad)
    pos = ", ".join(repr(v) for v in target_position_m)
    return (
        f"name='{name}'",
        f"robot.q0=[{q0}]",
        f"target.position=[{pos}]",
        f"target.yaw={target_yaw_rad!r}",
    )


@dataclass(frozen=True)
class Start:
    """One drawn start: the target and the hand's offset from its goal, the joint angles that
    put it there, and the pre-launch check's verdict (``refused``: its reason, "" to run)."""

    index: int
    name: str
    target_position_m: tuple[float, float, float]
    target_yaw_rad: float
    offset_m: tuple[float, float, float]
    turn_deg: float
    q0_rad: tuple[float, ...] | None
    refused: str
    draws: int  # draws it took
    redrawn: dict[str, int]  # why the draws before it were drawn again (REDRAW_*)
    # The constant strategy's stability at the goal (.stability; ≤ 0: its frozen matrix drives
    # the hand away from it); None for a start not run.
    constant_goal_stability: float | None = None

    def overrides(self) -> tuple[str, ...]:
        """The scenario overrides that make the base scenario this start."""
        assert self.q0_rad is not None
        return start_overrides(self.name, self.q0_rad, self.target_position_m, self.target_yaw_rad)


def with_target(base: Scenario, position: Sequence[float], yaw_rad: float) -> Scenario:
    target = base.target.model_copy(update={"position": list(position), "yaw": yaw_rad})
    return base.model_copy(update={"target": target})


def with_q0(scenario: Scenario, q0: Sequence[float]) -> Scenario:
    return scenario.model_copy(update={"robot": scenario.robot.model_copy(update={"q0": list(q0)})})


def rotation_about(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    s = kin.skew(axis / np.linalg.norm(axis))
    return np.eye(3) + math.sin(angle_rad) * s + (1 - math.cos(angle_rad)) * s @ s


def walk_to_start(
    scenario: Scenario, q_goal: np.ndarray, turn: int, offset_m: np.ndarray, turn_rad: float
) -> np.ndarray | None:
    """Joint angles putting the hand marker at its goal turned about the optical axis by
    ``turn_rad`` and moved by ``offset_m``, walked from the goal's solution (its elbow and
    wrist branch); None when IK does not get there."""
    goal = square_turns(goal_pose(scenario))[turn]
    axis = scenario.camera.pose()[:3, 2]
    tool = kin.hand_marker_in_ee()
    q = q_goal
    for i in range(1, IK_STEPS + 1):
        f = i / IK_STEPS
        wanted = kin.homogeneous(
            rotation_about(axis, f * turn_rad) @ goal[:3, :3], goal[:3, 3] + f * offset_m
        )
        q, pos_err, rot_err = kin.inverse_kinematics(wanted, q, tool)
    if pos_err > 1e-5 or rot_err > 1e-4:
        return None
    return q


def half_ball_offset(rng: np.random.Generator, radius_m: float) -> np.ndarray:
    """Uniform in the half ball of ``radius_m`` above its centre (base y ≥ 0)."""
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    offset = radius_m * rng.uniform() ** (1 / 3) * direction
    offset[1] = abs(offset[1])
    return offset


# Why a draw was drawn again (none of these is in the distribution; each is counted).
REDRAW_TARGET_OUTSIDE = "target marker not wholly in the image"
REDRAW_START_OUT_OF_REACH = "start pose out of reach"
REDRAW_HAND_OUTSIDE = "hand marker not wholly in the image at start"
REDRAW_HAND_FACING_AWAY = "hand marker facing away from the camera at start"
REDRAW_HAND_HIDDEN = "hand marker hidden by the robot's own arm at start"
# The goal reached on the start's elbow and wrist branch: there the servo ends.
REDRAW_GOAL_HIDDEN = "hand marker hidden by the robot's own arm at the goal (on that branch)"
# A posture that intersects the object or the table is no posture of the arm at all.
REDRAW_ARM_INSIDE = "arm inside the object or the table at start"


def draw_start(dist: Distribution, base: Scenario, index: int) -> Start:
    """Start ``index`` of the distribution, from its own generator (see the module doc)."""
    rng = np.random.default_rng([dist.seed, index])
    name = f"start_{index:04d}"
    redrawn: Counter[str] = Counter()
    size = base.marker.size_m
    for draw in range(1, dist.max_draws + 1):
        position = (
            float(rng.uniform(*dist.target_x_m)),
            dist.target_y_m,
            float(rng.uniform(*dist.target_z_m)),
        )
        yaw = float(rng.uniform(-math.pi, math.pi))
        offset = half_ball_offset(rng, dist.max_offset_m)
        turn_rad = math.radians(float(rng.uniform(-dist.max_turn_deg, dist.max_turn_deg)))
        scenario = with_target(base, position, yaw)
        target = kin.target_marker_pose(np.array(position), yaw)
        if not marker_in_image(kin.marker_corners(target, size), scenario):
            redrawn[REDRAW_TARGET_OUTSIDE] += 1
            continue
        start = Start(
            index, name, position, yaw, tuple(float(v) for v in offset),
            math.degrees(turn_rad), None, "", draw, {},
        )  # fmt: skip
        solved = solve_goal(scenario)
        if solved is None:
            refused = "target.position: the hand cannot place its marker on the target"
            return replace(start, refused=refused, redrawn=dict(redrawn))
        q = walk_to_start(scenario, solved[0], solved[1], offset, turn_rad)
        if q is None:
            redrawn[REDRAW_START_OUT_OF_REACH] += 1
            continue
        hand = kin.forward_kinematics(q) @ kin.hand_marker_in_ee()
        if not marker_in_image(kin.marker_corners(hand, size), scenario):
            redrawn[REDRAW_HAND_OUTSIDE] += 1
            continue
        if view_angle_deg(hand, scenario) > MAX_VIEW_ANGLE_DEG:
            redrawn[REDRAW_HAND_FACING_AWAY] += 1
            continue
        if arm_hides_hand_marker(q, scenario):
            redrawn[REDRAW_HAND_HIDDEN] += 1
            continue
        if arm_hides_hand_marker(solved[0], scenario):
            redrawn[REDRAW_GOAL_HIDDEN] += 1
            continue
        q0 = tuple(round(float(v), 6) for v in q)
        try:
            check_scenario(with_q0(scenario, q0))
            refused = ""
        except ArmInsideScenery:
            redrawn[REDRAW_ARM_INSIDE] += 1
            continue
        except ScenarioError as exc:
            refused = str(exc)
        stability = None if refused else goal_stability_of(scenario)
        return replace(
            start,
            q0_rad=q0,
            refused=refused,
            redrawn=dict(redrawn),
            constant_goal_stability=stability,
        )
    return Start(
        index, name, (0.0, 0.0, 0.0), 0.0, (0.0, 0.0, 0.0), 0.0, None,
        f"no start drawn in {dist.max_draws} draws", dist.max_draws, dict(redrawn),
    )  # fmt: skip
