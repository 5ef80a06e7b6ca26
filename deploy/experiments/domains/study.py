"""Convergence domains: the grid of large initial displacements and its draws. Pure.

A study is defined in a TOML file (``deploy/domains/study.toml``, documented there): the grid
of cells (rotation of the hand marker about the camera's optical axis × distance across the
line of sight × depth change along it), the draws per cell and the seed. Draw ``d`` of cell
``c`` comes from its own generator, ``default_rng([seed, c, d])``: the same seed gives the
same grid and the same starts whatever the grid's size or the order the runs are scheduled
in. A start no motion can reach or the camera cannot see is refused with its reason (the
checks of :mod:`~deploy.experiments.campaign.starts` and :mod:`~deploy.launch.reachability`);
every other start is run with every strategy (:class:`RunTask`, a plain picklable value any
executor can ship).

Every run is judged into one :class:`DomainRecord` with one named cause
(:func:`deploy.experiments.campaign.causes.failure_cause`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from common import kinematics as kin
from common.config import Scenario, ScenarioError, load_scenario
from common.runtime import parse_overrides
from deploy.experiments.campaign.causes import failure_cause
from deploy.experiments.campaign.starts import (
    REDRAW_ARM_INSIDE,
    REDRAW_GOAL_HIDDEN,
    REDRAW_HAND_FACING_AWAY,
    REDRAW_HAND_HIDDEN,
    REDRAW_HAND_OUTSIDE,
    REDRAW_START_OUT_OF_REACH,
    REDRAW_TARGET_OUTSIDE,
    load_definition,
    start_overrides,
    walk_to_start,
    with_q0,
    with_target,
)
from deploy.experiments.compare import CompareError
from deploy.experiments.compare.plan import job_overrides
from deploy.experiments.compare.rows import CompareRow, is_on_goal
from deploy.launch.evaluate import RunResult
from deploy.launch.reachability import (
    MAX_VIEW_ANGLE_DEG,
    ArmInsideScenery,
    arm_hides_hand_marker,
    check_scenario,
    marker_in_image,
    solve_goal,
    view_angle_deg,
)

DEFAULT_STUDY = Path(__file__).resolve().parents[2] / "domains" / "study.toml"
# The hand marker's centre must start at least this far above the target marker: lower, the
# hand is in the target's block (its top is the target marker) or on its way into it.
BLOCK_CLEARANCE_M = 0.01
REFUSED_TARGET_OUTSIDE = REDRAW_TARGET_OUTSIDE
REFUSED_BELOW_BLOCK = "hand marker below the target's top at start (inside its block)"
REFUSED_GOAL_OUT_OF_REACH = "target.position: the hand cannot place its marker on the target"
# The hand marker is a plain square: vision labels its corners from the top-left one at first
# sight (services/vision/quad.py), so the image sees a turn modulo 90°, in (-45°, 45°].
SQUARE_SYMMETRY_DEG = 90.0


class StudyDefinition(BaseModel):
    """A convergence-domain study (see ``deploy/domains/study.toml``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    seed: int = Field(ge=0)
    base_scenario: str
    rotations_deg: tuple[float, ...] = Field(min_length=1)
    distances_m: tuple[float, ...] = Field(min_length=1)
    depths_m: tuple[float, ...] = Field(min_length=1)
    draws: int = Field(ge=1, le=1000)
    target_x_m: tuple[float, float]
    target_z_m: tuple[float, float]
    target_yaw_deg: tuple[float, float]
    # The goal's posture: inverse kinematics for the goal starts here, so every draw's goal is
    # on this elbow and wrist branch (the one with room to turn the hand, see study.toml).
    goal_seed_q_deg: tuple[float, float, float, float, float, float]
    turn_signs: tuple[int, ...] = (1, -1)  # the rotation's sign is drawn among these
    fixed_distance_m: float
    success_goal: float = Field(0.95, gt=0.0, le=1.0)
    timeout_s: float = Field(gt=0.0, le=3600.0)
    overrides: tuple[str, ...] = ()  # scenario overrides for every run (before --set's)

    @model_validator(mode="after")
    def _grid(self) -> StudyDefinition:
        if any(not 0.0 <= r <= 180.0 for r in self.rotations_deg):
            raise ValueError("rotations_deg: each in [0, 180]")
        if any(not 0.0 <= d <= 0.5 for d in self.distances_m):
            raise ValueError("distances_m: each in [0, 0.5]")
        if any(abs(z) > 0.3 for z in self.depths_m):
            raise ValueError("depths_m: each within ±0.3")
        for name in ("rotations_deg", "distances_m", "depths_m"):
            values = getattr(self, name)
            if list(values) != sorted(set(values)):
                raise ValueError(f"{name}: increasing, without repeats")
        if not self.turn_signs or set(self.turn_signs) - {1, -1}:
            raise ValueError("turn_signs: 1, -1 or both")
        if not -180.0 <= self.target_yaw_deg[0] <= self.target_yaw_deg[1] <= 180.0:
            raise ValueError("target_yaw_deg: [low, high] within ±180")
        if self.fixed_distance_m not in self.distances_m:
            raise ValueError("fixed_distance_m: must be one of distances_m")
        return self

    @property
    def n_cells(self) -> int:
        return len(self.rotations_deg) * len(self.distances_m) * len(self.depths_m)


def load_study(path: Path, **changes: object) -> tuple[StudyDefinition, Path]:
    """The study (``changes``: fields replaced, e.g. ``seed`` or ``draws`` from the command
    line) and the absolute path of its base scenario; raises CompareError."""
    return load_definition(path, StudyDefinition, "--study", changes)


@dataclass(frozen=True)
class Cell:
    index: int
    rotation_deg: float
    distance_m: float
    depth_m: float


def cells(study: StudyDefinition) -> list[Cell]:
    """Every cell, rotation-major (then distance, then depth): its index seeds its draws."""
    grid = itertools.product(study.rotations_deg, study.distances_m, study.depths_m)
    return [Cell(i, r, d, z) for i, (r, d, z) in enumerate(grid)]


class DomainStart(BaseModel):
    """One draw of one cell: the target, the hand's displacement from its goal, the joint
    angles that put it there, and ``refused`` (why no motion could start from it; "" to run)."""

    model_config = ConfigDict(frozen=True)
    name: str
    cell: int
    draw: int
    rotation_deg: float  # the cell's, unsigned
    distance_m: float
    depth_m: float
    turn_deg: float  # signed: the rotation about the optical axis actually applied
    image_turn_deg: float  # what the image sees of it: modulo the square's 90°, (-45, 45]
    direction_rad: float  # of the lateral move, in the image plane (0: image right, +v down)
    offset_m: tuple[float, float, float]  # the hand marker from its goal, base frame
    target_position_m: tuple[float, float, float]
    target_yaw_rad: float
    q0_rad: tuple[float, ...] | None
    refused: str

    def overrides(self) -> tuple[str, ...]:
        """The scenario overrides that make the study's base scenario this start."""
        assert self.q0_rad is not None
        return start_overrides(self.name, self.q0_rad, self.target_position_m, self.target_yaw_rad)


def image_turn_deg(turn_deg: float) -> float:
    """The turn the image sees of a square turned by ``turn_deg``: within (-45°, 45°]."""
    wrapped = math.remainder(turn_deg, SQUARE_SYMMETRY_DEG)
    return 45.0 if wrapped == -45.0 else wrapped


def lateral_direction(camera_pose: np.ndarray, angle_rad: float) -> tuple[np.ndarray, float]:
    """A unit vector across the line of sight at ``angle_rad`` in the image plane (0: image
    right, π/2: image down), turned half a circle when it would lower the hand; the vector and
    the angle used."""
    ex, ey = camera_pose[:3, 0], camera_pose[:3, 1]
    direction = math.cos(angle_rad) * ex + math.sin(angle_rad) * ey
    if direction[1] < 0.0:  # base y is up
        direction, angle_rad = -direction, angle_rad + math.pi
    return direction, math.remainder(angle_rad, 2.0 * math.pi)


def start_name(cell: int, draw: int) -> str:
    return f"c{cell:04d}_d{draw:02d}"


def draw_domain_start(study: StudyDefinition, base: Scenario, cell: Cell, draw: int) -> DomainStart:
    """Draw ``draw`` of ``cell`` (see the module doc): one draw, refused with the first reason
    that applies, never drawn again."""
    rng = np.random.default_rng([study.seed, cell.index, draw])
    position = (
        float(rng.uniform(*study.target_x_m)),
        float(base.target.position[1]),
        float(rng.uniform(*study.target_z_m)),
    )
    yaw = math.radians(float(rng.uniform(*study.target_yaw_deg)))
    sign = float(study.turn_signs[int(rng.integers(len(study.turn_signs)))])
    scenario = with_target(base, position, yaw)
    camera = scenario.camera.pose()
    direction, angle = lateral_direction(camera, float(rng.uniform(0.0, 2.0 * math.pi)))
    offset = cell.distance_m * direction + cell.depth_m * camera[:3, 2]
    turn = sign * cell.rotation_deg
    start = DomainStart(
        name=start_name(cell.index, draw), cell=cell.index, draw=draw,
        rotation_deg=cell.rotation_deg, distance_m=cell.distance_m, depth_m=cell.depth_m,
        turn_deg=turn, image_turn_deg=image_turn_deg(turn), direction_rad=angle,
        offset_m=tuple(float(v) for v in offset), target_position_m=position,
        target_yaw_rad=yaw, q0_rad=None, refused="",
    )  # fmt: skip

    def refuse(reason: str, q: np.ndarray | None = None) -> DomainStart:
        q0 = None if q is None else tuple(round(float(v), 6) for v in q)
        return start.model_copy(update={"refused": reason, "q0_rad": q0})

    size = base.marker.size_m
    target = kin.target_marker_pose(np.array(position), yaw)
    if not marker_in_image(kin.marker_corners(target, size), scenario):
        return refuse(REFUSED_TARGET_OUTSIDE)
    if offset[1] < BLOCK_CLEARANCE_M - scenario.target.approach_height_m:
        return refuse(REFUSED_BELOW_BLOCK)
    solved = solve_goal(with_q0(scenario, np.radians(study.goal_seed_q_deg)))
    if solved is None:
        return refuse(REFUSED_GOAL_OUT_OF_REACH)
    q = walk_to_start(scenario, solved[0], solved[1], offset, math.radians(turn))
    if q is None:
        return refuse(REDRAW_START_OUT_OF_REACH)
    hand = kin.forward_kinematics(q) @ kin.hand_marker_in_ee()
    if not marker_in_image(kin.marker_corners(hand, size), scenario):
        return refuse(REDRAW_HAND_OUTSIDE, q)
    if view_angle_deg(hand, scenario) > MAX_VIEW_ANGLE_DEG:
        return refuse(REDRAW_HAND_FACING_AWAY, q)
    if arm_hides_hand_marker(q, scenario):
        return refuse(REDRAW_HAND_HIDDEN, q)
    if arm_hides_hand_marker(solved[0], scenario):
        return refuse(REDRAW_GOAL_HIDDEN, q)
    q0 = tuple(round(float(v), 6) for v in q)
    try:
        check_scenario(with_q0(scenario, q0))
    except ArmInsideScenery:
        return refuse(REDRAW_ARM_INSIDE, q)
    except ScenarioError as exc:
        return refuse(str(exc), q)
    return start.model_copy(update={"q0_rad": q0})


def draw_starts(study: StudyDefinition, base: Scenario) -> list[DomainStart]:
    """Every draw of every cell, cell-major."""
    return [draw_domain_start(study, base, c, d) for c in cells(study) for d in range(study.draws)]


# --- runs ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RunTask:
    """One (start, strategy) run as plain data: the base scenario's file and the overrides
    that make it the start. Picklable and small, so any executor can ship it to any worker;
    ``key`` names the run (and its Zenoh key prefix in a distributed pipeline)."""

    key: str
    start: str
    mode: str
    scenario_path: str
    overrides: tuple[str, ...]

    def scenario(self) -> Scenario:
        return load_scenario(self.scenario_path, parse_overrides(list(self.overrides)))


def run_key(start: str, mode: str) -> str:
    return f"{start}_{mode}"


def study_overrides(study: StudyDefinition, overrides: Sequence[str] = ()) -> list[str]:
    """What every run of the study adds to its start: its timeout, the study's own overrides,
    then ``overrides`` (the command line's ``--set``)."""
    return [f"run.timeout_s={study.timeout_s!r}", *study.overrides, *overrides]


def check_overrides(
    study: StudyDefinition, base_path: Path, modes: Sequence[str], overrides: Sequence[str] = ()
) -> None:
    """The base scenario with what every run adds (the study's overrides, ``overrides``: the
    command line's ``--set``, the strategy) validated: raises :class:`CompareError` naming the
    option and the field. Cheap, so a study checks its input with it before anything is drawn
    or written (a worker would only find it drawing)."""
    checks = [("--study overrides", study_overrides(study))]
    checks += [("--set", study_overrides(study, overrides))] if overrides else []
    checks += [(f"--modes {m}", job_overrides(study_overrides(study, overrides), m)) for m in modes]
    for option, items in checks:
        try:
            load_scenario(base_path, parse_overrides(list(items)))
        except ScenarioError as exc:
            raise CompareError(f"{option}: {exc}") from exc


def plan_tasks(
    study: StudyDefinition,
    base_path: Path,
    starts: Sequence[DomainStart],
    modes: Sequence[str],
    overrides: Sequence[str] = (),
) -> list[RunTask]:
    """Every strategy on every start that was not refused, start-major; each validated."""
    tasks = []
    added = study_overrides(study, overrides)
    for start in starts:
        if start.refused:
            continue
        for mode in modes:
            items = job_overrides([*start.overrides(), *added], mode)
            task = RunTask(run_key(start.name, mode), start.name, mode, str(base_path), items)
            try:
                task.scenario()
            except ScenarioError as exc:
                raise CompareError(f"{start.name}: {exc}") from exc
            tasks.append(task)
    return tasks


class DomainRecord(BaseModel):
    """One run of the study: which start and strategy, its outcome and one named cause, and
    the run's full result (ground truth used to judge only)."""

    key: str
    start: str
    mode: str
    outcome: str  # "converged" (on its goal) or "failed"
    cause: str  # deploy.experiments.campaign.causes.failure_cause
    frames: int
    final_pixel_rms: float | None
    final_position_error_m: float | None
    result: RunResult


def judge(task: RunTask, result: RunResult) -> DomainRecord:
    """The record of a run: its cause from the campaign's taxonomy."""
    row = CompareRow(
        **result.model_dump(),
        on_goal=is_on_goal(result),
        scenario_file=Path(task.scenario_path).name,
        moving_target=False,
    )
    cause = failure_cause(row)
    return DomainRecord(
        key=task.key,
        start=task.start,
        mode=task.mode,
        outcome="converged" if cause == "converged" else "failed",
        cause=cause,
        frames=result.frames,
        final_pixel_rms=result.final_pixel_rms,
        final_position_error_m=result.final_position_error_m,
        result=result,
    )


def record_without_wall_time(record: DomainRecord) -> dict:
    """What two runs of the same study must agree on: everything but the wall time."""
    data = record.model_dump()
    data["result"].pop("wall_time_s")
    return data


def study_differences(a: Sequence[DomainRecord], b: Sequence[DomainRecord]) -> list[str]:
    """Runs only in one, and runs whose records differ (wall time aside)."""
    left = {r.key: record_without_wall_time(r) for r in a}
    right = {r.key: record_without_wall_time(r) for r in b}
    out = [f"{k}: only in the first" for k in left.keys() - right.keys()]
    out += [f"{k}: only in the second" for k in right.keys() - left.keys()]
    out += [f"{k}: differs" for k in left.keys() & right.keys() if left[k] != right[k]]
    return sorted(out)
