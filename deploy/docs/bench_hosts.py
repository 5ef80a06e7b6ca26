"""The default lockstep run again, on each host it was measured on and in repeated runs
(``docs/bench/hosts/``): hosts of one machine class (2 × x86_64 VMs, the same image) run the
four-process loop at different speeds, and one host from one run to the next, so issue 26's
latency goals are met on some hosts and in some runs and not in others."""

from __future__ import annotations

import shlex

from deploy.docs.bench_tables import (
    code_cell,
    frame_handoff_ms,
    latency,
    link,
    load_cell,
    num,
)
from deploy.docs.sources import BENCH_DIR, LOCKSTEP_RUN, BenchRun, DocsError, Inputs
from deploy.experiments.compare.summary import markdown_table

HEADERS = [
    "run",
    "CPU",
    "code",
    "load",
    "real-time factor (≥ 2.5)",
    "frame publish + transport p50 (≤ 0.5)",
    "latency p50 / p99 (≤ 6 / ≤ 9)",
    "distribution adds (≤ 2.0)",
]


def _row(here: str, run: BenchRun) -> list[str]:
    d = run.data
    m = d["machine"]
    lat, _ = latency(d)
    return [
        f"[`{link(BENCH_DIR, run.path).removesuffix('.json')}`]({link(here, run.path)})",
        m.get("cpu_model") or "not recorded",
        code_cell(m),
        load_cell(m),
        num(d["distributed"]["real_time_factor"]),
        num(frame_handoff_ms(d)),
        f"{num(lat['p50'])} / {num(lat['p99'])}",
        num(d["distribution_adds_ms"]["p50"]),
    ]


def measured(command: str) -> list[str]:
    """A bench command's words but where it wrote its JSON (``--json PATH``): what was run."""
    words = shlex.split(command)
    if "--json" in words:
        at = words.index("--json")
        del words[at : at + 2]
    return words


def bench_hosts(inputs: Inputs, here: str) -> str:
    """The headline run (``docs/bench/lockstep_640x480.json``) and the same command's other
    runs, one row each: CPU, code, load and the figures whose goals depend on the host."""
    runs = [inputs.run(LOCKSTEP_RUN), *inputs.hosts]
    for r in runs[1:]:
        if measured(r.data["command"]) != measured(runs[0].data["command"]):
            raise DocsError(
                f"{r.path} was made by `{r.data['command']}`, not by the headline run's "
                f"`{runs[0].data['command']}`: a host's row must be the same command"
            )
    return (
        markdown_table(HEADERS, [_row(here, r) for r in runs], right_from=3)
        + "\n\nTimes in ms; each row is `"
        + runs[0].data["command"]
        + "` (a row under `hosts/` was made by it in another run, on this host or another, its "
        "JSON written there or moved there)."
    )
