"""One run of a comparison as a row: CSV and JSON, and two comparisons compared."""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from deploy.experiments.compare.plan import Job, moves_target
from deploy.launch.evaluate import RunResult

# What two lockstep comparisons of the same scenarios may disagree on: the wall time, and
# where the scenario files were (a subset copied elsewhere is checked against the suite).
NOT_RESULTS = frozenset({"wall_time_s", "scenario_file"})


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
    "first_contact_s",
    "contact_with",
    "wall_time_s",
    "moving_target",
    "clock",
    "scenario_file",
    "detail",
)


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
