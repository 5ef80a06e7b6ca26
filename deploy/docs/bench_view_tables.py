"""The loop watched (``umay bench --view``, ``docs/bench/view/*.json``): its figures without and
with a live view and a Foxglove client, in pairs."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from statistics import median
from typing import Any

from deploy.bench.goals import HOST_FIGURES
from deploy.docs.bench_cells import code_cell, cpu_cell, measured, num
from deploy.docs.sources import VIEW_DIR, BenchRun, DocsError, Inputs
from deploy.markdown import link, markdown_table

VIEW_NOT_RUN = (
    "*Not run yet: `umay bench --frames 60 --repeat 3 --no-reference --synthetic-frames 0 "
    "--json docs/bench/view/without.json`, then the same with `--view` and "
    "`--json docs/bench/view/with.json`.*"
)


def view_pairs(runs: Sequence[BenchRun]) -> list[tuple[BenchRun, BenchRun]]:
    """The runs of ``docs/bench/view/`` in pairs, in name order: ``without<suffix>`` (no view)
    and ``with<suffix>``, the same command with ``--view``; :class:`DocsError` for a run out of
    a pair or a pair that is not that."""
    by_name = {r.name: r for r in runs}
    pairs = []
    for r in runs:
        if not r.name.startswith("without"):
            continue
        suffix = r.name.removeprefix("without")
        partner = by_name.get(f"with{suffix}")
        if partner is None:
            raise DocsError(f"{r.path} has no {VIEW_DIR}/with{suffix}.json beside it")
        for run, view in ((r, False), (partner, True)):
            if bool(run.data["config"].get("view")) is not view:
                said = "with" if view else "without"
                raise DocsError(f"{run.path} was not run {said} --view (its config.view)")
        words = measured(partner.data["command"])
        if [w for w in words if w != "--view"] != measured(r.data["command"]):
            raise DocsError(
                f"{partner.path} was made by `{partner.data['command']}`, not by "
                f"`{r.data['command']}` with --view"
            )
        pairs.append((r, partner))
    paired = {run.name for pair in pairs for run in pair}
    lone = [r.path for r in runs if r.name not in paired]
    if lone:
        raise DocsError(f"{', '.join(lone)}: not in a pair of without<suffix> and with<suffix>")
    return pairs


def _client_messages(data: Mapping[str, Any]) -> float | None:
    """Messages the bench's Foxglove client read in a run, when watched: the median of the
    runs' totals (the report's own figure is per channel, each its median, whose sum is no
    run's total)."""
    totals = [
        float(sum(got.values()))
        for run in data.get("each_run") or [data]
        if (got := (run["distributed"].get("observer") or {}).get("client_messages")) is not None
    ]
    return float(median(totals)) if totals else None


# (words, figure of a run, format) of the view block's rows.
# The goals' figures, as a run's JSON gives them (deploy/bench/goals.py).
_OF = {f.words: f.of for f in HOST_FIGURES}
VIEW_FIGURES: tuple[tuple[str, Callable[[Mapping[str, Any]], float | None], str], ...] = (
    ("latency p50, all frames (ms)", _OF["latency p50"], ".2f"),
    ("latency p99, all frames (ms)", _OF["latency p99"], ".2f"),
    (
        "frame transport p50 (ms)",
        lambda d: d["distributed"]["stages_ms"]["frame_transport"]["p50"],
        ".2f",
    ),
    ("frame publish + transport p50 (ms)", _OF["frame publish + transport"], ".2f"),
    ("what distribution adds, p50 (ms)", _OF["what distribution adds"], ".2f"),
    ("real-time factor", _OF["real-time factor"], ".2f"),
    ("messages the Foxglove client read, per run", _client_messages, ".0f"),
)


def moved(pairs: Sequence[tuple[float | None, float | None]], fmt: str) -> str:
    """How many pairs moved a figure the way most did: "3 of 3 up" (as ``umay bench
    --alternate`` counts them: values compared as shown, a pair missing one side not
    counted)."""
    from deploy.bench.alternate import pairs_moved

    if not any(o is not None and w is not None for o, w in pairs):
        return "–"
    return pairs_moved(pairs, fmt)


def bench_view(inputs: Inputs, here: str) -> str:
    """The loop without and with a live view and a Foxglove client (``umay bench --view``), in
    pairs run one right after the other: per figure its value in every pair on each side and
    how many pairs moved it the same way; then the runs and their commands."""
    pairs = view_pairs(inputs.view)
    if not pairs:
        return VIEW_NOT_RUN
    body = []
    for words, figure, fmt in VIEW_FIGURES:
        sides = [[figure(run.data) for run in side] for side in zip(*pairs, strict=True)]
        body.append(
            [
                words,
                " / ".join(num(v, fmt) for v in sides[0]),
                " / ".join(num(v, fmt) for v in sides[1]),
                moved(list(zip(*sides, strict=True)), fmt),
            ]
        )
    runs = [run for pair in pairs for run in pair]
    listed = ", ".join(
        f"[`{a.name}`]({link(here, a.path)}) → [`{b.name}`]({link(here, b.path)})" for a, b in pairs
    )
    loads = [(r.data["machine"].get("load_start") or [None])[0] for r in runs]
    known = [v for v in loads if v is not None]
    load = f"{num(min(known))}–{num(max(known))}" if known else "not recorded"
    codes = list(dict.fromkeys(code_cell(r.data["machine"]) for r in runs))
    machines = list(
        dict.fromkeys(f"{r.data['machine']['cpus']} × {cpu_cell(r.data['machine'])}" for r in runs)
    )
    caption = (
        f"{len(pairs)} pair{'s' if len(pairs) != 1 else ''}, each without then with the view, one "
        f"right after the other: {listed}; {', '.join(machines)}, load "
        f"{load}, code {', '.join(codes)}."
    )
    commands = "\n".join(r.data["command"] for r in runs)
    table = markdown_table(
        ["figure", "without a view", "with `umay view` and a client", "pairs"], body, right_from=1
    )
    return f"{caption}\n\n{table}\n\n```sh\n{commands}\numay docs\n```"
