"""A comparison summarised per strategy: medians, the best per metric, the Markdown tables and
``summary.md``."""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence

from pydantic import BaseModel

from deploy.experiments.compare.rows import ON_GOAL_M, CompareRow
from deploy.markdown import format_cell, markdown_table


# --- summary ---------------------------------------------------------------------------------
class StrategySummary(BaseModel):
    """One strategy over the comparison. Medians are over the static scenarios it converged on
    (a failed run's final numbers do not compare, and a moving target's path is not a reach);
    None when there is none. Success counts every run; tracking, the moving-target runs."""

    mode: str
    runs: int
    converged: int  # the controller said so
    on_goal: int  # ... and the hand was within ON_GOAL_M of its goal (ground truth)
    success_rate: float  # on_goal / runs
    static_runs: int  # scenarios without a moving target
    static_converged: int
    median_frames: float | None
    median_sim_time_s: float | None
    median_final_pixel_rms: float | None
    median_final_position_error_m: float | None
    median_final_orientation_error_deg: float | None
    median_path_ratio: float | None
    median_peak_ee_speed_m_s: float | None
    median_peak_joint_speed_rad_s: float | None
    median_min_manipulability: float | None
    median_marker_lost_s: float | None
    median_tracking_position_error_m: float | None  # moving-target runs (converged or not)
    median_wall_time_s: float | None


# (summary field, markdown header with units, scale for display, format, better)
METRICS: tuple[tuple[str, str, float, str, str], ...] = (
    ("success_rate", "success", 100.0, ".0f", "higher"),
    ("median_frames", "frames", 1.0, ".0f", "lower"),
    ("median_sim_time_s", "sim time (s)", 1.0, ".2f", "lower"),
    ("median_final_pixel_rms", "pixel RMS (px)", 1.0, ".3f", "lower"),
    ("median_final_position_error_m", "position error (mm)", 1000.0, ".2f", "lower"),
    ("median_final_orientation_error_deg", "orientation error (°)", 1.0, ".2f", "lower"),
    ("median_path_ratio", "path ratio", 1.0, ".3f", "lower"),
    ("median_peak_ee_speed_m_s", "peak hand speed (m/s)", 1.0, ".3f", "lower"),
    ("median_peak_joint_speed_rad_s", "peak joint speed (rad/s)", 1.0, ".3f", "lower"),
    ("median_min_manipulability", "min manipulability", 1.0, ".4f", "higher"),
    ("median_marker_lost_s", "marker lost (s)", 1.0, ".2f", "lower"),
    ("median_tracking_position_error_m", "tracking error (mm)", 1000.0, ".1f", "lower"),
)


def _median(values: Sequence[float | int | None]) -> float | None:
    present = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    return statistics.median(present) if present else None


def summarize_mode(rows: Sequence[CompareRow], mode: str) -> StrategySummary:
    mine = [r for r in rows if r.mode == mode]
    static = [r for r in mine if not r.moving_target]
    ok = [r for r in static if r.converged]

    def med(field: str, among: Sequence[CompareRow] = ok) -> float | None:
        return _median([getattr(r, field) for r in among])

    return StrategySummary(
        mode=mode,
        runs=len(mine),
        converged=sum(r.converged for r in mine),
        on_goal=sum(r.on_goal for r in mine),
        success_rate=sum(r.on_goal for r in mine) / len(mine) if mine else 0.0,
        static_runs=len(static),
        static_converged=len(ok),
        median_frames=med("frames"),
        median_sim_time_s=med("sim_time_s"),
        median_final_pixel_rms=med("final_pixel_rms"),
        median_final_position_error_m=med("final_position_error_m"),
        median_final_orientation_error_deg=med("final_orientation_error_deg"),
        median_path_ratio=med("path_ratio"),
        median_peak_ee_speed_m_s=med("peak_ee_speed_m_s"),
        median_peak_joint_speed_rad_s=med("peak_joint_speed_rad_s"),
        median_min_manipulability=med("min_manipulability"),
        median_marker_lost_s=med("marker_lost_s"),
        median_tracking_position_error_m=med(
            "tracking_position_error_m", [r for r in mine if r.moving_target]
        ),
        median_wall_time_s=med("wall_time_s", mine),
    )


def summarize_modes(rows: Sequence[CompareRow], modes: Sequence[str]) -> list[StrategySummary]:
    return [summarize_mode(rows, m) for m in modes]


class Best(BaseModel):
    metric: str  # a StrategySummary field
    header: str
    better: str  # "lower" or "higher"
    modes: list[str]  # every strategy tied for best
    value: float


def best_per_metric(summaries: Sequence[StrategySummary]) -> list[Best]:
    """For each metric, the strategy (or strategies, when tied at display precision) with
    the best value; metrics no strategy has a value for are left out."""
    out = []
    for field, header, scale, fmt, better in METRICS:
        values = {s.mode: getattr(s, field) for s in summaries if getattr(s, field) is not None}
        if not values:
            continue
        pick = max if better == "higher" else min
        best = pick(values.values())
        shown = format(best * scale, fmt)
        tied = [m for m, v in values.items() if format(v * scale, fmt) == shown]
        out.append(Best(metric=field, header=header, better=better, modes=tied, value=best))
    return out


def paired_medians(
    rows: Sequence[CompareRow], modes: Sequence[str], field: str
) -> tuple[list[str], dict[str, float | None]]:
    """Median of ``field`` per strategy over the static scenarios every strategy converged on
    (so the medians are over the same runs); returns (those scenarios, medians)."""
    by_scenario: dict[str, dict[str, CompareRow]] = {}
    for r in rows:
        by_scenario.setdefault(r.scenario, {})[r.mode] = r
    common = [
        s
        for s, runs in by_scenario.items()
        if all(m in runs and runs[m].converged and not runs[m].moving_target for m in modes)
    ]
    return common, {m: _median([getattr(by_scenario[s][m], field) for s in common]) for m in modes}


def strategy_table(
    summaries: Sequence[StrategySummary],
    metrics: Sequence[tuple[str, str, float, str, str]] = METRICS,
) -> str:
    """Per strategy: converged, on goal and the ``metrics`` (a selection of :data:`METRICS`;
    the README shows a few, summary.md all)."""
    headers = ["strategy", "converged", "on goal", *[h for _, h, _, _, _ in metrics]]
    body = []
    for s in summaries:
        cells = [s.mode, f"{s.converged}/{s.runs}", f"{s.on_goal}/{s.runs}"]
        for field, _, scale, fmt, _ in metrics:
            unit = "%" if field == "success_rate" else ""
            cells.append(format_cell(getattr(s, field), scale, fmt) + unit)
        body.append(cells)
    return markdown_table(headers, body)


def best_table(bests: Sequence[Best]) -> str:
    scale_fmt = {f: (sc, fm) for f, _, sc, fm, _ in METRICS}
    body = []
    for b in bests:
        scale, fmt = scale_fmt[b.metric]
        unit = "%" if b.metric == "success_rate" else ""
        body.append(
            [
                b.header,
                f"{b.better} is better",
                ", ".join(b.modes),
                format_cell(b.value, scale, fmt) + unit,
            ]
        )
    return markdown_table(["metric (median)", "", "best strategy", "value"], body, right_from=3)


def converged_cell(r: CompareRow) -> str:
    if not r.converged:
        return f"**no** ({r.reason})"
    return "yes" if r.on_goal else "yes, **off goal**"


def runs_table(rows: Sequence[CompareRow]) -> str:
    headers = [
        "scenario",
        "strategy",
        "converged",
        "frames",
        "pixel RMS (px)",
        "position error (mm)",
        "orientation error (°)",
        "path ratio",
        "peak hand speed (m/s)",
        "marker lost (s)",
        "tracking error (mm)",
    ]
    body = [
        [
            r.scenario,
            r.mode,
            converged_cell(r),
            str(r.frames),
            format_cell(r.final_pixel_rms, 1.0, ".3f"),
            format_cell(r.final_position_error_m, 1000.0, ".2f"),
            format_cell(r.final_orientation_error_deg, 1.0, ".2f"),
            format_cell(r.path_ratio, 1.0, ".3f"),
            format_cell(r.peak_ee_speed_m_s, 1.0, ".3f"),
            format_cell(r.marker_lost_s, 1.0, ".2f"),
            format_cell(r.tracking_position_error_m, 1000.0, ".1f"),
        ]
        for r in rows
    ]
    return markdown_table(headers, body, right_from=3)


def summary_markdown(
    rows: Sequence[CompareRow],
    modes: Sequence[str],
    scenario_names: Sequence[str],
    figures: Sequence[str] = (),
    note: str = "",
) -> str:
    """summary.md: per strategy success and medians, the best strategy per metric, paired
    medians, failures, every run, and links to the figures (paths relative to summary.md)."""
    summaries = summarize_modes(rows, modes)
    common, ratios = paired_medians(rows, modes, "path_ratio")
    _, frames = paired_medians(rows, modes, "frames")
    failed = [r for r in rows if not r.on_goal]
    parts = [
        "# Jacobian strategies compared",
        "",
        f"{len(scenario_names)} scenarios × {len(modes)} strategies = {len(rows)} runs "
        "(lockstep clock; `umay compare`). Medians are over the static scenarios each strategy "
        "converged on (tracking: over the moving-target runs); the position error is the green "
        "marker's distance from its goal (ground truth), the path ratio the hand's path over "
        "the straight line from its start to its end. *Converged*: the controller's image "
        f"error stayed below its threshold; *on goal*: converged and the hand within "
        f"{1000 * ON_GOAL_M:g} mm of its goal (success counts these)."
        + (f"\n\n{note}" if note else ""),
        "",
        "## Per strategy",
        "",
        strategy_table(summaries),
        "",
        "## Best strategy per metric",
        "",
        best_table(best_per_metric(summaries)),
        "",
        f"## Paired: the {len(common)} static scenarios every strategy converged on",
        "",
        markdown_table(
            ["strategy", "median frames", "median path ratio"],
            [[m, format_cell(frames[m], 1.0, ".0f"), format_cell(ratios[m])] for m in modes],
        ),
        "",
        "Scenarios: " + (", ".join(common) if common else "none") + ".",
        "",
        "## Runs that did not end on their goal",
        "",
    ]
    if failed:
        parts += [
            f"- {r.scenario} · {r.mode}: "
            + ("converged in the image but off goal" if r.converged else r.reason)
            + f" after {r.frames} frames "
            f"({r.sim_time_s:.1f} s simulated), pixel RMS {format_cell(r.final_pixel_rms)} px, "
            f"{format_cell(r.final_position_error_m, 1000.0, '.1f')} mm from the goal"
            + (f"; {r.detail}" if r.detail else "")
            for r in failed
        ]
    else:
        parts.append("None.")
    parts += ["", "## Every run", "", runs_table(rows), ""]
    if figures:
        parts += ["## Figures", ""] + [f"- [{f}]({f})" for f in figures] + [""]
    return "\n".join(parts)
