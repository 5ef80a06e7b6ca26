"""``umay compare``: every Jacobian strategy on every scenario of a suite, side by side.

The thesis's experiment (§5.6-5.7: constant, dynamic, PMJ and MPJ Jacobians), extended with
``points3d`` and with a scenario suite (``deploy/scenarios/suite``). Each (scenario, strategy)
pair is one lockstep :func:`deploy.launch.run.run_once`: its own four service processes, its own
key prefix and its own listening port, so several pipelines share a machine without
crosstalk, and every run is deterministic (only the wall time varies).

Functional core (pure, tested without processes): :func:`plan` validates the whole
comparison before anything starts, :class:`CompareRow` is one run, :func:`rows_csv` /
:func:`rows_json` and their inverses write and read the results, :func:`summarize_modes`,
:func:`best_per_metric` and :func:`summary_markdown` aggregate them, :func:`differences`
compares two comparisons. Imperative shell: :func:`run_all` (a thread per running job, each
waiting on its own processes), :func:`make_figures`, :func:`write_outputs`; the command line
is in :mod:`deploy.experiments.cli`.

Outputs in ``--out``: ``results.csv``, ``results.json``, ``summary.md``, ``logs/`` (each run's
service logs) and ``figures/`` (per strategy, the thesis-style figures of the figures
scenario, its MCAP recording, and ``overlay.png`` of all strategies).
"""

from __future__ import annotations

import csv
import io
import json
import math
import statistics
import threading
import uuid
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from common.config import EventAction, JacobianMode, Scenario, ScenarioError, load_scenario
from common.runtime import parse_overrides
from deploy.experiments.evaluate import RunResult

ALL_MODES = tuple(m.value for m in JacobianMode)
# What two lockstep comparisons of the same scenarios may disagree on: the wall time, and
# where the scenario files were (a subset copied elsewhere is checked against the suite).
NOT_RESULTS = frozenset({"wall_time_s", "scenario_file"})


class CompareError(ValueError):
    """Bad input to ``umay compare``; the message names what and why. Nothing was launched."""


# A run that converged in the image but ended further than this from its goal (ground truth)
# converged on something else than the target: the tolerance of the integration tests.
ON_GOAL_M = 0.005


class CompareRow(RunResult):
    """One run of the comparison: the run's result and where its scenario came from.

    ``converged`` is the controller's claim (image error below the threshold); ``on_goal`` is
    the judgement: converged and the green marker within :data:`ON_GOAL_M` of its goal."""

    on_goal: bool
    scenario_file: str
    moving_target: bool  # the scenario moves the target: it judges tracking


# Column order of results.csv (every field of CompareRow exactly once; a test checks it).
CSV_COLUMNS: tuple[str, ...] = (
    "scenario",
    "mode",
    "converged",
    "on_goal",
    "reason",
    "frames",
    "sim_time_s",
    "final_pixel_rms",
    "final_position_error_m",
    "final_orientation_error_deg",
    "path_length_m",
    "path_ratio",
    "peak_ee_speed_m_s",
    "peak_joint_speed_rad_s",
    "min_manipulability",
    "marker_lost_s",
    "tracking_position_error_m",
    "tracking_max_position_error_m",
    "tracking_pixel_rms",
    "final_joint_margin_deg",
    "final_hand_border_px",
    "wall_time_s",
    "moving_target",
    "clock",
    "scenario_file",
    "detail",
)


# --- planning: validate everything before anything starts ----------------------------------
@dataclass(frozen=True)
class Job:
    """One (scenario, strategy) run; ``overrides`` include the mode."""

    scenario_path: Path
    scenario: Scenario
    mode: str
    overrides: tuple[str, ...]
    record: bool  # the figures scenario's runs are recorded (MCAP) for the figures


@dataclass(frozen=True)
class Plan:
    jobs: tuple[Job, ...]
    modes: tuple[str, ...]
    scenario_names: tuple[str, ...]
    figures_scenario: str


def parse_modes(values: Sequence[str] | None) -> tuple[str, ...]:
    """``--modes`` (space- or comma-separated, ``all`` for every strategy) in the given order,
    duplicates dropped; default: all five."""
    if not values:
        return ALL_MODES
    names = [n.strip() for v in values for n in v.split(",") if n.strip()]
    if not names:
        raise CompareError("--modes: no strategy given")
    if "all" in names:
        return ALL_MODES
    unknown = [n for n in names if n not in ALL_MODES]
    if unknown:
        raise CompareError(
            f"--modes: unknown strategy {unknown[0]!r} (choose from {', '.join(ALL_MODES)}, all)"
        )
    return tuple(dict.fromkeys(names))


def scenario_files(directory: Path) -> list[Path]:
    """The ``*.toml`` files of ``directory``, sorted by name (the suite's numbering)."""
    if not directory.exists():
        raise CompareError(f"--scenarios: {directory}: no such directory")
    if not directory.is_dir():
        raise CompareError(f"--scenarios: {directory}: not a directory")
    files = sorted(p for p in directory.glob("*.toml") if p.is_file())
    if not files:
        raise CompareError(f"--scenarios: {directory}: no scenario (*.toml) files in it")
    return files


def job_overrides(overrides: Sequence[str], mode: str) -> tuple[str, ...]:
    """The user's ``--set`` items, then the strategy (so ``--set controller.mode`` cannot
    make two columns run the same strategy)."""
    return (*overrides, f"controller.mode='{mode}'")


def moves_target(scenario: Scenario) -> bool:
    return any(e.action is EventAction.MOVE_TARGET for e in scenario.events)


def plan(
    directory: Path,
    modes: Sequence[str],
    overrides: Sequence[str] = (),
    figures_scenario: str | None = None,
) -> Plan:
    """Every (scenario, mode) job, scenario-major, after validating each scenario with each
    mode (pydantic) and once with the pre-launch check
    (:func:`deploy.experiments.reachability.check_scenario`). Raises :class:`CompareError`
    naming the file and the reason."""
    from deploy.experiments.reachability import check_scenario as check

    files = scenario_files(directory)
    jobs: list[Job] = []
    names: dict[str, Path] = {}
    for path in files:
        scenario = None
        for mode in modes:
            items = job_overrides(overrides, mode)
            try:
                scenario = load_scenario(path, parse_overrides(list(items)))
            except ScenarioError as exc:
                raise CompareError(str(exc)) from exc
            jobs.append(Job(path, scenario, mode, items, record=False))
        assert scenario is not None
        if scenario.name in names:
            raise CompareError(
                f"{path}: scenario name {scenario.name!r} is also the name of "
                f"{names[scenario.name]} (rows are keyed by name)"
            )
        names[scenario.name] = path
        try:
            check(scenario)
        except ScenarioError as exc:
            raise CompareError(f"{path}: {exc}") from exc
    figures = figures_scenario or next(iter(names))
    if figures not in names:
        stems = {p.stem: n for n, p in names.items()}
        if figures not in stems:
            raise CompareError(
                f"--figures-scenario: no scenario named {figures!r} in {directory} "
                f"(names: {', '.join(names)})"
            )
        figures = stems[figures]
    jobs = [
        Job(j.scenario_path, j.scenario, j.mode, j.overrides, record=j.scenario.name == figures)
        for j in jobs
    ]
    return Plan(tuple(jobs), tuple(modes), tuple(names), figures)


# --- rows: CSV and JSON ----------------------------------------------------------------------
def is_on_goal(result: RunResult) -> bool:
    error = result.final_position_error_m
    return result.converged and error is not None and error <= ON_GOAL_M


def display_path(path: Path) -> str:
    """Relative to the working directory when under it (the suite's rows then read
    ``deploy/scenarios/suite/...`` wherever the checkout is), else absolute."""
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path.resolve())


def make_row(job: Job, result: RunResult) -> CompareRow:
    return CompareRow(
        **result.model_dump(),
        on_goal=is_on_goal(result),
        scenario_file=display_path(job.scenario_path),
        moving_target=moves_target(job.scenario),
    )


def _csv_cell(value: object) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return repr(value)  # shortest text that reads back to the same float
    return str(value)


def rows_csv(rows: Sequence[CompareRow]) -> str:
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    for row in rows:
        data = row.model_dump()
        writer.writerow([_csv_cell(data[c]) for c in CSV_COLUMNS])
    return out.getvalue()


def rows_json(rows: Sequence[CompareRow]) -> str:
    return json.dumps([r.model_dump() for r in rows], indent=2) + "\n"


def rows_from_json(text: str) -> list[CompareRow]:
    return [CompareRow.model_validate(r) for r in json.loads(text)]


def _by_run(rows: Sequence[CompareRow]) -> dict[tuple[str, str], CompareRow]:
    return {(r.scenario, r.mode): r for r in rows}


def _compared(
    left: dict[tuple[str, str], CompareRow], right: dict[tuple[str, str], CompareRow]
) -> Iterator[tuple[str, Any, Any, float | None]]:
    """(label, value in left, value in right, their relative difference when both are floats,
    else None) of every result field of the runs in both."""
    for k in sorted(left.keys() & right.keys()):
        x, y = left[k].model_dump(), right[k].model_dump()
        for field in CSV_COLUMNS:
            if field in NOT_RESULTS:
                continue
            a, b = x[field], y[field]
            yield f"{k[0]} · {k[1]}: {field}", a, b, _relative_difference(a, b)


def _relative_difference(a: Any, b: Any) -> float | None:
    """``|a - b|`` over the larger magnitude when both are floats (0 when equal), else None."""
    if not (isinstance(a, float) and isinstance(b, float)):
        return None
    return 0.0 if a == b else abs(a - b) / max(abs(a), abs(b))


def differences(
    a: Sequence[CompareRow], b: Sequence[CompareRow], rel_tol: float = 0.0
) -> list[str]:
    """What differs between two comparisons, run by run and field by field: exactly, except
    that floats within ``rel_tol`` of each other (relative) count as equal (see
    :data:`deploy.experiments.cli.REFERENCE_REL_TOL`); the wall time and the scenario file's path
    are ignored."""
    left, right = _by_run(a), _by_run(b)
    out = [f"{s} · {m}: only in the first" for s, m in left.keys() - right.keys()]
    out += [f"{s} · {m}: only in the second" for s, m in right.keys() - left.keys()]
    for label, x, y, relative in _compared(left, right):
        if x != y and not (relative is not None and relative <= rel_tol):
            out.append(f"{label} {x!r} != {y!r}")
    return sorted(out)


def largest_float_difference(a: Sequence[CompareRow], b: Sequence[CompareRow]) -> tuple[int, float]:
    """How many float results of the runs in both differ at all, and the largest relative
    difference among them (0 when every one is the same to the bit)."""
    changes = [r for *_, r in _compared(_by_run(a), _by_run(b)) if r]
    return len(changes), max(changes, default=0.0)


def check_against(
    reference: Sequence[CompareRow], rows: Sequence[CompareRow], name: str, rel_tol: float
) -> tuple[bool, list[str]]:
    """Whether ``rows`` match the runs of ``reference`` (a previous comparison, ``name`` in the
    messages) that they repeat, within ``rel_tol`` for floats (see :func:`differences`), and
    the lines that say so."""
    before = same_runs(reference, rows)
    diffs = differences(before, rows, rel_tol)
    if diffs:
        return False, [f"{len(diffs)} difference(s) from {name}:", *("  " + d for d in diffs)]
    changed, largest = largest_float_difference(before, rows)
    if not changed:
        return True, [f"identical to {name} (wall time aside): {len(rows)} runs"]
    return True, [
        f"the same as {name} within relative {rel_tol:g} (wall time aside): {len(rows)} runs; "
        f"{changed} float result(s) differ, by {largest:.1e} at most (relative)"
    ]


def same_runs(reference: Sequence[CompareRow], rows: Sequence[CompareRow]) -> list[CompareRow]:
    """The reference's rows for the (scenario, mode) pairs of ``rows``: a subset of a suite can
    be checked against the whole suite's results."""
    wanted = {(r.scenario, r.mode) for r in rows}
    return [r for r in reference if (r.scenario, r.mode) in wanted]


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


def format_cell(value: float | None, scale: float = 1.0, fmt: str = ".3f") -> str:
    return "–" if value is None else format(value * scale, fmt)


def markdown_table(
    headers: Sequence[str], rows: Sequence[Sequence[str]], right_from: int = 1
) -> str:
    align = ["---" if i < right_from else "---:" for i in range(len(headers))]
    lines = ["| " + " | ".join(headers) + " |", "| " + " | ".join(align) + " |"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


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


# --- running -----------------------------------------------------------------------------------
class _Endpoints:
    """Free loopback ports, never the same one twice in a comparison (a port freed by one
    pipeline could otherwise be handed to the next before the first one is done with it)."""

    def __init__(self) -> None:
        self._used: set[str] = set()
        self._lock = threading.Lock()

    def take(self) -> str:
        from common.transport import free_tcp_endpoint

        with self._lock:
            while True:
                endpoint = free_tcp_endpoint()
                if endpoint not in self._used:
                    self._used.add(endpoint)
                    return endpoint


def job_label(job: Job) -> str:
    return f"{job.scenario.name} · {job.mode}"


def run_job(
    job: Job,
    index: int,
    token: str,
    out_dir: Path,
    endpoints: _Endpoints,
    stop: threading.Event,
) -> CompareRow:
    """One closed-loop run under its own prefix, port and log directory."""
    import shutil

    from deploy.launch.run import run_once

    record = figure_recording(out_dir, job.mode) if job.record else None
    log_dir = out_dir / "logs" / job.scenario.name / job.mode
    shutil.rmtree(log_dir, ignore_errors=True)  # the services append: keep this run's only
    result = run_once(
        str(job.scenario_path),
        job.scenario,
        list(job.overrides),
        prefix=f"umay/compare-{token}/{index:03d}",
        log_dir=log_dir,
        listen=endpoints.take(),
        quiet=True,
        record=record,
        stop=stop,
    )
    return make_row(job, result)


def figure_recording(out_dir: Path, mode: str) -> Path:
    return out_dir / "figures" / mode / "run.mcap"


def run_all(
    jobs: Sequence[Job],
    n_jobs: int,
    out_dir: Path,
    stop: threading.Event,
    on_start: Callable[[Job], None] = lambda _job: None,
    on_done: Callable[[Job, CompareRow], None] = lambda _job, _row: None,
) -> list[CompareRow]:
    """Run ``jobs``, ``n_jobs`` at a time; the rows in plan order. When ``stop`` is set (or
    Ctrl-C arrives), running jobs stop their services and the rest never start; the rows of
    the runs that finished are returned."""
    token = uuid.uuid4().hex[:8]  # another comparison on this machine uses other prefixes
    endpoints = _Endpoints()
    rows: dict[int, CompareRow] = {}
    pending = list(enumerate(jobs))
    running: dict[Future, int] = {}
    with ThreadPoolExecutor(max_workers=n_jobs, thread_name_prefix="compare") as pool:
        try:
            while pending or running:
                while pending and len(running) < n_jobs and not stop.is_set():
                    i, job = pending.pop(0)
                    on_start(job)
                    running[pool.submit(run_job, job, i, token, out_dir, endpoints, stop)] = i
                if not running:
                    break
                done, _ = wait(running, timeout=0.5, return_when=FIRST_COMPLETED)
                for future in done:
                    i = running.pop(future)
                    row = future.result()
                    if not (stop.is_set() and row.detail == "interrupted"):
                        rows[i] = row
                        on_done(jobs[i], row)
        except BaseException:
            stop.set()  # the running jobs stop their services; the pool waits for them
            raise
    return [rows[i] for i in sorted(rows)]


def make_figures(plan_: Plan, out_dir: Path) -> list[Path]:
    """Per strategy, the thesis-style figures of the figures scenario's run (Figs. 5.10-5.17:
    image trajectory, end-effector velocity, plus feature error and joint velocities), and
    ``overlay.png`` of every strategy's image trajectory, error and speed."""
    from deploy.experiments.compare_plots import write_overlay
    from deploy.recording.plots import load_series, plot_series

    job = next(j for j in plan_.jobs if j.record)
    converged_px = job.scenario.controller.converged_px
    written: list[Path] = []
    series = {}
    for mode in plan_.modes:
        rec = figure_recording(out_dir, mode)
        if rec.is_file():
            series[mode] = load_series(rec)  # read once: the mode's figures and the overlay
            written += plot_series(series[mode], rec.parent, converged_px, source=str(rec))
    overlay = write_overlay(
        series,
        out_dir / "figures" / "overlay.png",
        converged_px,
        title=f"All strategies, scenario {plan_.figures_scenario!r}",
    )
    if overlay is not None:
        written.append(overlay)
    return written


def write_outputs(
    plan_: Plan, rows: Sequence[CompareRow], out_dir: Path, figures: Sequence[Path], note: str = ""
) -> list[Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    csv_path, json_path, md_path = (
        out_dir / "results.csv",
        out_dir / "results.json",
        out_dir / "summary.md",
    )
    csv_path.write_text(rows_csv(rows))
    json_path.write_text(rows_json(rows))
    relative = [str(p.relative_to(out_dir)) for p in figures]
    md_path.write_text(summary_markdown(rows, plan_.modes, plan_.scenario_names, relative, note))
    return [csv_path, json_path, md_path]
