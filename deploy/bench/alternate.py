"""``umay bench --alternate SET --pairs N``: the same bench without and with one change, run
in turns, so that both sides see the same moments of a noisy host.

From one run to the next on a shared 2-core VM the latency moves by a millisecond or more, more
than most single changes; a change is judged by pairs run one right after the other, and by
whether every pair moves the same way. Each side of a pair is the ordinary bench (``--repeat``
runs, merged as usual); the report keeps each side's headline figures and the command, machine
and code they were measured on.
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict

from deploy.bench.report import BenchReport, Machine

ALTERNATION_VERSION = 1


class SideFigures(BaseModel):
    """One side of a pair: the figures the goals are stated in (ms unless said)."""

    model_config = ConfigDict(extra="forbid")

    latency_p50: float | None  # over all frames of the side's runs
    latency_p99: float | None
    frame_handoff_p50: float | None  # publish + frame transport
    distribution_adds_p50: float | None
    real_time_factor: float | None  # simulated / wall time (none)
    load_start: list[float]  # the host's load averages as the side began


class Pair(BaseModel):
    model_config = ConfigDict(extra="forbid")

    without: SideFigures
    with_change: SideFigures


class AlternationReport(BaseModel):
    model_config = ConfigDict(extra="forbid")

    version: int = ALTERNATION_VERSION
    command: str
    change: str  # the --set item the second side of each pair adds
    machine: Machine  # of the first run
    pairs: list[Pair]


def side_figures(report: BenchReport) -> SideFigures:
    """The headline figures of one bench report (pooled over its runs where it has several)."""
    d = report.distributed
    latency = d.pooled.latency_ms if d.pooled is not None else d.latency_ms
    handoff = d.pooled.frame_handoff_ms if d.pooled is not None else d.frame_handoff_ms
    return SideFigures(
        latency_p50=latency.p50,
        latency_p99=latency.p99,
        frame_handoff_p50=handoff.p50,
        distribution_adds_p50=report.distribution_adds_ms.p50,
        real_time_factor=d.real_time_factor,
        load_start=report.machine.load_start,
    )


# (field, words, format) of the figures compared, in the order shown.
COMPARED: tuple[tuple[str, str, str], ...] = (
    ("latency_p50", "latency p50, all frames (ms)", ".2f"),
    ("latency_p99", "latency p99, all frames (ms)", ".2f"),
    ("distribution_adds_p50", "what distribution adds, p50 (ms)", ".2f"),
    ("frame_handoff_p50", "frame publish + transport p50 (ms)", ".2f"),
    ("real_time_factor", "real-time factor", ".2f"),
)


def values(report: AlternationReport, field: str, side: str) -> list[float | None]:
    """``field`` of every pair's ``side`` ("without" or "with_change"), in run order."""
    return [getattr(getattr(p, side), field) for p in report.pairs]


def same_way(report: AlternationReport, field: str, fmt: str = ".2f") -> str:
    """How many pairs moved ``field`` the way most did with the change (:func:`pairs_moved`)."""
    pairs = zip(values(report, field, "without"), values(report, field, "with_change"), strict=True)
    return pairs_moved(pairs, fmt)


def pairs_moved(pairs: Iterable[tuple[float | None, float | None]], fmt: str = ".2f") -> str:
    """How many (without, with) pairs moved the way most did: "4 of 4 down" (a pair missing
    the figure on either side does not count). Values are compared as ``fmt`` shows them: a
    move too small to show (a realtime run's real-time factor) is no move."""
    moves = [
        float(format(w, fmt)) - float(format(o, fmt))
        for o, w in pairs
        if o is not None and w is not None
    ]
    down = sum(m < 0 for m in moves)
    up = sum(m > 0 for m in moves)
    if not down and not up:
        return f"none of {len(moves)} moved"
    if down == up:
        return f"{down} of {len(moves)} down, {up} up"
    return f"{max(down, up)} of {len(moves)} " + ("down" if down > up else "up")


def shown(value: float | None, fmt: str) -> str:
    """A figure as the tables show it ("–": not measured)."""
    return "–" if value is None else format(value, fmt)


def comparison_rows(report: AlternationReport) -> list[list[str]]:
    """Per compared figure: its values without and with the change (one per pair, in run
    order) and how many pairs moved it the same way."""

    def joined(vs: list[float | None], fmt: str) -> str:
        return " / ".join(shown(v, fmt) for v in vs)

    return [
        [
            words,
            joined(values(report, field, "without"), fmt),
            joined(values(report, field, "with_change"), fmt),
            same_way(report, field, fmt),
        ]
        for field, words, fmt in COMPARED
    ]


def format_side(side: SideFigures) -> str:
    """One side of a pair on a line, as it ends (progress of a long comparison)."""
    return ", ".join(
        f"{words} {shown(getattr(side, field), fmt)}" for field, words, fmt in COMPARED
    )


def format_alternation(report: AlternationReport) -> str:
    """The printed comparison: a line per figure."""
    n = len(report.pairs)
    lines = [f"{n} pair{'s' if n != 1 else ''}, each without then with {report.change}:"]
    for words, without, with_change, moved in comparison_rows(report):
        lines.append(f"  {words}: {without}  ->  {with_change}   ({moved})")
    return "\n".join(lines)


def write_alternation(report: AlternationReport, path: str | Path) -> None:
    Path(path).write_text(json.dumps(report.model_dump(mode="json"), indent=1) + "\n")


def load_alternation(data: dict[str, Any]) -> AlternationReport:
    return AlternationReport.model_validate(data)
