"""The bench's generated counts and tables beside the headline's: the runs within each goal
(bench-hosts), the pairs within each goal (bench-alternations), the headline run stage by stage
(bench-stages) and the loop without and with a live view (bench-view), each from its JSON."""

from __future__ import annotations

import copy
import json
import shutil
from pathlib import Path
from typing import Any

import pytest

from deploy.bench.alternate import AlternationReport, Pair, SideFigures
from deploy.bench.goals import ADDS_GOAL, HANDOFF_GOAL, LATENCY_P50_GOAL, REAL_TIME_GOAL
from deploy.cli import main
from deploy.docs.bench_alternation_tables import alternation_summary
from deploy.docs.bench_view_tables import view_pairs
from deploy.docs.blocks import BLOCKS
from deploy.docs.documents import END
from deploy.docs.sources import (
    HOSTS_DIR,
    LOCKSTEP_RUN,
    REPO_ROOT,
    RESULTS_JSON,
    VIEW_DIR,
    BenchRun,
    DocsError,
    Inputs,
)
from tests.unit.test_docs import _bench, _stage

VIEW_COMMAND = "umay bench --frames 60 --repeat 3 --no-reference --synthetic-frames 0"


def test_a_goal_is_met_by_the_figure_and_shown_on_its_side_of_the_limit() -> None:
    assert (str(HANDOFF_GOAL), str(ADDS_GOAL), str(REAL_TIME_GOAL)) == ("≤ 0.5", "≤ 2.0", "≥ 2.5")
    assert not HANDOFF_GOAL.met(0.5041) and HANDOFF_GOAL.met(0.5)
    assert HANDOFF_GOAL.shown(0.5041) == "0.504"  # not "0.50", which would read as met
    assert HANDOFF_GOAL.shown(0.50004) == "0.50004" and HANDOFF_GOAL.shown(0.4321) == "0.43"
    assert REAL_TIME_GOAL.met(2.5) and not REAL_TIME_GOAL.met(2.4999)
    assert REAL_TIME_GOAL.shown(2.4999) == "2.4999" and REAL_TIME_GOAL.shown(None) == "–"
    assert not LATENCY_P50_GOAL.met(None)  # not measured: not within


def test_the_hosts_block_counts_the_runs_within_each_goal() -> None:
    fast, slow = _bench(), _bench()  # hand-off 0.75, latency 6 / 12, adds 2.0, RTF 2.0
    fast["distributed"]["real_time_factor"] = 4.0
    fast["distributed"]["stages_ms"]["frame_transport"] = _stage(0.2)
    slow["distribution_adds_ms"] = {"p50": 2.44, "parts_p50": {}}
    inputs = Inputs(bench=[BenchRun(LOCKSTEP_RUN, fast)], hosts=[BenchRun("slow", slow, HOSTS_DIR)])
    table = BLOCKS["bench-hosts"].render(inputs, "docs")
    assert (
        "Runs within each goal, of 2: real-time factor 1, frame publish + transport 1, "
        "latency p50 2, latency p99 0, what distribution adds 1." in table
    )


def _side(p50: float, p99: float, adds: float, handoff: float, rtf: float) -> SideFigures:
    return SideFigures(
        latency_p50=p50,
        latency_p99=p99,
        frame_handoff_p50=handoff,
        distribution_adds_p50=adds,
        real_time_factor=rtf,
        load_start=[0.5],
    )


def test_an_alternation_says_how_many_pairs_are_within_each_goal_and_their_medians() -> None:
    machine = json.loads((REPO_ROOT / f"docs/bench/{LOCKSTEP_RUN}.json").read_text())["machine"]
    pairs = [
        Pair(without=_side(6.5, 9.5, 3.0, 0.9, 3.0), with_change=_side(5.5, 8.0, 2.0, 0.6, 4.0)),
        Pair(without=_side(7.0, 8.5, 3.4, 1.0, 3.2), with_change=_side(6.2, 8.2, 2.6, 0.7, 4.2)),
    ]
    change = "supervisor.cpu_wakeup_latency_us=0"
    lockstep = AlternationReport(
        command=f"umay bench --alternate {change}", change=change, machine=machine, pairs=pairs
    )
    line = alternation_summary(lockstep)
    assert line.startswith(
        "Pairs within each goal, of 2, without → with: latency p50 ≤ 6 ms 0 → 1, p99 ≤ 9 ms 1 → 2, "
        "what distribution adds ≤ 2.0 ms 0 → 1, frame publish + transport ≤ 0.5 ms 0 → 0, "
        "real-time factor ≥ 2.5 2 → 2."
    )
    assert "Medians of the pairs, without → with: latency p50 6.75 → 5.85 ms" in line
    assert "real-time factor 3.10 → 4.10." in line
    realtime = lockstep.model_copy(
        update={"command": f"umay bench --mode realtime --alternate {change}"}
    )
    line = alternation_summary(realtime)  # the real-time factor's goal is lockstep's
    assert "≥ 2.5" not in line and "real-time factor 3.10 → 4.10." in line
    block = BLOCKS["bench-alternations"].render(Inputs(alternations=[("x", lockstep)]), "docs")
    assert block.endswith("| 2 of 2 up |\n\n" + alternation_summary(lockstep))  # under its table


def test_the_stages_block_sets_each_stage_against_the_same_function_in_one_process() -> None:
    data = _bench()
    data["distributed"]["stages_ms"].update(controller=_stage(0.9), features_transport=_stage(0.2))
    data["inprocess"]["stages_ms"] = {
        "vision": _stage(2.5),
        "controller": _stage(0.6),
        "frame_codec": _stage(0.3),
        "features_codec": _stage(0.04),
        "vision_warm": _stage(2.0),
    }
    data["distribution_adds_ms"] = {
        "p50": 2.0,
        "parts_p50": {"publish": 0.25, "vision": 0.5, "features_transport": 0.2, "controller": 0.3},
    }
    out = BLOCKS["bench-stages"].render(Inputs(bench=[BenchRun(LOCKSTEP_RUN, data)]), "docs")
    assert "| publish | 0.25 | – | 0.25 |" in out
    assert "| vision | 3.00 | 2.50 | 0.50 |" in out
    assert "| features transport | 0.20 | – | 0.20 |" in out
    assert "| controller | 0.90 | 0.60 | 0.30 |" in out
    assert "| latency, frame captured → command applied | 6.00 | 4.00 | 2.00 |" in out
    assert "the frame's (the joint state, the depth image, the colour frame) 0.30" in out
    assert "the features' 0.04 ms." in out  # codecs not timed are left out
    assert "p50 2.00 ms, against 2.50 ms right after the render" in out
    assert f"(bench/{LOCKSTEP_RUN}.json)" in out


# --- umay bench --view ---------------------------------------------------------------------------
def _view_run(view: bool, suffix: str = "", transport_ms: float = 0.5) -> dict[str, Any]:
    data = _bench(view=view)
    name = f"{'with' if view else 'without'}{suffix}"
    data["command"] = f"{VIEW_COMMAND}{' --view' if view else ''} --json {VIEW_DIR}/{name}.json"
    data["machine"] = {**data["machine"], "load_start": [0.4], "code": "abc1234567"}
    data["distributed"]["stages_ms"]["frame_transport"] = _stage(transport_ms)
    if view:
        data["distributed"]["observer"] = {"client_messages": {"/tf": 15, "/log": 5}}
    return data


def _view_inputs(*runs: tuple[str, dict[str, Any]]) -> Inputs:
    return Inputs(view=[BenchRun(name, data, VIEW_DIR) for name, data in sorted(runs)])


def test_the_view_block_sets_each_pair_without_and_with_the_view_side_by_side() -> None:
    inputs = _view_inputs(
        ("without", _view_run(False)),
        ("with", _view_run(True, transport_ms=0.7)),
        ("without_run2", _view_run(False, "_run2", transport_ms=0.4)),
        ("with_run2", _view_run(True, "_run2", transport_ms=0.6)),
    )
    assert [(a.name, b.name) for a, b in view_pairs(inputs.view)] == [
        ("without", "with"),
        ("without_run2", "with_run2"),
    ]
    out = BLOCKS["bench-view"].render(inputs, "docs")
    assert out.startswith(
        "2 pairs, each without then with the view, one right after the other: "
        "[`without`](bench/view/without.json) → [`with`](bench/view/with.json), "
        "[`without_run2`](bench/view/without_run2.json) → [`with_run2`](bench/view/with_run2.json)"
        "; 2 × x86_64, load 0.40–0.40, code `abc1234567`."
    )
    assert "| figure | without a view | with `umay view` and a client | pairs |" in out
    assert "| latency p50, all frames (ms) | 6.00 / 6.00 | 6.00 / 6.00 | none of 2 moved |" in out
    assert "| latency p99, all frames (ms) | 12.00 / 12.00 | 12.00 / 12.00 |" in out
    assert "| frame transport p50 (ms) | 0.50 / 0.40 | 0.70 / 0.60 | 2 of 2 up |" in out
    assert "| frame publish + transport p50 (ms) | 0.75 / 0.65 | 0.95 / 0.85 | 2 of 2 up |" in out
    assert "| what distribution adds, p50 (ms) | 2.00 / 2.00 | 2.00 / 2.00 |" in out
    assert "| messages the Foxglove client read, per run | – / – | 20 / 20 | – |" in out
    commands = out[out.index("```sh\n") :].splitlines()[1:-1]
    assert commands == [
        f"{VIEW_COMMAND} --json {VIEW_DIR}/without.json",
        f"{VIEW_COMMAND} --view --json {VIEW_DIR}/with.json",
        f"{VIEW_COMMAND} --json {VIEW_DIR}/without_run2.json",
        f"{VIEW_COMMAND} --view --json {VIEW_DIR}/with_run2.json",
        "umay docs",
    ]
    assert "Not run yet" in BLOCKS["bench-view"].render(Inputs(), "docs")


@pytest.mark.parametrize(
    ("runs", "says"),
    [
        ((("without", _view_run(False)),), r"without\.json has no docs/bench/view/with\.json"),
        (
            (("without", _view_run(False)), ("with", _view_run(False))),
            r"with\.json was not run with --view",
        ),
        (
            (("without", _view_run(True)), ("with", _view_run(True))),
            r"without\.json was not run without --view",
        ),
        (
            (("without", _view_run(False)), ("with", _view_run(True)), ("other", _view_run(True))),
            r"other\.json: not in a pair",
        ),
    ],
)
def test_a_view_run_out_of_a_pair_is_refused(
    runs: tuple[tuple[str, dict[str, Any]], ...], says: str
) -> None:
    with pytest.raises(DocsError, match=says):
        BLOCKS["bench-view"].render(_view_inputs(*runs), "docs")


def test_a_view_pair_must_be_the_same_command_but_view() -> None:
    other = _view_run(True)
    other["command"] = f"{VIEW_COMMAND} --frames 30 --view --json {VIEW_DIR}/with.json"
    with pytest.raises(DocsError, match=r"with\.json was made by `umay bench"):
        view_pairs(_view_inputs(("without", _view_run(False)), ("with", other)).view)


def test_umay_docs_check_catches_a_stale_view_table(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "docs" / "results").mkdir(parents=True)
    shutil.copy(REPO_ROOT / RESULTS_JSON, tmp_path / RESULTS_JSON)
    view = tmp_path / VIEW_DIR
    view.mkdir(parents=True)
    with_view = _view_run(True, transport_ms=0.7)
    (view / "without.json").write_text(json.dumps(_view_run(False)))
    (view / "with.json").write_text(json.dumps(with_view))
    doc = tmp_path / "docs" / "foxglove.md"
    doc.write_text(f"# Foxglove\n<!-- generated: bench-view -->\nold\n{END}\n")

    assert main(["docs", "--check", "--root", str(tmp_path)]) == 1
    assert main(["docs", "--root", str(tmp_path)]) == 0
    assert main(["docs", "--check", "--root", str(tmp_path)]) == 0
    assert "| frame transport p50 (ms) | 0.50 | 0.70 | 1 of 1 up |" in doc.read_text()

    again = copy.deepcopy(with_view)
    again["distributed"]["stages_ms"]["frame_transport"] = _stage(0.3)  # re-run: JSON changed
    (view / "with.json").write_text(json.dumps(again))
    capsys.readouterr()
    assert main(["docs", "--check", "--root", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert f"docs/foxglove.md: block 'bench-view' differs from {VIEW_DIR}/*.json" in err
    assert main(["docs", "--root", str(tmp_path)]) == 0
    assert "| frame transport p50 (ms) | 0.50 | 0.30 | 1 of 1 down |" in doc.read_text()
