"""The default lockstep run again, on each host it was measured on and in repeated runs
(``docs/bench/hosts/``): hosts of one machine class (2 × x86_64 VMs, the same image) run the
four-process loop at different speeds, and one host from one run to the next, so issue 26's
latency goals are met on some hosts and in some runs and not in others."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from deploy.bench.goals import (
    ADDS_GOAL,
    HANDOFF_GOAL,
    HOST_FIGURES,
    LATENCY_P50_GOAL,
    LATENCY_P99_GOAL,
    REAL_TIME_GOAL,
)
from deploy.docs.bench_cells import code_cell, load_cell, measured
from deploy.docs.sources import BENCH_DIR, LOCKSTEP_RUN, BenchRun, DocsError, Inputs
from deploy.markdown import link, markdown_table

__all__ = ["HEADERS", "bench_hosts", "within_goals"]

HEADERS = [
    "run",
    "CPU",
    "code",
    "load",
    f"real-time factor ({REAL_TIME_GOAL})",
    f"frame publish + transport p50 ({HANDOFF_GOAL})",
    f"latency p50 / p99 ({LATENCY_P50_GOAL} / {LATENCY_P99_GOAL})",
    f"distribution adds ({ADDS_GOAL})",
]


def _row(here: str, run: BenchRun) -> list[str]:
    d = run.data
    m = d["machine"]
    rtf, handoff, p50, p99, adds = (f.goal.shown(f.of(d)) for f in HOST_FIGURES)
    return [
        f"[`{link(BENCH_DIR, run.path).removesuffix('.json')}`]({link(here, run.path)})",
        m.get("cpu_model") or "not recorded",
        code_cell(m),
        load_cell(m),
        rtf,
        handoff,
        f"{p50} / {p99}",
        adds,
    ]


def within_goals(reports: list[Mapping[str, Any]]) -> str:
    """How many of the runs have each figure within its goal."""
    counts = [(f.words, sum(f.goal.met(f.of(d)) for d in reports)) for f in HOST_FIGURES]
    said = ", ".join(f"{words} {n}" for words, n in counts)
    return f"Runs within each goal, of {len(reports)}: {said}."


def bench_hosts(inputs: Inputs, here: str) -> str:
    """The headline run (``docs/bench/lockstep_640x480.json``) and the same command's other
    runs, one row each: CPU, code, load and the figures whose goals depend on the host; then
    how many runs are within each goal."""
    runs = [inputs.run(LOCKSTEP_RUN), *inputs.hosts]
    for r in runs[1:]:
        if measured(r.data["command"]) != measured(runs[0].data["command"]):
            raise DocsError(
                f"{r.path} was made by `{r.data['command']}`, not by the headline run's "
                f"`{runs[0].data['command']}`: a host's row must be the same command"
            )
    return (
        markdown_table(HEADERS, [_row(here, r) for r in runs], right_from=3)
        + "\n\n"
        + within_goals([r.data for r in runs])
        + " Times in ms; each row is `"
        + runs[0].data["command"]
        + "` (a row under `hosts/` was made by it in another run, on this host or another, its "
        "JSON written there or moved there)."
    )
