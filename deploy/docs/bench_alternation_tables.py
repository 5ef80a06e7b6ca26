"""The changes judged by ``umay bench --alternate`` (``docs/bench/alternations/*.json``): each
figure in every pair without and with the change, and the pairs within each goal."""

from __future__ import annotations

from collections.abc import Sequence
from statistics import median
from typing import Any

from deploy.bench.goals import (
    ADDS_GOAL,
    HANDOFF_GOAL,
    LATENCY_P50_GOAL,
    LATENCY_P99_GOAL,
    REAL_TIME_GOAL,
    Goal,
)
from deploy.docs.bench_cells import caption, num, realtime_command
from deploy.docs.sources import ALTERNATIONS_DIR, Inputs
from deploy.markdown import markdown_table


def bench_alternations(inputs: Inputs, here: str) -> str:
    """Each change judged by ``umay bench --alternate``: a figure per row, its value in every
    pair without and with the change, and how many pairs moved it the same way."""
    from deploy.bench.alternate import comparison_rows

    parts = []
    for name, report in inputs.alternations:
        path = f"{ALTERNATIONS_DIR}/{name}.json"
        parts.append(
            caption(here, name, path, report.command, report.machine.model_dump())
            + markdown_table(
                ["figure", "without", f"with `{report.change}`", "pairs"],
                comparison_rows(report),
                right_from=1,
            )
            + "\n\n"
            + alternation_summary(report)
        )
    return "\n\n".join(parts) or "*No alternation has been run.*"


# (field of the alternation's figures, words, goal, unit) of the line under each alternation.
ALTERNATION_GOALS: tuple[tuple[str, str, Goal, str], ...] = (
    ("latency_p50", "latency p50", LATENCY_P50_GOAL, " ms"),
    ("latency_p99", "p99", LATENCY_P99_GOAL, " ms"),
    ("distribution_adds_p50", "what distribution adds", ADDS_GOAL, " ms"),
    ("frame_handoff_p50", "frame publish + transport", HANDOFF_GOAL, " ms"),
    ("real_time_factor", "real-time factor", REAL_TIME_GOAL, ""),
)


def _median(vs: Sequence[float]) -> float | None:
    return median(vs) if vs else None


def alternation_summary(report: Any) -> str:
    """Under an alternation's table: how many pairs had each figure within its goal, without
    and with the change (the real-time factor's goal only in lockstep), and the median of the
    pairs on each side."""
    from deploy.bench.alternate import values

    n = len(report.pairs)
    realtime = realtime_command(report.command)
    within, medians = [], []
    for field, words, goal, unit in ALTERNATION_GOALS:
        sides = [values(report, field, side) for side in ("without", "with_change")]
        if not (realtime and goal is REAL_TIME_GOAL):
            counts = [sum(goal.met(v) for v in vs) for vs in sides]
            within.append(f"{words} {goal}{unit} {counts[0]} → {counts[1]}")
        mids = [_median([v for v in vs if v is not None]) for vs in sides]
        medians.append(f"{words} {num(mids[0])} → {num(mids[1])}{unit}")
    return (
        f"Pairs within each goal, of {n}, without → with: {', '.join(within)}. "
        f"Medians of the pairs, without → with: {', '.join(medians)}."
    )
