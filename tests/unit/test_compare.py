"""``umay compare``'s pure core on synthetic rows: the CSV and JSON, the summary, differences
against a reference, the plan of runs, the overlay figure."""

from __future__ import annotations

import csv
import io
import shutil
from pathlib import Path

import pytest

from deploy.experiments.compare import CompareError
from deploy.experiments.compare.plan import parse_modes, plan
from deploy.experiments.compare.plots import write_overlay
from deploy.experiments.compare.rows import (
    CSV_COLUMNS,
    CompareRow,
    check_against,
    differences,
    largest_float_difference,
    rows_csv,
    rows_from_json,
    rows_json,
    same_runs,
)
from deploy.experiments.compare.summary import (
    best_per_metric,
    paired_medians,
    summarize_modes,
    summary_markdown,
)
from deploy.recording.plots import load_series
from tests.unit.test_plots import PNG_SIGNATURE, write_recording

SUITE = Path(__file__).resolve().parents[2] / "deploy" / "scenarios" / "suite"
MODES = ("constant", "dynamic", "pmj", "mpj", "points3d")
# The CI comparison: the baseline and the moving target (so the tracking columns are filled),
# at 320×240 and with short timeouts; about 2 minutes on 2 cores.
SMALL_SUITE = ("01_baseline.toml", "12_moving_target.toml")
CHEAP = ["camera.width_px=320", "camera.height_px=240", "run.timeout_s=12.0"]


def rows_from_csv(text: str) -> list[CompareRow]:
    """What a reader of results.csv gets back (an empty cell is None; pydantic parses the rest)."""
    reader = csv.DictReader(io.StringIO(text))
    return [
        CompareRow.model_validate(
            {k: (None if v == "" and k != "detail" else v) for k, v in r.items()}
        )
        for r in reader
    ]


def row(scenario: str, mode: str, converged: bool = True, **fields) -> CompareRow:
    base = {
        "scenario": scenario,
        "mode": mode,
        "clock": "lockstep",
        "converged": converged,
        "reason": "converged" if converged else "timeout",
        "frames": 150,
        "sim_time_s": 5.0,
        "wall_time_s": 30.0,
        "final_pixel_rms": 0.2,
        "final_position_error_m": 0.0004,
        "final_orientation_error_deg": 0.1,
        "path_length_m": 0.1,
        "path_ratio": 1.05,
        "peak_ee_speed_m_s": 0.08,
        "peak_joint_speed_rad_s": 0.4,
        "min_manipulability": 0.01,
        "marker_lost_s": 0.0,
        "scenario_file": f"suite/{scenario}.toml",
        "moving_target": False,
    }
    data = base | fields
    error = data["final_position_error_m"]
    data["on_goal"] = data["converged"] and error is not None and error <= 0.005
    return CompareRow(**data)


def synthetic_rows() -> list[CompareRow]:
    return [
        row("a", "constant", path_ratio=1.20, frames=200),
        row("a", "dynamic", path_ratio=1.10, frames=160),
        row("a", "points3d", path_ratio=1.00, frames=170, final_pixel_rms=0.123456789012345),
        row("b", "constant", converged=False, final_pixel_rms=None, path_ratio=1.5),
        row("b", "dynamic", path_ratio=1.30, frames=180),
        row("b", "points3d", path_ratio=1.02, frames=190, detail='odd, "quoted" text'),
        row("m", "constant", moving_target=True, tracking_position_error_m=0.02),
        row("m", "dynamic", moving_target=True, tracking_position_error_m=0.01),
        row("m", "points3d", moving_target=True, final_position_error_m=0.02),
    ]


# --- pure core ------------------------------------------------------------------------------
def test_csv_columns_are_every_field_once() -> None:
    assert len(CSV_COLUMNS) == len(set(CSV_COLUMNS))
    assert set(CSV_COLUMNS) == set(CompareRow.model_fields)


def test_csv_and_json_read_back_to_the_same_rows() -> None:
    rows = synthetic_rows()
    assert rows_from_csv(rows_csv(rows)) == rows
    assert rows_from_json(rows_json(rows)) == rows


def test_summary_counts_medians_and_best() -> None:
    modes = ("constant", "dynamic", "points3d")
    summaries = {s.mode: s for s in summarize_modes(synthetic_rows(), modes)}
    constant = summaries["constant"]
    assert (constant.runs, constant.converged, constant.static_runs) == (3, 2, 2)
    assert constant.static_converged == 1
    assert constant.success_rate == pytest.approx(2 / 3)
    points3d = summaries["points3d"]
    assert (points3d.converged, points3d.on_goal) == (3, 2)  # m: converged 20 mm off
    assert summaries["dynamic"].median_path_ratio == pytest.approx(1.20)  # a, b; m moves
    assert summaries["constant"].median_frames == 200  # a only: b failed, m moves
    assert summaries["dynamic"].median_tracking_position_error_m == pytest.approx(0.01)
    best = {b.metric: b for b in best_per_metric(list(summaries.values()))}
    assert best["median_path_ratio"].modes == ["points3d"]
    assert best["success_rate"].modes == ["dynamic"]
    assert best["median_tracking_position_error_m"].modes == ["dynamic"]


def test_paired_medians_use_the_static_scenarios_every_strategy_converged_on() -> None:
    common, ratios = paired_medians(synthetic_rows(), ("constant", "dynamic"), "path_ratio")
    assert common == ["a"]  # b: constant failed; m: moving target
    assert ratios == {"constant": 1.20, "dynamic": 1.10}


def test_summary_markdown_counts_match_the_rows() -> None:
    rows = synthetic_rows()
    text = summary_markdown(rows, ("constant", "dynamic", "points3d"), ("a", "b", "m"))
    assert "| constant | 2/3 | 2/3 |" in text and "| dynamic | 3/3 | 3/3 |" in text
    assert "| points3d | 3/3 | 2/3 |" in text
    assert "- b · constant: timeout" in text
    assert "- m · points3d: converged in the image but off goal" in text
    assert text.count("\n| a | ") == 3  # one line per run in the table of every run


def test_differences_ignore_only_the_wall_time_and_the_file_path() -> None:
    rows = synthetic_rows()
    again = [
        r.model_copy(update={"wall_time_s": r.wall_time_s + 7.0, "scenario_file": "copy.toml"})
        for r in rows
    ]
    assert differences(rows, again) == []
    again[1] = again[1].model_copy(update={"frames": 161})
    assert differences(rows, again) == ["a · dynamic: frames 160 != 161"]
    assert differences(same_runs(rows, again[:3]), again[:3]) == ["a · dynamic: frames 160 != 161"]
    assert differences(rows, again[:-1]) == [
        "a · dynamic: frames 160 != 161",
        "m · points3d: only in the first",
    ]


def test_differences_allow_floats_a_relative_tolerance_and_nothing_else() -> None:
    """Another CPU changes the last digits of float results, never counts, flags or reasons."""
    rows = synthetic_rows()
    again = list(rows)
    pixel = rows[2].final_pixel_rms
    again[2] = rows[2].model_copy(update={"final_pixel_rms": pixel * (1 + 2e-5)})
    assert largest_float_difference(rows, rows) == (0, 0.0)
    changed, largest = largest_float_difference(rows, again)
    assert changed == 1 and largest == pytest.approx(2e-5, rel=1e-3)
    assert differences(rows, again, rel_tol=1e-4) == []
    assert differences(rows, again) == [
        f"a · points3d: final_pixel_rms {pixel!r} != {pixel * (1 + 2e-5)!r}"
    ]
    assert len(differences(rows, again, rel_tol=1e-5)) == 1
    again[1] = again[1].model_copy(update={"frames": 161})  # an int: exact at any tolerance
    again[3] = again[3].model_copy(update={"final_pixel_rms": 0.2})  # None before: exact too
    assert differences(rows, again, rel_tol=0.5) == [
        "a · dynamic: frames 160 != 161",
        "b · constant: final_pixel_rms None != 0.2",
    ]


def test_check_against_a_reference_says_identical_close_or_what_differs() -> None:
    rows = synthetic_rows()
    same, lines = check_against(rows, rows[:3], "old.json", 1e-4)  # a subset of its runs
    assert same and lines == ["identical to old.json (wall time aside): 3 runs"]
    close = [rows[0].model_copy(update={"path_ratio": rows[0].path_ratio * (1 + 1e-5)})]
    same, lines = check_against(rows, close, "old.json", 1e-4)
    assert same and len(lines) == 1
    assert (
        "within relative 0.0001" in lines[0] and "1 float result(s) differ, by 1.0e-05" in lines[0]
    )
    same, lines = check_against(rows, close, "old.json", 0.0)
    assert not same and lines[0] == "1 difference(s) from old.json:"
    assert lines[1].startswith("  a · constant: path_ratio 1.2 != 1.2000")


def test_parse_modes() -> None:
    assert parse_modes(None) == MODES
    assert parse_modes(["mpj,constant", "mpj"]) == ("mpj", "constant")
    assert parse_modes(["all"]) == MODES
    with pytest.raises(CompareError, match="'nope'"):
        parse_modes(["dynamic", "nope"])


def _suite_copy(tmp_path: Path, names: tuple[str, ...]) -> Path:
    folder = tmp_path / "scenarios"
    folder.mkdir()
    for name in names:
        shutil.copy(SUITE / name, folder / name)
    return folder


def test_plan_is_scenario_major_and_records_the_figures_scenario(tmp_path: Path) -> None:
    folder = _suite_copy(tmp_path, SMALL_SUITE)
    p = plan(folder, ("mpj", "dynamic"), CHEAP, figures_scenario="12_moving_target")
    assert [(j.scenario.name, j.mode) for j in p.jobs] == [
        ("baseline", "mpj"),
        ("baseline", "dynamic"),
        ("moving_target", "mpj"),
        ("moving_target", "dynamic"),
    ]
    assert p.figures_scenario == "moving_target"
    assert [j.record for j in p.jobs] == [False, False, True, True]
    assert all(j.scenario.camera.width_px == 320 for j in p.jobs)
    assert [j.scenario.controller.mode.value for j in p.jobs] == ["mpj", "dynamic"] * 2


@pytest.mark.parametrize(
    ("setup", "message"),
    [
        ("missing", "no such directory"),
        ("empty", "no scenario"),
        ("invalid", "controller.gain"),
        ("unreachable", "target.position"),
        ("duplicate", "also the name of"),
        ("figures", "--figures-scenario"),
    ],
)
def test_plan_refuses_bad_input(tmp_path: Path, setup: str, message: str) -> None:
    folder = tmp_path / "scenarios"
    figures = None
    if setup != "missing":
        folder.mkdir()
    baseline = (SUITE / "01_baseline.toml").read_text()
    if setup == "invalid":
        (folder / "a.toml").write_text(baseline.replace("gain = 1.0", "gain = -1.0"))
    elif setup == "unreachable":
        (folder / "a.toml").write_text(baseline.replace("[0.28, -0.32, 0.04]", "[0.9, -0.3, 0]"))
    elif setup == "duplicate":
        (folder / "a.toml").write_text(baseline)
        (folder / "b.toml").write_text(baseline)
    elif setup == "figures":
        (folder / "a.toml").write_text(baseline)
        figures = "nope"
    with pytest.raises(CompareError, match=message):
        plan(folder, MODES, figures_scenario=figures)


def test_overlay_figure_is_a_png(tmp_path: Path) -> None:
    series = {m: load_series(write_recording(tmp_path / f"{m}.mcap")) for m in ("dynamic", "mpj")}
    path = write_overlay(series, tmp_path / "overlay.png", 0.25, title="two strategies")
    assert path is not None and path.read_bytes()[:8] == PNG_SIGNATURE
    assert write_overlay({}, tmp_path / "none.png") is None
