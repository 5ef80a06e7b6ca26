"""Convergence-domain study, the pure parts: the grid and its seeded draws, refusals, tasks,
the judged records, and the report (tables, the largest rotation, heat maps) from a small
study."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from common import kinematics as kin
from common.config import load_scenario
from deploy.experiments.campaign.starts import rotation_about
from deploy.experiments.compare import CompareError
from deploy.experiments.domains.report import (
    Study,
    bands_table,
    cell_stats,
    largest_rotation_deg,
    report_markdown,
    summary_table,
    write_heatmaps,
)
from deploy.experiments.domains.study import (
    DEFAULT_STUDY,
    REFUSED_BELOW_BLOCK,
    REFUSED_TARGET_OUTSIDE,
    Cell,
    DomainStart,
    cells,
    draw_domain_start,
    image_turn_deg,
    judge,
    lateral_direction,
    load_study,
    plan_tasks,
    study_differences,
)
from deploy.launch.evaluate import RunResult
from deploy.launch.reachability import goal_pose, square_turns

STUDY, BASE_PATH = load_study(DEFAULT_STUDY)
BASE = load_scenario(BASE_PATH)


def test_the_published_grid_reaches_180_degrees_in_15_degree_steps() -> None:
    assert STUDY.rotations_deg[0] == 0.0 and STUDY.rotations_deg[-1] == 180.0
    assert max(np.diff(STUDY.rotations_deg)) <= 15.0
    grid = cells(STUDY)
    assert len(grid) == STUDY.n_cells == 13 * len(STUDY.distances_m) * len(STUDY.depths_m)
    assert [c.index for c in grid] == list(range(len(grid)))
    assert len({(c.rotation_deg, c.distance_m, c.depth_m) for c in grid}) == len(grid)
    # At least 2,000 runs of five strategies could be drawn.
    assert STUDY.n_cells * STUDY.draws * 5 >= 2000


def test_a_draw_depends_on_the_seed_cell_and_draw_only() -> None:
    cell = cells(STUDY)[3 * 9 + 4]  # 45°, 3 cm, level
    a = draw_domain_start(STUDY, BASE, cell, 1)
    assert draw_domain_start(STUDY, BASE, cell, 1) == a
    assert draw_domain_start(STUDY, BASE, cell, 0) != a
    reseeded = STUDY.model_copy(update={"seed": STUDY.seed + 1})
    assert draw_domain_start(reseeded, BASE, cell, 1) != a
    # A smaller grid keeps the draws of its cells: a draw is seeded by the cell's index only.
    smaller = STUDY.model_copy(update={"draws": 2})
    assert draw_domain_start(smaller, BASE, cell, 1) == a


def test_a_start_is_its_goal_turned_about_the_optical_axis_and_moved() -> None:
    checked = 0
    for index, draw in [(3 * 9 + 4, 0), (1 * 9 + 7, 1), (2 * 9 + 1, 2), (12 * 9 + 4, 0)]:
        cell = cells(STUDY)[index]
        s = draw_domain_start(STUDY, BASE, cell, draw)
        assert abs(s.turn_deg) == cell.rotation_deg
        assert s.turn_deg == 0.0 or math.copysign(1, s.turn_deg) in STUDY.turn_signs
        assert abs(image_turn_deg(s.turn_deg)) <= 45.0
        scenario = BASE.model_copy(
            update={
                "target": BASE.target.model_copy(
                    update={"position": list(s.target_position_m), "yaw": s.target_yaw_rad}
                )
            }
        )
        camera = scenario.camera.pose()
        offset = np.array(s.offset_m)
        # Distance across the line of sight, depth along it, never lowering the hand.
        assert offset @ camera[:3, 2] == pytest.approx(cell.depth_m, abs=1e-9)
        across = offset - (offset @ camera[:3, 2]) * camera[:3, 2]
        assert np.linalg.norm(across) == pytest.approx(cell.distance_m, abs=1e-9)
        assert across[1] >= -1e-12
        assert STUDY.target_x_m[0] <= s.target_position_m[0] <= STUDY.target_x_m[1]
        lo, hi = STUDY.target_yaw_deg
        assert lo <= math.degrees(s.target_yaw_rad) <= hi
        if s.q0_rad is None:  # refused before a posture was walked to
            continue
        hand = kin.forward_kinematics(np.array(s.q0_rad)) @ kin.hand_marker_in_ee()
        goals = square_turns(goal_pose(scenario))
        assert np.allclose(hand[:3, 3], goals[0][:3, 3] + offset, atol=1e-4)
        turned = [
            rotation_about(camera[:3, 2], math.radians(s.turn_deg)) @ g[:3, :3] for g in goals
        ]
        assert min(kin.rotation_error_rad(hand[:3, :3], r) for r in turned) < 1e-3
        checked += 1
    assert checked >= 2


def test_image_turn_is_modulo_the_squares_quarter_turn() -> None:
    assert [image_turn_deg(t) for t in (0, 15, 45, 60, 90, 135, 150, 180, -45, -60)] == [
        0, 15, 45, -30, 0, 45, -30, 0, 45, 30,
    ]  # fmt: skip


def test_the_lateral_direction_never_lowers_the_hand() -> None:
    camera = BASE.camera.pose()
    for angle in np.linspace(0.0, 2 * math.pi, 17):
        direction, used = lateral_direction(camera, float(angle))
        assert direction[1] >= 0.0
        assert abs(direction @ camera[:3, 2]) < 1e-12 and np.linalg.norm(
            direction
        ) == pytest.approx(1.0)
        assert direction == pytest.approx(
            math.cos(used) * camera[:3, 0] + math.sin(used) * camera[:3, 1]
        )


def test_refusals_name_their_reason() -> None:
    into_block = draw_domain_start(STUDY, BASE, Cell(0, 0.0, 0.0, 0.2), 0)
    assert into_block.refused == REFUSED_BELOW_BLOCK and into_block.q0_rad is None
    far = STUDY.model_copy(update={"target_x_m": (0.9, 1.0)})
    assert draw_domain_start(far, BASE, Cell(0, 0.0, 0.0, 0.0), 0).refused == (
        REFUSED_TARGET_OUTSIDE
    )
    # A start the arm cannot turn to: its reason is the walk's, and it is not run.
    refusals = {
        draw_domain_start(STUDY, BASE, Cell(9, 180.0, 0.15, 0.03), d).refused for d in (0, 1)
    }
    assert all(refusals)


def test_tasks_rebuild_each_runnable_start_with_every_strategy() -> None:
    good = draw_domain_start(STUDY, BASE, cells(STUDY)[1], 0)
    assert not good.refused
    bad = draw_domain_start(STUDY, BASE, Cell(0, 0.0, 0.0, 0.2), 0)
    tasks = plan_tasks(STUDY, BASE_PATH, [good, bad], ["dynamic", "mpj"])
    assert [t.key for t in tasks] == [f"{good.name}_dynamic", f"{good.name}_mpj"]
    scenario = tasks[1].scenario()
    assert tuple(scenario.robot.q0) == good.q0_rad
    assert scenario.controller.mode.value == "mpj"
    assert scenario.run.timeout_s == STUDY.timeout_s
    assert scenario.name == good.name
    # The study's own overrides reach every run (the orientation cue, once on main).
    changed = STUDY.model_copy(update={"overrides": ("camera.rgb_hz=10.0",)})
    again = plan_tasks(changed, BASE_PATH, [good], ["dynamic"])[0].scenario()
    assert again.camera.rgb_hz == 10.0 and scenario.camera.rgb_hz != 10.0


def test_a_bad_study_file_is_refused(tmp_path: Path) -> None:
    with pytest.raises(CompareError, match="turn_signs"):
        load_study(DEFAULT_STUDY, turn_signs=[2])
    text = DEFAULT_STUDY.read_text().replace("fixed_distance_m = 0.03", "fixed_distance_m = 0.07")
    (tmp_path / "s.toml").write_text(text)
    with pytest.raises(CompareError, match="fixed_distance_m"):
        load_study(tmp_path / "s.toml")


# --- records and the report --------------------------------------------------------------------
def result(mode: str, converged: bool, **fields) -> RunResult:
    base = dict(
        scenario="c", mode=mode, clock="lockstep", converged=converged,
        reason="converged" if converged else "timeout", frames=90, sim_time_s=6.0,
        wall_time_s=1.0, final_pixel_rms=0.2, final_position_error_m=0.001 if converged else 0.04,
        final_orientation_error_deg=0.1, path_length_m=0.1, min_manipulability=0.01,
        final_joint_margin_deg=30.0, final_hand_border_px=40.0,
        detail="" if converged else "15 s simulated; still servoing",
    )  # fmt: skip
    base.update(fields)
    return RunResult(**base)


def start(cell: int, draw: int, rotation: float, distance: float, refused: str = "") -> DomainStart:
    return DomainStart(
        name=f"c{cell:04d}_d{draw:02d}", cell=cell, draw=draw, rotation_deg=rotation,
        distance_m=distance, depth_m=0.0, turn_deg=rotation, image_turn_deg=0.0,
        direction_rad=0.0, offset_m=(0.0, 0.0, 0.0), target_position_m=(0.28, -0.32, 0.08),
        target_yaw_rad=0.0, q0_rad=None if refused else (0.0,) * 6, refused=refused,
    )  # fmt: skip


def small_study() -> Study:
    """Two strategies over rotations 0, 15, 30 at 5 cm (2 draws each) and 0 at 10 cm: dynamic
    fails once at 15° (joint limit), mpj at 30° twice (local minimum, marker left the image);
    30° at 10 cm is refused."""
    study = STUDY.model_copy(
        update={
            "rotations_deg": (0.0, 15.0, 30.0),
            "distances_m": (0.05, 0.10),
            "depths_m": (0.0,),
            "fixed_distance_m": 0.05,
        }
    )
    starts = [start(i * 2 + 0, d, r, 0.05) for i, r in enumerate((0.0, 15.0, 30.0)) for d in (0, 1)]
    starts += [start(1, 0, 0.0, 0.10), start(5, 0, 30.0, 0.10, refused="start pose out of reach")]
    outcomes = {
        ("c0002_d00", "dynamic"): result("dynamic", False, final_joint_margin_deg=2.0),
        ("c0004_d00", "mpj"): result("mpj", True, final_position_error_m=0.02),
        ("c0004_d01", "mpj"): result("mpj", False, reason="stuck", final_hand_border_px=-3.0,
                                     detail="held 4.00 s waiting for: hand partial"),
    }  # fmt: skip
    runs = []
    for s in starts:
        if s.refused:
            continue
        for mode in ("dynamic", "mpj"):
            r = outcomes.get((s.name, mode), result(mode, True))
            from deploy.experiments.domains.study import RunTask

            runs.append(judge(RunTask(f"{s.name}_{mode}", s.name, mode, "x.toml", ()), r))
    return Study(
        study=study, study_file="study.toml", modes=["dynamic", "mpj"], pipeline="inprocess",
        executor="--jobs 2", wall_time_s=60.0, complete=True, starts=starts, runs=runs,
    )  # fmt: skip


def test_records_carry_one_named_cause() -> None:
    study = small_study()
    causes = {r.key: r.cause for r in study.runs if r.outcome == "failed"}
    assert causes == {
        "c0002_d00_dynamic": "joint limit",
        "c0004_d00_mpj": "local minimum",
        "c0004_d01_mpj": "marker left the image",
    }


def test_the_report_counts_cells_bands_and_the_largest_rotation(tmp_path: Path) -> None:
    study = small_study()
    assert largest_rotation_deg(study, "mpj") == 15.0
    assert largest_rotation_deg(study, "dynamic") == 0.0  # 15° at 5 cm: 1 of 2
    stats = {(c.rotation_deg, c.distance_m): c for c in cell_stats(study, "mpj")}
    assert (stats[30.0, 0.05].runs, stats[30.0, 0.05].converged) == (2, 0)
    assert stats[30.0, 0.05].dominant in ("L", "O")
    assert (stats[30.0, 0.10].runs, stats[30.0, 0.10].refused) == (0, 1)
    table = summary_table(study)
    assert "| dynamic | 7 | 86% (6/7) | 0° | 0 | 0 | 1 |" in table
    assert "| mpj | 7 | 71% (5/7) | 15° | 1 | 1 | 0 |" in table
    bands = bands_table(study)
    assert "| mpj | 71% (5/7) | 67% (4/6) | 100% (1/1) | 71% (5/7) |" in bands
    figures = write_heatmaps(study, tmp_path)
    assert [p.name for p in figures] == ["domain_dynamic.png", "domain_mpj.png"]
    assert all(p.stat().st_size > 10_000 for p in figures)
    md = report_markdown(study, ["figures/domain_mpj.png"], {"c0004_d00_mpj": "rec/x.mcap"})
    assert "[recording](rec/x.mcap)" in md and "start pose out of reach | 1" in md


def test_study_differences_ignore_only_the_wall_time() -> None:
    a = small_study().runs
    b = [
        r.model_copy(update={"result": r.result.model_copy(update={"wall_time_s": 9.0})}) for r in a
    ]
    assert study_differences(a, b) == []
    c = [*b[:-1], b[-1].model_copy(update={"frames": 1})]
    assert study_differences(a, c) == [f"{a[-1].key}: differs"]
    assert study_differences(a, b[:-1]) == [f"{a[-1].key}: only in the first"]


def test_starts_are_drawn_on_the_scenario_the_runs_see() -> None:
    """With the study's orientation cue only the unturned goal is a goal (corner 0 over the
    target's corner 0): the 0° start on the goal must be that one, not a quarter turn of it
    that a plain square would accept and the cue would make a real turn."""
    from common.runtime import parse_overrides
    from deploy.experiments.campaign.starts import with_target
    from deploy.experiments.domains.run import draw_one

    assert "marker.orientation_cue=true" in STUDY.overrides
    cell = next(c for c in cells(STUDY) if (c.rotation_deg, c.distance_m, c.depth_m) == (0, 0, 0))
    start = draw_one(STUDY, str(BASE_PATH), cell, 0)
    assert not start.refused and start.q0_rad is not None
    cued = load_scenario(BASE_PATH, parse_overrides(list(STUDY.overrides)))
    target = with_target(cued, start.target_position_m, start.target_yaw_rad)
    hand = kin.forward_kinematics(np.array(start.q0_rad)) @ kin.hand_marker_in_ee()
    assert kin.rotation_error_rad(hand[:3, :3], goal_pose(target)[:3, :3]) < 1e-3


def test_every_published_goal_holds_for_constants_frozen_matrix() -> None:
    """What docs/domains.md says: no goal of the study is one the constant strategy's frozen
    matrix makes unstable (some of the random starts' goals are)."""
    import json

    from deploy.experiments.campaign.starts import with_target
    from deploy.launch.goal_stability import goal_stability_of

    study = json.loads(
        (Path(__file__).resolve().parents[2] / "docs/domains/domains.json").read_text()
    )
    runnable = [s for s in study["starts"] if not s["refused"]]
    assert len(runnable) > 100
    assert BASE.controller.constant_depth == "single"  # the thesis's: what can leave a goal
    for s in runnable:
        placed = with_target(BASE, s["target_position_m"], s["target_yaw_rad"])
        assert goal_stability_of(placed) > 0.0, s["name"]
