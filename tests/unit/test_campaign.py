"""Random-start campaigns: the distribution, its seeds, and the failure taxonomy."""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from common import kinematics as kin
from common.config import ConstantDepth, load_scenario
from common.runtime import parse_overrides
from deploy.experiments.campaign.causes import CAUSES, cause_family, failure_cause, waited_for
from deploy.experiments.campaign.report import taxonomy_markdown
from deploy.experiments.campaign.starts import DEFAULT_DISTRIBUTION, draw_start, load_distribution
from deploy.experiments.compare.rows import CompareRow
from deploy.launch.goal_stability import goal_stability_of
from deploy.launch.reachability import (
    check_scenario,
    goal_pose,
    marker_in_image,
    view_angle_deg,
)
from deploy.launch.run import prepare
from services.controller.progress import stall_detail
from services.pipeline import Pipeline
from tests.conftest import CliResult

DIST, BASE_PATH = load_distribution(DEFAULT_DISTRIBUTION)
BASE = load_scenario(BASE_PATH)


def test_each_start_comes_from_its_own_seed_and_lies_in_the_distribution() -> None:
    starts = [draw_start(DIST, BASE, i) for i in range(6)]
    assert draw_start(DIST, BASE, 4) == starts[4]  # the same whatever came before
    other = DIST.model_copy(update={"seed": DIST.seed + 1})
    assert draw_start(other, BASE, 4) != starts[4]
    runnable = 0
    for s in starts:
        assert DIST.target_x_m[0] <= s.target_position_m[0] <= DIST.target_x_m[1]
        assert DIST.target_z_m[0] <= s.target_position_m[2] <= DIST.target_z_m[1]
        assert -np.pi <= s.target_yaw_rad <= np.pi
        assert np.linalg.norm(s.offset_m) <= DIST.max_offset_m and s.offset_m[1] >= 0.0
        assert abs(s.turn_deg) <= DIST.max_turn_deg
        if s.refused:
            assert s.q0_rad is None or s.refused.startswith(("robot.", "target."))
            continue
        runnable += 1
        scenario = BASE.model_copy(
            update={
                "robot": BASE.robot.model_copy(update={"q0": list(s.q0_rad)}),
                "target": BASE.target.model_copy(
                    update={"position": list(s.target_position_m), "yaw": s.target_yaw_rad}
                ),
            }
        )
        check_scenario(scenario)  # runnable: the pre-launch check passes
        hand = kin.forward_kinematics(np.array(s.q0_rad)) @ kin.hand_marker_in_ee()
        assert marker_in_image(kin.marker_corners(hand, BASE.marker.size_m), scenario)
        assert view_angle_deg(hand, scenario) <= 70.0
        # Where IK put it: the offset from the goal (up to the square's 90° turns).
        assert np.allclose(hand[:3, 3] - goal_pose(scenario)[:3, 3], s.offset_m, atol=1e-4)
    assert runnable >= 2, "too few runnable starts to check what a runnable start is"


def row(**fields) -> CompareRow:
    base = dict(
        scenario="start_0001", mode="dynamic", clock="lockstep", converged=False,
        reason="timeout", frames=100, sim_time_s=10.0, wall_time_s=5.0, final_pixel_rms=None,
        final_position_error_m=0.05, final_orientation_error_deg=3.0, path_length_m=0.1,
        min_manipulability=0.01, final_joint_margin_deg=20.0, final_hand_border_px=50.0,
        detail="20 s simulated; still servoing", on_goal=False, scenario_file="x.toml",
        moving_target=False,
    )  # fmt: skip
    base.update(fields)
    return CompareRow(**base)


@pytest.mark.parametrize(
    "fields, cause",
    [
        ({"converged": True, "reason": "converged", "on_goal": True}, "converged"),
        ({"converged": True, "reason": "converged", "on_goal": False}, "local minimum"),
        ({"reason": "acquisition_failed"}, "acquisition failed"),
        ({"reason": "stuck", "final_hand_border_px": -2.0}, "marker left the image"),
        ({"final_joint_margin_deg": 4.0}, "joint limit"),
        (  # holding, not servoing: the hold is the cause, whatever the joints
            {
                "reason": "stuck",
                "detail": "waiting for: hand partial (",
                "final_joint_margin_deg": 4.0,
            },
            "stuck (hand partial)",
        ),
        ({"min_manipulability": 0.0005}, "singularity"),
        (
            {"reason": "stuck", "detail": "held 4.00 s waiting for: hand partial (holding ...)"},
            "stuck (hand partial)",
        ),
        ({}, "timeout"),
        ({"reason": "stalled"}, "local minimum (image error stalled)"),
        (  # the law would lower the hand onto the object; the clearance held it
            {"reason": "stalled", "detail": stall_detail(22.7, 13.5, 1.5, 6.5, 0.0)},
            "local minimum (against the clearance)",
        ),
        ({"reason": "stalled", "final_joint_margin_deg": 4.0}, "joint limit"),  # a limit blamed
        ({"reason": "error", "detail": "service exited"}, "error"),
        (  # the arm pressed on the object: named so whatever it led to (here a joint limit)
            {"first_contact_s": 1.6, "contact_with": "object", "final_joint_margin_deg": -10.0},
            "collision (object)",
        ),
    ],
)
def test_every_failure_gets_one_named_cause(fields: dict, cause: str) -> None:
    assert failure_cause(row(**fields)) == cause
    assert cause_family(cause) in CAUSES


def test_waited_for_reads_the_stuck_detail() -> None:
    assert waited_for("held 4.03 s waiting for: target partial (holding since 0.00 s)") == (
        "target partial"
    )


def test_taxonomy_counts_every_start_and_run() -> None:
    starts = [draw_start(DIST, BASE, i) for i in range(3)]
    rows = [
        row(scenario=s.name, mode=m, converged=True, reason="converged", on_goal=True)
        for s in starts
        if not s.refused
        for m in ("dynamic", "mpj")
    ]
    md = taxonomy_markdown(starts, rows, ("dynamic", "mpj"), DIST)
    ok = sum(not s.refused for s in starts)
    low = 100.0 * ok / (ok + 1.959964**2)  # Wilson's lower bound of n out of n: n / (n + z²)
    assert f"| dynamic | {ok} | {ok} | 100.0% | {low:.1f}–100.0% |" in md
    assert f"{len(starts)} starts drawn (seed {DIST.seed}" in md
    stabilities = [s.constant_goal_stability for s in starts if not s.refused]
    assert all(v is not None and v > 0.0 for v in stabilities)  # starts 0–2: constant holds
    assert f"0 of the {ok} goals run are unstable under the constant strategy's" in md
    assert "| dynamic | " + f"{ok}/{ok} (100.0%) | – |" in md


def test_the_first_starts_runs_are_recorded_for_the_figures_unless_none_are_wanted(
    tmp_path: Path,
) -> None:
    from deploy.experiments.campaign.run import plan_campaign
    from deploy.experiments.compare.run import make_figures

    with_figures = plan_campaign(2, ["dynamic", "mpj"])
    first = next(s.name for s in with_figures.starts if not s.refused)
    recorded = [(j.scenario.name, j.mode) for j in with_figures.plan.jobs if j.record]
    assert with_figures.plan.figures_scenario == first
    assert {mode for _, mode in recorded} == {"dynamic", "mpj"} and len(recorded) == 2
    without = plan_campaign(2, ["dynamic", "mpj"], figures=False)
    assert not any(j.record for j in without.plan.jobs)
    assert [j.overrides for j in without.plan.jobs] == [j.overrides for j in with_figures.plan.jobs]
    assert make_figures(without.plan, tmp_path) == [] and not any(tmp_path.iterdir())


def test_a_start_posture_inside_the_scenery_is_drawn_again_and_counted(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """No posture at all, so not a refusal: the draw is made again (the geometry itself:
    test_arm_contacts.py). Here the first posture drawn is said to be 3 mm inside the object."""
    import deploy.experiments.campaign.starts as campaign
    import deploy.launch.reachability as reachability

    plain = draw_start(DIST, BASE, 0)
    calls: list[int] = []
    real = reachability.arm_penetration

    def first_inside(scenario):
        calls.append(1)
        return (0.003, "object") if len(calls) == 1 else real(scenario)

    monkeypatch.setattr(reachability, "arm_penetration", first_inside)
    start = draw_start(DIST, BASE, 0)
    assert start.redrawn.get(campaign.REDRAW_ARM_INSIDE) == 1 and len(calls) == 2
    assert not start.refused and start.draws > plain.draws and start.q0_rad != plain.q0_rad


def test_starts_drawn_by_two_processes_are_the_same_and_reported_in_order() -> None:
    from deploy.experiments.campaign.run import plan_campaign

    drawn: list[int] = []
    parallel = plan_campaign(3, ["dynamic"], figures=False, jobs=2, on_drawn=drawn.append)
    assert drawn == [0, 1, 2]
    assert parallel.starts == tuple(draw_start(DIST, BASE, i) for i in range(3))


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--out", "/proc/no-such-dir/out"], "--out /proc/no-such-dir/out: cannot write"),
        (["--set", "controller.gain=-3"], "controller.gain"),
        (["--n", "0"], "--n: at least 1 start"),
        (["--only", "start_x"], "--only: 'start_x'"),
        (["--only", "first"], "--only: 'first': a start's name (e.g. start_0003) or its index"),
        (["--n", "3", "--only", "3"], "not allowed with argument --n"),
    ],
)
def test_bad_campaign_input_exits_2_before_any_start_is_drawn(
    monkeypatch: pytest.MonkeyPatch,
    tmp_path: Path,
    args: list[str],
    message: str,
    umay_cli: Callable[..., CliResult],
) -> None:
    """Drawing 200 starts takes minutes: a bad option is named before it starts."""
    import deploy.experiments.campaign.run as campaign

    def no_drawing(*_args: object) -> None:
        raise AssertionError("a start was drawn")

    monkeypatch.setattr(campaign, "draw_start", no_drawing)
    out = ["--out", str(tmp_path / "out")] if "--out" not in args else []
    n = [] if "--only" in args else ["--n", "2"]  # --only replaces --n
    refused = umay_cli("campaign", *n, *out, *args)
    assert refused.returncode == 2, refused.stderr
    assert message in refused.stderr
    assert not (tmp_path / "out").exists()


def test_a_seed_given_to_the_campaign_is_checked_as_the_files_own() -> None:
    """Called from code, not argparse: a negative seed is refused by name, not by numpy
    later, while the starts are drawn."""
    from deploy.experiments.campaign.run import campaign_inputs
    from deploy.experiments.compare import CompareError

    assert campaign_inputs(1, seed=7)[0].seed == 7
    with pytest.raises(CompareError, match="--seed -3: Input should be greater than or equal"):
        campaign_inputs(1, seed=-3)


@pytest.mark.parametrize("index", [0, 102])  # a goal constant holds, and one it leaves
def test_a_starts_goal_stability_is_what_the_controller_measures_there(index: int) -> None:
    """The campaign judges each goal from the true geometry; the controller computes the same
    from the target it measured when it freezes its matrix (in-process lockstep)."""
    start = draw_start(DIST, BASE, index)
    assert not start.refused and start.constant_goal_stability is not None
    items = [*start.overrides(), "controller.mode='constant'"]
    scenario = load_scenario(BASE_PATH, parse_overrides(items))
    with Pipeline(scenario, truth=False) as pipeline:
        for _ in range(40):
            pipeline.step()
            if pipeline.controller.goal_stability is not None:
                break
    measured = pipeline.controller.goal_stability
    assert measured is not None
    assert measured == pytest.approx(start.constant_goal_stability, abs=0.1)
    assert (measured > 0.0) == (index == 0)
    per_corner = scenario.model_copy(
        update={
            "controller": scenario.controller.model_copy(
                update={"constant_depth": ConstantDepth.PER_CORNER}
            )
        }
    )
    assert goal_stability_of(per_corner) == pytest.approx(1.0)


def test_a_constant_run_whose_goal_its_matrix_leaves_is_warned_of_before_launch(
    caplog: pytest.LogCaptureFixture,
) -> None:
    unstable, stable = draw_start(DIST, BASE, 102), draw_start(DIST, BASE, 0)
    with caplog.at_level(logging.WARNING, logger="umay.run"):
        prepare(str(BASE_PATH), [*unstable.overrides(), "controller.mode='constant'"])
    assert "makes this goal unstable" in caplog.text and "-1.4" in caplog.text
    caplog.clear()
    for items in (
        [*unstable.overrides(), "controller.mode='dynamic'"],  # inverts L* at its goal
        [
            *unstable.overrides(),
            "controller.mode='constant'",
            "controller.constant_depth='per_corner'",
        ],
        [*stable.overrides(), "controller.mode='constant'"],
    ):
        with caplog.at_level(logging.WARNING, logger="umay.run"):
            prepare(str(BASE_PATH), items)
        assert "unstable" not in caplog.text, items


def test_every_goal_of_the_suite_is_one_constants_frozen_matrix_holds() -> None:
    """What docs/results.md says: the suite's twelve goals are stable under constant."""
    suite = sorted(BASE_PATH.parent.glob("*.toml"))  # the base is the suite's first
    assert len(suite) == 12
    for path in suite:
        scenario = load_scenario(path, parse_overrides(["controller.mode='constant'"]))
        assert goal_stability_of(scenario) > 0.0, path.name


def test_the_contacts_block_counts_the_runs_on_goal_that_touched_the_scenery() -> None:
    from deploy.docs.blocks import BLOCKS
    from deploy.docs.sources import Inputs

    on_goal = dict(converged=True, reason="converged", on_goal=True, final_pixel_rms=0.2)
    rows = [
        row(scenario="s1", **on_goal),
        row(scenario="s2", first_contact_s=0.5, contact_with="object", **on_goal),
        row(scenario="s3", first_contact_s=0.9, contact_with="table", **on_goal),
        row(scenario="s4", first_contact_s=0.1, contact_with="object"),  # a failure: not counted
        row(scenario="s1", mode="pmj", **on_goal),
    ]
    table = BLOCKS["campaign-contacts"].render(Inputs(campaign_results=rows), "docs")
    assert "| dynamic | 3 | 2 (66.7%) | object 1, table 1 | 0.70 |" in table
    assert "| pmj | 1 | 0 (0.0%) | – | – |" in table
    assert "[`results.json`](campaign/results.json)" in table
    assert "Not run yet" in BLOCKS["campaign-contacts"].render(Inputs(), "docs")
