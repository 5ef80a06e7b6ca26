"""``umay campaign``: every strategy from random starts, and why each failure failed.

The suite's starts were chosen by hand; a campaign draws them from a distribution kept in the
repository (``deploy/campaigns/random_starts.toml``, documented there): targets anywhere on
the table within the image at any yaw, the hand up to 15 cm from its goal and turned up to 45°
about the optical axis, overlap with the target allowed. Each start runs with every strategy
through :mod:`deploy.experiments.compare`'s machinery (one lockstep pipeline per run,
results.json/csv, summary.md, figures), and every run that does not end on its goal gets
exactly one named cause (:func:`failure_cause`); starts the pre-launch check refuses are
counted with its reason.

Functional core (pure): :class:`Distribution`, :func:`draw_start` (a start from its own
generator, ``default_rng([seed, i])``: the same starts whatever N), :func:`failure_cause`,
:func:`taxonomy_markdown`. Imperative shell: :func:`plan_campaign`, :func:`run_campaign`.
"""

from __future__ import annotations

import json
import math
import tomllib
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, replace
from functools import partial
from pathlib import Path
from typing import TypeVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from common import kinematics as kin
from common.config import Scenario, ScenarioError, load_scenario
from common.runtime import parse_overrides
from deploy.experiments.compare import CompareError
from deploy.experiments.compare.plan import Job, Plan, job_overrides
from deploy.experiments.compare.rows import ON_GOAL_M, CompareRow
from deploy.experiments.compare.summary import format_cell, markdown_table
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
DEFAULT_DISTRIBUTION = Path(__file__).resolve().parents[1] / "campaigns" / "random_starts.toml"
IK_STEPS = 20  # the start is reached from the goal in this many small IK moves
# A run that failed with a joint this near its limit failed on it: the actuation slows a joint
# linearly inside its last 10° (services/actuation/inverse.py), so the servo's last pixels
# there take many seconds (at 2° from the limit, a fifth of the speed).
JOINT_LIMIT_MARGIN_DEG = 10.0
HAND_OUT_PX = 1.0  # a hand marker corner this near the border (or beyond) has left the image


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
        return replace(start, q0_rad=q0, refused=refused, redrawn=dict(redrawn))
    return Start(
        index, name, (0.0, 0.0, 0.0), 0.0, (0.0, 0.0, 0.0), 0.0, None,
        f"no start drawn in {dist.max_draws} draws", dist.max_draws, dict(redrawn),
    )  # fmt: skip


# --- planning -------------------------------------------------------------------------------
@dataclass(frozen=True)
class CampaignPlan:
    plan: Plan
    starts: tuple[Start, ...]
    distribution: Distribution
    distribution_path: Path


def _draw_all(
    dist: Distribution, base: Scenario, n: int, jobs: int, on_drawn: Callable[[int], None]
) -> Iterator[Start]:
    """Starts 0 … n-1 in order, drawn by ``jobs`` processes (inverse kinematics and a
    pybullet scene per draw: the slow part of planning a campaign)."""
    if jobs <= 1 or n == 1:
        for i in range(n):
            yield draw_start(dist, base, i)
            on_drawn(i)
        return
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        for i, start in enumerate(pool.map(partial(draw_start, dist, base), range(n))):
            yield start
            on_drawn(i)


def campaign_inputs(
    n: int,
    distribution_path: Path = DEFAULT_DISTRIBUTION,
    seed: int | None = None,
    overrides: Sequence[str] = (),
) -> tuple[Distribution, Path, Scenario]:
    """The distribution (``seed`` instead of its own), its base scenario's path and the base
    scenario with ``overrides``, validated: raises :class:`CompareError` naming the bad
    input. Cheap, so a command checks its input with it before drawing for minutes."""
    if n < 1:
        raise CompareError(f"--n: at least 1 start, not {n}")
    dist, base_path = load_distribution(distribution_path)
    if seed is not None:
        dist = dist.model_copy(update={"seed": seed})
    try:
        base = load_scenario(base_path, parse_overrides(list(overrides)))
    except ScenarioError as exc:
        raise CompareError(str(exc)) from exc
    return dist, base_path, base


def plan_campaign(
    n: int,
    modes: Sequence[str],
    distribution_path: Path = DEFAULT_DISTRIBUTION,
    seed: int | None = None,
    overrides: Sequence[str] = (),
    figures: bool = True,
    jobs: int = 1,
    on_drawn: Callable[[int], None] | None = None,
) -> CampaignPlan:
    """Draw ``n`` starts (``seed`` instead of the distribution's), validate every job.
    ``figures``: the first start's runs are recorded, for the figures (False: none is).
    ``jobs``: worker processes drawing at once (each start comes from its own generator, so
    the same starts whatever ``jobs``); ``on_drawn(i)`` after start ``i``, in order."""
    dist, base_path, base = campaign_inputs(n, distribution_path, seed, overrides)
    starts = tuple(_draw_all(dist, base, n, jobs, on_drawn or (lambda _i: None)))
    jobs: list[Job] = []
    names: list[str] = []
    for start in starts:
        if start.refused:
            continue
        names.append(start.name)
        for mode in modes:
            timeout = () if dist.timeout_s is None else (f"run.timeout_s={dist.timeout_s!r}",)
            items = job_overrides([*start.overrides(), *timeout, *overrides], mode)
            try:
                scenario = load_scenario(base_path, parse_overrides(list(items)))
            except ScenarioError as exc:
                raise CompareError(f"{start.name}: {exc}") from exc
            record = figures and start.name == names[0]
            jobs.append(Job(base_path, scenario, mode, items, record=record))
    figures_start = names[0] if names and figures else ""
    return CampaignPlan(
        Plan(tuple(jobs), tuple(modes), tuple(names), figures_start),
        starts,
        dist,
        distribution_path,
    )


# --- the failure taxonomy ---------------------------------------------------------------------
CAUSES = (
    "converged",
    "refused at start",
    "acquisition failed",
    "collision",
    "stuck",
    "local minimum",
    "joint limit",
    "marker left the image",
    "singularity",
    "timeout",
    "error",
)


def failure_cause(row: CompareRow, manipulability_threshold: float = 0.002) -> str:
    """One named cause per run. ``converged`` (on its goal) or *local minimum* (the image
    error converged, the hand more than 5 mm from its goal; or ``local minimum (image error
    stalled)``: the run ended stalled above the threshold, no limit to blame); *acquisition
    failed*; *error*;
    *collision* with what the arm pressed on (``collision (object)``: it touched the scenery,
    whatever followed, which a servo law cannot undo by itself); a run ended holding: *marker
    left the image* when the hand marker was at or past the image border, else *stuck* with
    what it waited for (from the detail); a run still servoing at its end: *joint limit*
    (a joint inside the actuation's slow-down zone at the end, :data:`JOINT_LIMIT_MARGIN_DEG`),
    *singularity* (least manipulability below the actuation's damping threshold), else
    *local minimum (image error stalled)* or *timeout*. The ground-truth fields judge; nothing
    flows back."""
    if row.converged:
        return "converged" if row.on_goal else "local minimum"
    if row.reason == "acquisition_failed":
        return "acquisition failed"
    if row.reason == "error":
        return "error"
    if row.first_contact_s is not None:
        return f"collision ({row.contact_with or 'scenery'})"
    border = row.final_hand_border_px
    if border is not None and border < HAND_OUT_PX:
        return "marker left the image"
    if row.reason == "stuck":
        return f"stuck ({waited_for(row.detail)})"
    margin = row.final_joint_margin_deg
    if margin is not None and margin < JOINT_LIMIT_MARGIN_DEG:
        return "joint limit"
    if row.min_manipulability is not None and row.min_manipulability < manipulability_threshold:
        return "singularity"
    return "local minimum (image error stalled)" if row.reason == "stalled" else "timeout"


def close_at_end(row: CompareRow) -> bool:
    """The issue's looser criterion: at the run's end the image error under 1 px and the hand
    within 5 mm of its goal, whether or not the controller had declared convergence."""
    pixel, position = row.final_pixel_rms, row.final_position_error_m
    return pixel is not None and position is not None and pixel < 1.0 and position < ON_GOAL_M


def waited_for(detail: str) -> str:
    """``hand partial`` out of a stuck run's detail (see deploy.launch.run_end.stuck_detail)."""
    head = "waiting for: "
    if head not in detail:
        return detail or "?"
    return detail.split(head, 1)[1].split(" (", 1)[0]


def cause_family(cause: str) -> str:
    return cause.split(" (", 1)[0]


class CampaignRow(BaseModel):
    """A run of the campaign and its cause, or a refused start (mode "", no result)."""

    start: str
    mode: str
    cause: str
    detail: str
    frames: int | None = None
    path_ratio: float | None = None


def campaign_rows(starts: Sequence[Start], rows: Sequence[CompareRow], modes: Sequence[str]):
    out = [
        CampaignRow(start=s.name, mode=m, cause="refused at start", detail=s.refused)
        for s in starts
        if s.refused
        for m in modes
    ]
    out += [
        CampaignRow(
            start=r.scenario,
            mode=r.mode,
            cause=failure_cause(r),
            detail=r.detail,
            frames=r.frames,
            path_ratio=r.path_ratio,
        )
        for r in rows
    ]
    return out


def _median(values: Sequence[float | int | None]) -> float | None:
    present = sorted(float(v) for v in values if v is not None)
    if not present:
        return None
    mid = len(present) // 2
    return present[mid] if len(present) % 2 else 0.5 * (present[mid - 1] + present[mid])


def taxonomy_markdown(
    starts: Sequence[Start], rows: Sequence[CompareRow], modes: Sequence[str], dist: Distribution
) -> str:
    """campaign.md: the starts (refused ones with their reasons), per strategy the success
    rate out of the non-refused starts, median frames and path ratio of the successes, the
    runs within 1 px and 5 mm at their end (:func:`close_at_end`), and the count of every
    cause."""
    crows = campaign_rows(starts, rows, modes)
    refused = [s for s in starts if s.refused]
    headers = ["strategy", "runs", "on goal", "success", "median frames", "median path ratio"]
    headers += ["< 1 px, < 5 mm at the end"]
    headers += [c for c in CAUSES if c not in ("converged",)]
    body = []
    for mode in modes:
        mine = [r for r in rows if r.mode == mode]
        ok = [r for r in mine if failure_cause(r) == "converged"]
        counts = Counter(cause_family(r.cause) for r in crows if r.mode == mode)
        cells = [
            mode,
            str(len(mine)),
            str(len(ok)),
            format_cell(len(ok) / len(mine) if mine else None, 100.0, ".1f") + "%",
            format_cell(_median([r.frames for r in ok]), 1.0, ".0f"),
            format_cell(_median([r.path_ratio for r in ok]), 1.0, ".3f"),
            str(sum(close_at_end(r) for r in mine)),
        ]
        cells += [str(counts.get(c, 0)) for c in headers[7:]]
        body.append(cells)
    reasons = Counter(s.refused for s in refused)
    redraws: Counter[str] = Counter()
    for s in starts:
        redraws.update(s.redrawn)
    failures = [r for r in crows if r.cause not in ("converged", "refused at start")]
    parts = [
        "# Random-start campaign",
        "",
        f"{len(starts)} starts drawn (seed {dist.seed}; distribution in the repository, see "
        f"`deploy/campaigns/`): {len(refused)} refused at start "
        f"({format_cell(len(refused) / len(starts), 100.0, '.1f')}%), "
        f"{len(starts) - len(refused)} run with each of {len(modes)} strategies. Success: "
        f"converged (image error below the threshold) with the hand within "
        f"{1000 * ON_GOAL_M:g} mm of its goal (ground truth), out of the non-refused starts. "
        f"Draws: {sum(s.draws for s in starts)} in all; drawn again (not in the distribution): "
        + (", ".join(f"{n} × {why}" for why, n in redraws.most_common()) or "none")
        + ".",
        "",
        "## Per strategy, and every run's cause",
        "",
        markdown_table(headers, body),
        "",
        "## Refused at start",
        "",
    ]
    parts += [f"- {n} × {reason}" for reason, n in reasons.most_common()] or ["None."]
    parts += ["", "## Runs that did not end on their goal", ""]
    parts += [f"- {r.start} · {r.mode}: **{r.cause}**; {r.detail}" for r in failures] or ["None."]
    return "\n".join(parts) + "\n"


def starts_json(starts: Sequence[Start]) -> str:
    return json.dumps([asdict(s) for s in starts], indent=2) + "\n"


def run_campaign(
    cplan: CampaignPlan,
    n_jobs: int,
    out_dir: Path,
    stop,
    on_start,
    on_done,
    pipeline: str = "distributed",
) -> list[CompareRow]:
    from deploy.experiments.compare.run import run_all

    return run_all(cplan.plan.jobs, n_jobs, out_dir, stop, on_start, on_done, pipeline)


def write_campaign(
    cplan: CampaignPlan, rows: Sequence[CompareRow], out_dir: Path, figures, note: str
) -> list[Path]:
    """compare's outputs, plus campaign.md (the taxonomy), causes.json and starts.json."""
    from deploy.experiments.compare.run import write_outputs

    written = write_outputs(cplan.plan, rows, out_dir, figures, note) if rows else []
    modes = cplan.plan.modes
    md = out_dir / "campaign.md"
    md.write_text(taxonomy_markdown(cplan.starts, rows, modes, cplan.distribution))
    causes = out_dir / "causes.json"
    crows = campaign_rows(cplan.starts, rows, modes)
    causes.write_text(json.dumps([r.model_dump() for r in crows], indent=2) + "\n")
    starts = out_dir / "starts.json"
    starts.write_text(starts_json(cplan.starts))
    return [*written, md, causes, starts]
