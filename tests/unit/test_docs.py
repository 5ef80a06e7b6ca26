"""``umay docs``: the generated tables of README.md and docs/*.md agree with their JSON, and the
rendering and the block markers behave (deploy/docs/)."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path
from typing import Any

import pytest

from deploy.bench.goals import frame_handoff_ms, latency
from deploy.cli import main
from deploy.docs.bench_cells import run_label
from deploy.docs.bench_tables import (
    bench_commands,
    bench_distribution,
    bench_dropped,
    bench_latency,
    bench_render,
    bench_startup,
)
from deploy.docs.blocks import BLOCKS
from deploy.docs.documents import END, Outdated, documents, find_blocks, rewrite, update
from deploy.docs.results_tables import results_compact
from deploy.docs.sources import (
    CPU_WAKEUP_RUN,
    KINECT_LOCKSTEP_RUN,
    KINECT_REALTIME_RUN,
    LOCKSTEP_RUN,
    REPO_ROOT,
    RESULTS_JSON,
    STARTUP_DIR,
    STARTUP_FRAMES,
    BenchRun,
    DocsError,
    Inputs,
)
from deploy.experiments.compare.rows import rows_from_json
from deploy.experiments.compare.summary import strategy_table, summarize_modes
from deploy.markdown import link


def test_every_generated_table_agrees_with_its_json() -> None:
    """The repository's README and docs: every block is what its JSON gives (else run
    ``umay docs`` and commit)."""
    assert [str(o) for o in update(REPO_ROOT, check=True)] == []


def test_the_docs_have_generated_blocks_and_link_inside_the_repository() -> None:
    names = {b.name for p in documents(REPO_ROOT) for b in find_blocks(p.read_text())}
    assert {"results-compact", "bench-headline", "bench-commands", "bench-latency"} <= names
    for p in documents(REPO_ROOT):
        assert "../shared" not in p.read_text(), p


def _anchors(markdown: str) -> set[str]:
    """GitHub's heading anchors: lower case, punctuation dropped, spaces to hyphens."""
    headings = re.findall(r"^#+ (.+)$", markdown, flags=re.MULTILINE)
    return {re.sub(r"[^\w\- ]", "", h.lower()).replace(" ", "-") for h in headings}


def test_relative_links_of_the_docs_exist() -> None:
    for doc in documents(REPO_ROOT):
        for target in re.findall(r"\]\(([^)\s]+)\)", doc.read_text()):
            path, _, anchor = target.partition("#")
            if "://" in path:
                continue
            linked = doc.parent / path if path else doc
            assert linked.exists(), f"{doc.name}: {target}"
            if anchor:
                assert anchor in _anchors(linked.read_text()), f"{doc.name}: {target}"


def test_readme_is_short() -> None:
    assert len((REPO_ROOT / "README.md").read_text().splitlines()) <= 250


# --- markers -----------------------------------------------------------------------------------
def _doc(name: str, body: str = "old") -> str:
    return f"before\n<!-- generated: {name} -->\n{body}\n{END}\nafter\n"


def test_find_blocks_in_order() -> None:
    text = _doc("results-compact") + _doc("bench-runs")
    assert [b.name for b in find_blocks(text)] == ["results-compact", "bench-runs"]
    first = find_blocks(text)[0]
    assert text[first.start : first.end] == "\nold\n"


@pytest.mark.parametrize(
    ("text", "says"),
    [
        (_doc("no-such-block"), "unknown block 'no-such-block'"),
        ("<!-- generated: bench-runs -->\nno end\n", "has no"),
        ("<!-- generated: bench-runs -->\n" + _doc("bench-runs"), "has no"),
        (f"text\n{END}\n", "line 2"),
    ],
)
def test_malformed_markers_are_refused(text: str, says: str) -> None:
    with pytest.raises(DocsError, match=says):
        find_blocks(text)


def _results() -> list:
    return rows_from_json((REPO_ROOT / RESULTS_JSON).read_text())


def test_rewrite_changes_only_the_blocks_and_is_idempotent() -> None:
    inputs = Inputs(results=_results())
    text = "# Title\n\nprose stays\n" + _doc("results-compact") + "tail\n"
    new, changed = rewrite(text, inputs, "")
    assert changed == ["results-compact"]
    assert new.startswith("# Title\n\nprose stays\nbefore\n<!-- generated: results-compact -->\n")
    assert new.endswith(f"{END}\nafter\ntail\n")
    assert "\nold\n" not in new
    again, changed_again = rewrite(new, inputs, "")
    assert (again, changed_again) == (new, [])


# --- the comparison ----------------------------------------------------------------------------
def test_results_table_is_compare_s_own_with_fewer_columns() -> None:
    rows = _results()
    out = results_compact(Inputs(results=rows), "docs")
    full = strategy_table(summarize_modes(rows, ["constant", "dynamic"]))
    constant = next(line for line in full.splitlines() if line.startswith("| constant |"))
    cells = constant.split(" | ")
    # Same strategy counts and path ratio as summary.md's table; link relative to docs/.
    mine = next(line for line in out.splitlines() if line.startswith("| constant |"))
    assert mine.split(" | ")[1:3] == cells[1:3]
    headers = full.splitlines()[0].split(" | ")
    assert cells[headers.index("path ratio")] in mine.split(" | ")
    assert "(results/results.json)" in out
    assert out.splitlines()[1].count("---") == len(out.splitlines()[0].split(" | "))


# --- the benchmark -----------------------------------------------------------------------------
def _stage(p50: float | None) -> dict[str, Any]:
    return {"n": 10, "p50": p50, "p99": None if p50 is None else 2 * p50, "max": p50}


def _bench(**config: Any) -> dict[str, Any]:
    stages = {
        "render": _stage(5.0),
        "publish": _stage(0.25),
        "frame_transport": _stage(0.5),
        "vision": _stage(3.0),
    }
    services = {
        s: {"peak_rss_mb": 100.0, "cpu_ms_per_frame": 1.0}
        for s in ("sim", "vision", "controller", "actuation")
    }
    dropped = {"camera": 0, "vision": 0, "controller": 0, "actuation": 0}
    return {
        "command": "umay bench --frames 10",
        "machine": {"cpus": 2, "processor": "x86_64", "python": "3.11", "zenoh": "1.10.2"},
        "config": {
            "width_px": 640,
            "height_px": 480,
            "depth_width_px": 640,
            "depth_height_px": 480,
            "rgb_hz": 30.0,
            "clock": "lockstep",
            "renderer": "gl",
            "transport": "shm",
            "frames": 10,
            "overrides": [],
            **config,
        },
        "distributed": {
            "stages_ms": stages,
            "latency_ms": _stage(6.0),
            "frames_over_goal": 1,
            "loop_rate_hz": 60.0,
            "real_time_factor": 2.0,
            "dropped": dropped,
            "services": services,
        },
        "inprocess": {"per_frame_ms": _stage(4.0)},
        "distribution_adds_ms": {"p50": 2.0, "parts_p50": {"publish": 0.25, "vision": 0.5}},
        "render": {
            "renderers": {
                "gl": {"renderer": "gl", "detail": "llvmpipe", "render_ms": _stage(3.0)},
                "tiny": {"renderer": "tiny", "detail": "TinyRenderer", "render_ms": _stage(90.0)},
            },
            "sensor_model": {
                "colour_px": [640, 480],
                "depth_px": [640, 480],
                "colour_ms": _stage(1.0),
                "depth_ms": _stage(2.0),
                "total_ms": _stage(3.0),
            },
        },
        "reference_renderer": {"renderer": "tiny", "loop_rate_hz": 10.0, "real_time_factor": 0.33},
        "synthetic": None,
    }


def test_run_label_says_what_a_run_is() -> None:
    assert run_label(_bench()) == "lockstep 640×480"
    kinect = _bench(
        depth_width_px=320,
        depth_height_px=240,
        clock="realtime",
        transport="tcp",
        overrides=["camera.kinect.enabled=true"],
    )
    assert run_label(kinect) == "realtime 640×480, depth 320×240, Kinect model, TCP"
    held = _bench()
    held["distributed"] = {**held["distributed"], "cpu_wakeup_latency": "held: 0 µs"}
    assert run_label(held) == "lockstep 640×480, CPU wake-up latency 0 µs"
    refused = _bench()
    refused["distributed"] = {**refused["distributed"], "cpu_wakeup_latency": "refused: x"}
    assert run_label(refused) == "lockstep 640×480"  # what the run had, not what it asked


def test_the_runs_table_names_the_code_and_cpu_each_run_measured_where_recorded() -> None:
    from deploy.docs.sources import BenchRun

    recorded, older = _bench(), _bench()
    cpu = "AMD EPYC (family 26, model 2)"
    recorded["machine"] = {**recorded["machine"], "code": "fd2f398abc", "cpu_model": cpu}
    table = BLOCKS["bench-runs"].render(
        Inputs(bench=[BenchRun("a", recorded), BenchRun("b", older)]), ""
    )
    rows = [line for line in table.splitlines() if line.startswith("| [")]
    assert rows[0].endswith("| `fd2f398abc` |") and rows[1].endswith("| not recorded |")
    assert f"| 2 × {cpu}, Python" in rows[0] and "| 2 × x86_64, Python" in rows[1]


def test_the_hosts_table_puts_the_same_command_on_each_host_side_by_side() -> None:
    from deploy.docs.sources import HOSTS_DIR, LOCKSTEP_RUN, BenchRun, DocsError

    here, there = _bench(), _bench()
    here["machine"] = {**here["machine"], "cpu_model": "AMD EPYC (family 26, model 2)"}
    there["distribution_adds_ms"] = {"p50": 3.15}
    inputs = Inputs(bench=[BenchRun(LOCKSTEP_RUN, here)], hosts=[BenchRun("old", there, HOSTS_DIR)])
    table = BLOCKS["bench-hosts"].render(inputs, "docs")
    rows = [line for line in table.splitlines() if line.startswith("| [")]
    assert rows[0].startswith(f"| [`{LOCKSTEP_RUN}`](bench/{LOCKSTEP_RUN}.json) | AMD EPYC")
    assert rows[1].startswith("| [`hosts/old`](bench/hosts/old.json) | not recorded |")
    assert rows[0].endswith("| 2.00 |") and rows[1].endswith("| 3.15 |")
    assert "| 0.75 | 6.00 / 12.00 |" in rows[0]  # hand-off: publish + transport; latency
    there["command"] = "umay bench --frames 60 --size 320x240"
    with pytest.raises(DocsError, match=r"hosts/old\.json was made by `umay bench --frames 60"):
        BLOCKS["bench-hosts"].render(inputs, "docs")


def test_figures_taken_from_the_json() -> None:
    one = _bench()
    assert frame_handoff_ms(one) == pytest.approx(0.75)
    assert latency(one) == (one["distributed"]["latency_ms"], 1)
    repeated = {**one, "runs": 3}
    repeated["distributed"] = {
        **one["distributed"],
        "pooled": {"latency_ms": _stage(7.0), "frames_over_goal": 4},
    }
    assert latency(repeated) == (_stage(7.0), 4)  # all frames of all runs, not the median


def test_bench_tables() -> None:
    inputs = Inputs(
        bench=[BenchRun("a_run", _bench()), BenchRun("b_run", _bench(clock="realtime"))]
    )
    rendered = bench_render(inputs, "docs")
    # The scenario's renderer drew the distributed loop, TinyRenderer the reference loop.
    assert "| a_run | gl | 3.00 | 6.00 | 60.0 | 2.00 |" in rendered
    assert "| a_run | tiny | 90.00 | 180.00 | 10.0 | 0.33 |" in rendered
    assert "`llvmpipe`" in rendered and "(bench/a_run.json)" in rendered
    lat = bench_latency(inputs, "")
    assert "| a_run | 10 | 0.75 | 6.00 | 6.00 | 12.00 | 6.00 | 1 | 4.00 | 2.00 |" in lat
    assert "(docs/bench/b_run.json)" in lat
    dist = bench_distribution(inputs, "docs")
    assert "| run | adds p50 | publish | vision |" in dist
    assert "| a_run | 2.00 | 0.25 | 0.50 |" in dist
    assert bench_commands(inputs, "docs").splitlines()[1:3] == ["umay bench --frames 10"] * 2


def test_dropped_counts_the_worst_run() -> None:
    data = _bench()
    data["dropped_max"] = {"distributed": {"camera": 3, "vision": 1, "controller": 0}}
    out = bench_dropped(Inputs(bench=[BenchRun("r", data)]), "docs")
    assert "| r | 3 | 1 / 0 / 0 | – |" in out


def test_link_is_relative_to_the_document() -> None:
    assert link("", "docs/bench/x.json") == "docs/bench/x.json"
    assert link("docs", "docs/bench/x.json") == "bench/x.json"
    assert link("docs", "README.md") == "../README.md"


def test_headline_against_the_goals() -> None:
    realtime = _bench(clock="realtime", frames=300)
    realtime["distributed"]["dropped"] = {"camera": 7, "vision": 1, "controller": 0}
    kinect = _bench()
    kinect["distributed"]["real_time_factor"] = 1.5
    kinect["distributed"]["services"]["sim"]["peak_rss_mb"] = 290.4
    runs = [
        BenchRun(LOCKSTEP_RUN, _bench()),
        BenchRun(KINECT_LOCKSTEP_RUN, kinect),
        BenchRun(KINECT_REALTIME_RUN, realtime),
    ]
    out = BLOCKS["bench-headline"].render(Inputs(bench=runs), "")
    assert "| 3.00 ms (90.00 ms) | ≤ 6 ms |" in out
    assert "| 2.00 (0.33) | ≥ 2.5 |" in out
    assert "| 1.50 | ≥ 2 |" in out
    assert (
        "300 frames: frames dropped" in out and "| 1; 7; 60.0 frames/s | 0; 0; 30 frames/s |" in out
    )
    assert "| 0.75 ms | ≤ 0.5 ms |" in out
    assert "| 6.00 / 12.00 ms |" in out and "| 2.00 ms | ≤ 2.0 ms |" in out
    assert "| 290 MiB |" in out
    assert "idle CPUs kept awake" not in out  # no such run: no row
    awake = _bench()
    awake["distributed"]["latency_ms"] = _stage(5.5)
    awake["distribution_adds_ms"] = {"p50": 1.75, "parts_p50": {}}
    out = BLOCKS["bench-headline"].render(
        Inputs(bench=[*runs, BenchRun(CPU_WAKEUP_RUN, awake)]), ""
    )
    assert "| 0.75 ms; 5.50 / 11.00 ms; 1.75 ms | ≤ 0.5 ms; ≤ 6 / ≤ 9 ms; ≤ 2.0 ms |" in out
    assert f"[`{CPU_WAKEUP_RUN}.json`]" in out


def test_a_missing_headline_run_is_named() -> None:
    with pytest.raises(DocsError, match=r"lockstep_640x480\.json is missing"):
        BLOCKS["bench-headline"].render(Inputs(), "")


# --- the command -------------------------------------------------------------------------------
def test_umay_docs_rewrites_then_check_names_the_block_that_differs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    results = tmp_path / RESULTS_JSON
    results.parent.mkdir(parents=True)
    shutil.copy(REPO_ROOT / RESULTS_JSON, results)
    (tmp_path / "docs" / "bench").mkdir()
    (tmp_path / "README.md").write_text(_doc("results-compact"))
    (tmp_path / "docs" / "results.md").write_text(_doc("results-strategies"))

    assert main(["docs", "--check", "--root", str(tmp_path)]) == 1
    assert "README.md: block 'results-compact' differs" in capsys.readouterr().err
    assert main(["docs", "--root", str(tmp_path)]) == 0
    assert main(["docs", "--check", "--root", str(tmp_path)]) == 0
    assert "| pmj | 12/12 | 12/12 |" in (tmp_path / "README.md").read_text()

    rows = json.loads(results.read_text())
    rows[0]["converged"] = rows[0]["on_goal"] = False  # constant on the baseline fails
    results.write_text(json.dumps(rows))
    capsys.readouterr()
    assert update(tmp_path, check=True) == [
        Outdated("README.md", "results-compact"),
        Outdated("docs/results.md", "results-strategies"),
    ]
    assert main(["docs", "--check", "--root", str(tmp_path)]) == 1
    err = capsys.readouterr().err
    assert "README.md: block 'results-compact' differs from docs/results/results.json" in err
    assert "docs/results.md: block 'results-strategies'" in err


def test_umay_docs_refuses_malformed_docs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "docs" / "results").mkdir(parents=True)
    shutil.copy(REPO_ROOT / RESULTS_JSON, tmp_path / RESULTS_JSON)
    (tmp_path / "README.md").write_text("<!-- generated: results-compact -->\n")
    assert main(["docs", "--check", "--root", str(tmp_path)]) == 2
    assert "README.md: line 1: block 'results-compact' has no" in capsys.readouterr().err


def test_domain_blocks_say_how_to_run_the_study_until_it_is_run() -> None:
    from deploy.docs.blocks import BLOCKS
    from deploy.docs.sources import DOMAINS_JSON
    from tests.unit.test_domains import small_study

    for name in ("domains-summary", "domains-bands", "domains-verdict"):
        assert "umay domains --out docs/domains" in BLOCKS[name].render(Inputs(), "")
    study = small_study()
    summary = BLOCKS["domains-summary"].render(Inputs(domains=study), "docs")
    assert "| mpj | 7 | 71% (5/7) | 15° |" in summary
    assert f"]({DOMAINS_JSON.removeprefix('docs/')})" in summary
    verdict = BLOCKS["domains-verdict"].render(Inputs(domains=study), "")
    assert "- **dynamic**: 86% (6/7) on goal" in verdict and "unturned starts only" in verdict
    assert "Rotations 0–45°: best dynamic (86% on goal)" in verdict
    for outcome, said in (("converged", "all 2 tie (100% on goal)"), ("failed", "no strategy")):
        runs = [r.model_copy(update={"outcome": outcome}) for r in study.runs]
        verdict = BLOCKS["domains-verdict"].render(
            Inputs(domains=study.model_copy(update={"runs": runs})), ""
        )
        assert f"Rotations 0–45°: {said}" in verdict, verdict
    assert "(docs/domains/figures/domain_mpj.png)" in verdict
    bands = BLOCKS["domains-bands"].render(Inputs(domains=study), "docs")
    assert "| start pose out of reach | 1 |" in bands


def test_the_executor_comparison_reports_the_overhead_and_whether_the_records_agree() -> None:
    from deploy.docs.blocks import BLOCKS
    from tests.unit.test_domains import small_study

    assert "Not measured yet: `umay domains" in BLOCKS["domains-executors"].render(Inputs(), "")
    jobs = small_study().model_copy(update={"executor": "--jobs 2", "wall_time_s": 10.0})
    dask = jobs.model_copy(update={"executor": "Dask local:2", "wall_time_s": 10.3})
    other = jobs.runs[0].model_copy(update={"frames": jobs.runs[0].frames + 1})
    changed = jobs.model_copy(update={"runs": [other, *jobs.runs[1:]], "executor": "x"})
    inputs = Inputs(executors=[("jobs2", jobs), ("dask_local2", dask), ("changed", changed)])
    table = BLOCKS["domains-executors"].render(inputs, "docs")
    n = len(jobs.runs)
    assert f"| `jobs2` | --jobs 2 | {n} | 10.0 | {10.0 / n:.3f} | +0.0% | yes |" in table
    assert f"| `dask_local2` | Dask local:2 | {n} | 10.3 | {10.3 / n:.3f} | +3.0% | yes |" in table
    assert "| `changed` | x |" in table and table.split("`changed`")[1].split("\n")[0].endswith(
        "no |"
    )


def test_the_campaign_block_counts_success_among_the_starts_run() -> None:
    from deploy.docs.blocks import BLOCKS

    assert "Not run yet: `umay campaign" in BLOCKS["campaign-summary"].render(Inputs(), "")
    runs = [
        {"start": "s1", "mode": "dynamic", "cause": "converged", "frames": 80, "path_ratio": 1.1},
        {"start": "s2", "mode": "dynamic", "cause": "joint limit", "frames": 900},
        {"start": "s3", "mode": "dynamic", "cause": "converged", "frames": 91, "path_ratio": 1.3},
        {"start": "s4", "mode": "dynamic", "cause": "refused at start"},
    ]
    table = BLOCKS["campaign-summary"].render(Inputs(campaign=runs), "docs")
    # medians over the runs on goal only
    assert "| dynamic | 3 | 66.7% (2/3) | 20.8–93.9% | 85.5 | 1.200 | joint limit 1 |" in table
    assert "[docs/campaign.md](campaign.md)" in table
    assert "4 starts, 1 refused at start (25.0%" in table
    assert "per_corner" not in table  # no per_corner campaign: no row
    per_corner = [
        {"start": "s1", "mode": "constant", "cause": "converged"},
        {"start": "s2", "mode": "constant", "cause": "local minimum (image error stalled)"},
        {"start": "s4", "mode": "constant", "cause": "refused at start"},
    ]
    from deploy.docs.sources import CampaignVariant

    variant = CampaignVariant("constant_per_corner", "constant, per_corner depths", per_corner)
    lift = CampaignVariant("constant_lift", "constant, clearance lifting", per_corner[:1], False)
    both = Inputs(campaign=runs, variants=[variant, lift])
    table = BLOCKS["campaign-summary"].render(both, "")
    row = "| constant, per_corner depths | 2 | 50.0% (1/2) | 9.5–90.5% | – | – | local minimum"
    assert row in table
    assert "clearance lifting" not in table  # an ablation: the taxonomy's row only
    assert "constant_per_corner/causes.json`](docs/campaign/constant_per_corner" in table
    assert "constant_lift/causes.json" not in table
    taxonomy = BLOCKS["campaign-taxonomy"].render(both, "")
    assert "| constant, clearance lifting | 1 | 1 | 100.0% | 20.7–100.0% |" in taxonomy
    assert "and [`constant_lift/causes.json`]" in taxonomy
    told = [{**r, "detail": "why"} for r in runs]  # every failure names its cause
    goals = BLOCKS["campaign-goals"].render(Inputs(campaign=told, variants=[variant]), "")
    assert "dynamic 66.7 %, (constant, per_corner depths 50.0 %)" in goals


def test_the_campaign_taxonomy_and_goals_count_every_cause_from_causes_json() -> None:
    from deploy.docs.blocks import BLOCKS

    def run(start: str, cause: str, detail: str = "", frames: int | None = None) -> dict:
        return {"start": start, "mode": "pmj", "cause": cause, "detail": detail,
                "frames": frames, "path_ratio": 1.1 if frames else None}  # fmt: skip

    runs = [
        run("s1", "converged", frames=80),
        run("s2", "converged", frames=90),
        run("s3", "stuck (hand partial)", "held 4.07 s waiting for: hand partial (…)"),
        run("s4", "acquisition failed", "acquisition failed: target partial after 4 attempt(s)"),
        run("s5", "refused at start", "target.position: out of reach"),
    ]
    taxonomy = BLOCKS["campaign-taxonomy"].render(Inputs(campaign=runs), "docs")
    header, _, row = taxonomy.splitlines()[:3]
    cells = dict(zip(header.split(" | "), row.split(" | "), strict=True))
    assert cells["runs"] == "4" and cells["on goal"] == "2" and cells["success"] == "50.0%"
    assert cells["median frames"] == "85" and cells["refused at start"] == "1"
    assert cells["stuck"] == "1" and cells["acquisition failed"] == "1" and cells["timeout"] == "0"
    goals = BLOCKS["campaign-goals"].render(Inputs(campaign=runs), "docs")
    assert "pmj 50.0 %" in goals and "per strategy (N = 4)" in goals  # the refused one aside
    assert '1 of 5 (20.0 %): 1 "target.position: out of reach"' in goals
    # Every run named, every failure with its detail; a refused start's record with its reason.
    assert "| 0 of 4 runs and 1 refused starts' records | 0 |" in goals
    assert "4.07–4.07 s simulated (1 runs)" in goals
    runs[2]["detail"] = ""
    said = "| 1 of 4 runs and 1 refused starts' records | 0 |"
    assert said in BLOCKS["campaign-goals"].render(Inputs(campaign=runs), "docs")


def test_the_stability_block_splits_every_row_by_the_goals_constant_leaves() -> None:
    from deploy.docs.blocks import BLOCKS
    from deploy.docs.sources import CampaignVariant

    runs = [
        {"start": "s1", "mode": "constant", "cause": "converged"},
        {"start": "s2", "mode": "constant", "cause": "marker left the image"},
        {"start": "s3", "mode": "constant", "cause": "converged"},
        {"start": "s1", "mode": "dynamic", "cause": "converged"},
        {"start": "s2", "mode": "dynamic", "cause": "converged"},
        {"start": "s3", "mode": "dynamic", "cause": "joint limit"},
        {"start": "s4", "mode": "dynamic", "cause": "refused at start"},
    ]
    starts = [
        {"name": "s1", "constant_goal_stability": 1.0},
        {"name": "s2", "constant_goal_stability": -1.5},
        {"name": "s3", "constant_goal_stability": 0.2},
        {"name": "s4", "constant_goal_stability": None},
    ]
    assert "Not run yet" in BLOCKS["campaign-stability"].render(Inputs(campaign=runs), "")
    table = BLOCKS["campaign-stability"].render(Inputs(campaign=runs, campaign_starts=starts), "")
    assert "| constant | 2/2 (100.0%) | 0/1 (0.0%) |" in table
    assert "| dynamic | 1/2 (50.0%) | 1/1 (100.0%) |" in table  # the refused start left out
    # a variant's runs are split by the campaign's starts too
    per_corner = [{**r, "mode": "constant"} for r in runs[3:6]]
    variant = CampaignVariant("constant_per_corner", "constant, per_corner depths", per_corner)
    inputs = Inputs(campaign=runs, campaign_starts=starts, variants=[variant])
    table = BLOCKS["campaign-stability"].render(inputs, "docs")
    assert "| constant, per_corner depths | 1/2 (50.0%) | 1/1 (100.0%) |" in table
    assert "*1 of the 3 goals run are unstable" in table
    assert "[`starts.json`](campaign/starts.json)" in table


def test_the_accuracy_block_renders_each_condition_from_its_json() -> None:
    from deploy.docs.blocks import BLOCKS

    assert "Not measured yet: `umay accuracy" in BLOCKS["vision-accuracy"].render(Inputs(), "")
    record = {
        "condition": "Kinect model, HSV",
        "frames": 300,
        "seen_both_fraction": 1.0,
        "found_both_fraction": 0.98,
        "corner_rms_px": 0.1144,
        "corner_max_px": 0.9,
        "depth_rms_m": 0.000364,
        "depth_max_m": 0.0066,
        "within_2_sigma_z": 0.999,
        "within_2_reported_sigma": 0.948,
    }
    lost = dict(record, condition="dark, RGB", corner_rms_px=None, depth_rms_m=None)
    table = BLOCKS["vision-accuracy"].render(Inputs(accuracy=[record, lost]), "docs")
    assert (
        "| Kinect model, HSV | 300 | 100.0 % | 98.0 % | 0.114 / 0.90 | 0.364 / 6.60 | 99.9 % "
        "| 94.8 % |" in table
    )
    assert "| dark, RGB | 300 | 100.0 % | 98.0 % | – | – |" in table


def test_the_suite_camera_block_sets_each_strategy_at_both_cameras_side_by_side() -> None:
    from deploy.docs.blocks import BLOCKS
    from deploy.docs.sources import SUITE_CAMERA_DIR, SUITE_CAMERAS

    assert "Not run yet: `umay compare" in BLOCKS["suite-camera"].render(Inputs(), "")
    small, large = (
        rows_from_json((REPO_ROOT / SUITE_CAMERA_DIR / n / "results.json").read_text())
        for n in SUITE_CAMERAS
    )
    missed = next(i for i, r in enumerate(large) if r.mode == "dynamic")
    large[missed] = large[missed].model_copy(update={"on_goal": False})
    table = BLOCKS["suite-camera"].render(Inputs(suite_cameras=[("a", small), ("b", large)]), "")
    rows = {line.split(" | ")[0].lstrip("| "): line for line in table.splitlines()}
    assert rows["dynamic"].startswith("| dynamic | 12/12 → 11/12 | ")
    assert rows["pmj"].startswith("| pmj | 12/12 → 12/12 | ")
    summed = [sum(r.wall_time_s for r in rows) for rows in (small, large)]
    assert f"summed: {summed[0]:.0f} s → {summed[1]:.0f} s" in table
    assert "--set camera.rgb_hz=30" in table  # how to make it again


def test_umay_docs_redraws_the_bench_figure_from_its_json_once(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from deploy.docs.figures import BENCH_STAGES_PNG

    (tmp_path / "docs" / "results").mkdir(parents=True)
    shutil.copy(REPO_ROOT / RESULTS_JSON, tmp_path / RESULTS_JSON)
    (tmp_path / "docs" / "bench").mkdir()
    shutil.copy(REPO_ROOT / f"docs/bench/{LOCKSTEP_RUN}.json", tmp_path / "docs" / "bench")
    assert main(["docs", "--check", "--root", str(tmp_path)]) == 0
    assert not (tmp_path / BENCH_STAGES_PNG).exists()  # --check changes nothing
    assert main(["docs", "--root", str(tmp_path)]) == 0
    assert f"redrew {BENCH_STAGES_PNG}" in capsys.readouterr().err
    png = (tmp_path / BENCH_STAGES_PNG).read_bytes()
    assert png.startswith(b"\x89PNG") and png == (REPO_ROOT / BENCH_STAGES_PNG).read_bytes()
    assert main(["docs", "--root", str(tmp_path)]) == 0
    assert "redrew" not in capsys.readouterr().err  # the same JSON draws the same bytes


def test_the_startup_block_shows_each_runs_first_frames_against_its_later_ones() -> None:
    def frames(first_ms: float) -> dict[str, Any]:
        seqs = range(14)
        return {
            "distributed": {
                "frames_ms": [
                    {"frame_seq": i, "latency_ms": first_ms if i == 0 else 6.0 + i % 2,
                     "frame_transport": 0.5, "vision": 3.0}
                    for i in seqs
                ]
            },
            "inprocess": {"frames_ms": [{"frame_seq": i, "latency_ms": 3.0} for i in seqs]},
        }  # fmt: skip

    data = {
        "command": "umay bench --warmup 0",
        "machine": {"cpus": 2, "processor": "x86_64", "load_start": [1.0], "code": "abc"},
        "each_run": [frames(13.0), frames(14.0)],
    }
    rendered = bench_startup(Inputs(startup=[BenchRun("s", data, STARTUP_DIR)]), "docs")
    assert "[`s`](bench/startup/s.json): `umay bench --warmup 0`" in rendered
    assert "| 0 | 13.00 (3.00) / 0.50 / 3.00 | 14.00 (3.00) / 0.50 / 3.00 |" in rendered
    assert "| 1 | 7.00 (3.00) / 0.50 / 3.00 | 7.00 (3.00) / 0.50 / 3.00 |" in rendered
    # frames 10 to 13: 6, 7, 6, 7 ms
    assert f"| median, frames {STARTUP_FRAMES} on | 6.50 (3.00) / 0.50 / 3.00 |" in rendered
    assert bench_startup(Inputs(), "docs") == "*No start-up run has been made.*"


def test_the_calibration_block_counts_each_campaign_s_runs_contacts_and_errors() -> None:
    """Refused starts left out; a run on goal that touched the object counted as such; the
    final errors of the runs on goal only; the bound's on and off rows each from their own
    folder."""
    from deploy.docs.blocks import BLOCKS
    from deploy.docs.sources import CalibrationRun
    from deploy.experiments.compare.rows import CompareRow

    def row(on_goal: bool, error_m: float, contact: str | None = None) -> CompareRow:
        return CompareRow.model_construct(
            on_goal=on_goal,
            final_position_error_m=error_m,
            first_contact_s=None if contact is None else 0.5,
            contact_with=contact,
        )

    causes = [
        {"start": "s1", "mode": "dynamic", "cause": "converged"},
        {"start": "s2", "mode": "dynamic", "cause": "converged"},
        {"start": "s3", "mode": "dynamic", "cause": "local minimum"},
        {"start": "s4", "mode": "dynamic", "cause": "refused at start"},
    ]
    results = [row(True, 0.0004), row(True, 0.0012, "object"), row(False, 0.0059)]
    on = CalibrationRun("x_plus_forearm_true", "[0.005,0,0]", True, causes, results)
    off = CalibrationRun("x_plus_forearm_false", "[0.005,0,0]", False, causes[:2], results[:2])
    assert "Not run yet" in BLOCKS["campaign-calibration"].render(Inputs(), "")
    table = BLOCKS["campaign-calibration"].render(Inputs(calibration=[on, off]), "docs")
    assert "| `[0.005,0,0]` | yes | 3 | 2 (66.7%) | local minimum 1 | 1 | 0.80 / 1.20 |" in table
    assert "| `[0.005,0,0]` | no | 2 | 2 (100.0%) | – | 1 | 0.80 / 1.20 |" in table
    assert "(campaign/calibration)" in table
