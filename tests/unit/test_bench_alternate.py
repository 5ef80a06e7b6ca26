"""``umay bench --alternate``: each side's headline figures, how the pairs moved, the printed
and generated comparison, and the command's checks before anything runs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from deploy.bench.alternate import (
    AlternationReport,
    Pair,
    SideFigures,
    comparison_rows,
    format_alternation,
    format_side,
    load_alternation,
    same_way,
    side_figures,
    write_alternation,
)
from deploy.bench.report import load_json
from deploy.docs.blocks import BLOCKS
from deploy.docs.sources import REPO_ROOT, Inputs

LOCKSTEP_JSON = REPO_ROOT / "docs/bench/lockstep_640x480.json"


def side(latency_p50: float, adds: float, handoff: float | None = 0.8) -> SideFigures:
    return SideFigures(
        latency_p50=latency_p50,
        latency_p99=latency_p50 + 2.0,
        frame_handoff_p50=handoff,
        distribution_adds_p50=adds,
        real_time_factor=3.5,
        load_start=[0.5, 0.6, 0.7],
    )


def report(*pairs: tuple[SideFigures, SideFigures]) -> AlternationReport:
    machine = load_json(LOCKSTEP_JSON).machine
    return AlternationReport(
        command="umay bench --alternate supervisor.cpu_wakeup_latency_us=0",
        change="supervisor.cpu_wakeup_latency_us=0",
        machine=machine,
        pairs=[Pair(without=a, with_change=b) for a, b in pairs],
    )


def test_a_sides_figures_are_the_reports_pooled_headline() -> None:
    bench = load_json(LOCKSTEP_JSON)  # three runs: pooled latency, medians otherwise
    figures = side_figures(bench)
    assert bench.distributed.pooled is not None
    assert figures.latency_p50 == bench.distributed.pooled.latency_ms.p50
    assert figures.latency_p99 == bench.distributed.pooled.latency_ms.p99
    assert figures.frame_handoff_p50 == bench.distributed.pooled.frame_handoff_ms.p50
    assert figures.distribution_adds_p50 == bench.distribution_adds_ms.p50
    assert figures.real_time_factor == bench.distributed.real_time_factor
    one = bench.each_run[0]  # a single run: its own latency
    assert side_figures(one).latency_p50 == one.distributed.latency_ms.p50


def test_pairs_are_counted_by_the_way_each_moved() -> None:
    r = report(
        (side(6.5, 3.3), side(6.2, 2.8)),
        (side(7.0, 3.7), side(6.3, 2.9)),
        (side(6.6, 3.3), side(6.7, 2.8, handoff=None)),
    )
    assert same_way(r, "latency_p50") == "2 of 3 down"
    assert same_way(r, "distribution_adds_p50") == "3 of 3 down"
    assert same_way(r, "frame_handoff_p50") == "none of 2 moved"  # a missing figure: no pair
    steady = report((side(6.5, 3.3), side(6.5001, 3.2999)))  # moves too small to show
    assert same_way(steady, "latency_p50") == "none of 1 moved"
    assert same_way(steady, "latency_p50", ".4f") == "1 of 1 up"
    split = report((side(6.5, 3.3), side(6.2, 3.3)), (side(6.5, 3.3), side(6.8, 3.3)))
    assert same_way(split, "latency_p50") == "1 of 2 down, 1 up"  # no majority either way
    rows = {row[0]: row for row in comparison_rows(r)}
    latency = rows["latency p50, all frames (ms)"]
    assert latency[1:] == ["6.50 / 7.00 / 6.60", "6.20 / 6.30 / 6.70", "2 of 3 down"]
    assert rows["frame publish + transport p50 (ms)"][2] == "0.80 / 0.80 / –"
    text = format_alternation(r)
    assert text.startswith("3 pairs, each without then with supervisor.cpu_wakeup_latency_us=0")
    assert "6.50 / 7.00 / 6.60  ->  6.20 / 6.30 / 6.70   (2 of 3 down)" in text
    line = format_side(side(6.5, 3.3, handoff=None))
    assert line.startswith("latency p50, all frames (ms) 6.50, latency p99, all frames (ms) 8.50")
    assert "frame publish + transport p50 (ms) –" in line


def test_the_report_round_trips_and_the_docs_block_renders_it(tmp_path: Path) -> None:
    r = report((side(6.5, 3.3), side(6.2, 2.8)))
    path = tmp_path / "cpu_wakeup_latency_0.json"
    write_alternation(r, path)
    again = load_alternation(json.loads(path.read_text()))
    assert again == r
    block = BLOCKS["bench-alternations"].render(
        Inputs(alternations=[("cpu_wakeup_latency_0", again)]), "docs"
    )
    assert "[`cpu_wakeup_latency_0`](bench/alternations/cpu_wakeup_latency_0.json)" in block
    assert "| figure | without | with `supervisor.cpu_wakeup_latency_us=0` | pairs |" in block
    assert "| what distribution adds, p50 (ms) | 3.30 | 2.80 | 1 of 1 down |" in block
    assert "No alternation" in BLOCKS["bench-alternations"].render(Inputs(), "")


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (
            ["--alternate", "supervisor.cpu_wakeup_latency_us=-1"],
            "supervisor.cpu_wakeup_latency_us",
        ),
        (
            ["--alternate", "supervisor.cpu_wakeup_latency_us=0", "--pairs", "0"],
            "--pairs: '0': a whole number, at least 1",
        ),
        (["--pairs", "3"], "--pairs counts the pairs of --alternate: give it too"),
        (["--alternate", "x.y=1", "--figure", "out.png"], "no --figure or --view"),
    ],
)
def test_a_bad_alternation_is_refused_before_anything_runs(
    argv: list[str], says: str, umay_cli
) -> None:
    refused = umay_cli("bench", *argv)  # a process started or a session opened fails it
    assert refused.returncode == 2
    assert says in refused.stderr
