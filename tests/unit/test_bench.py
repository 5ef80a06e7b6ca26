"""``umay bench``'s analysis on synthetic traces: stages, hops, drops, the figure, the
medians of runs and the typed report (the JSON in docs/bench/ loads and is written back as is)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import pytest

from common.codec import encode
from common.messages import AppliedCommand, Header, PublishedStamps, SimTiming
from deploy.bench.figure import bench_figure
from deploy.bench.goals import HOST_FIGURES, against_goals
from deploy.bench.processes import code_version, cpu_model
from deploy.bench.report import BenchReport, load_json, median_of_runs, summary_ms
from deploy.bench.run import same_commands_max_abs_diff
from deploy.bench.stages import LATENCY_STAGES
from deploy.bench.text import format_report
from deploy.bench.trace import HopStamp, Trace, analyse_trace

BENCH_DIR = Path(__file__).parents[2] / "docs" / "bench"
# The runs umay docs reads (alternations have a report of their own).
BENCH_JSON = sorted(
    p for pattern in ("*.json", "startup/*.json", "hosts/*.json") for p in BENCH_DIR.glob(pattern)
)


def header(seq: int, send: float, recv: float = 0.0) -> Header:
    return Header(seq=seq, sim_time_s=seq / 30, send_time_s=send, frame_seq=seq, recv_time_s=recv)


def test_stages_add_up_to_the_latency_and_missing_answers_count_as_drops() -> None:
    trace = Trace()
    for k in range(4):
        t0 = 1000.0 + k
        applied = []
        if k > 0:  # frame k reports the command of frame k-1 as applied
            applied = [
                AppliedCommand(
                    frame_seq=k - 1,
                    send_time_s=t0 - 1 + 0.120,
                    recv_time_s=t0 - 1 + 0.121,
                    applied_time_s=t0 - 1 + 0.122,
                )
            ]
        trace.timings[k] = SimTiming(
            header=header(k, t0 + 0.2),
            render_start_s=t0,
            capture_time_s=t0 + 0.1,
            frame_send_time_s=t0 + 0.101,
            with_depth=True,
            applied=applied,
        )
        for a in applied:
            trace.applied[a.frame_seq] = a
        if k == 2:
            continue  # vision never answered frame 2
        trace.features[k] = HopStamp(recv_time_s=t0 + 0.102, send_time_s=t0 + 0.110)
        trace.twists[k] = HopStamp(recv_time_s=t0 + 0.111, send_time_s=t0 + 0.115)
        trace.commands[k] = HopStamp(recv_time_s=t0 + 0.116, send_time_s=t0 + 0.120)
    r = analyse_trace(trace, [0, 1, 2])
    assert r.frames == 3 and r.frames_complete == 2
    assert r.dropped["vision"] == 1
    assert r.dropped["controller"] == r.dropped["actuation"] == r.dropped["apply"] == 0
    assert r.stages_ms["render"].p50 == pytest.approx(100.0)
    assert r.stages_ms["vision"].p50 == pytest.approx(8.0)
    assert r.latency_ms.p50 == pytest.approx(22.0)
    assert [row["frame_seq"] for row in r.frames_ms] == [0, 1]  # the complete ones
    assert all(row["latency_ms"] == pytest.approx(22.0) for row in r.frames_ms)
    assert r.frames_over_goal == 2  # both complete frames took 22 ms, over 10
    assert all(row["vision"] == pytest.approx(8.0) for row in r.frames_ms)
    # capture → colour frame sent (1 ms) → vision has it (1 ms): the frame's hand-off
    assert r.frame_handoff_ms.p50 == pytest.approx(2.0) and r.frame_handoff_ms.n == 2
    total = sum(r.stages_ms[s].mean for s in LATENCY_STAGES)
    assert total == pytest.approx(r.latency_ms.mean, abs=1e-3)


def test_the_services_stamps_fill_the_hops_first_message_per_frame() -> None:
    """A service's stamps go to the hop of their key; a frame's first message counts (a lockstep
    resend answers the same frame again), and stamps of no frame (-1) or of other keys none."""
    trace = Trace()
    trace.add_stamps(
        PublishedStamps(
            service="vision",
            stamps={
                "vision/features": [(3, 1.0, 1.5), (3, 2.0, 2.5), (-1, 3.0, 3.5), (4, 4.0, 4.5)]
            },
        )
    )
    trace.add_stamps(PublishedStamps(service="sim", stamps={"sim/rgb": [(5, 0.0, 1.0)]}))
    trace.add_stamps(
        PublishedStamps(
            service="actuation",
            stamps={"actuation/joint_command": [(3, 7.0, 7.5)]},
        )
    )
    assert trace.features == {3: HopStamp(1.0, 1.5), 4: HopStamp(4.0, 4.5)}
    assert trace.commands == {3: HopStamp(7.0, 7.5)} and trace.twists == {}


def test_the_applied_commands_velocities_come_with_the_sims_timing() -> None:
    """The commands the bench compares with the in-process ones are those the sim applied."""

    @dataclass
    class Payload:
        data: bytes

        def to_bytes(self) -> bytes:
            return self.data

    @dataclass
    class Sample:  # what Trace.on_timing reads of a zenoh.Sample
        payload: Payload

    applied = [
        AppliedCommand(
            frame_seq=k, send_time_s=1.0, recv_time_s=1.1, applied_time_s=1.2, velocity_rad_s=v
        )
        for k, v in ((6, [0.1] * 6), (-1, [0.0] * 6), (7, None))
    ]
    trace = Trace()
    timing = SimTiming(
        header=header(8, 1.3),
        render_start_s=1.0,
        capture_time_s=1.1,
        frame_send_time_s=1.2,
        with_depth=True,
        applied=applied,
    )
    trace.on_timing(Sample(Payload(encode(timing))))
    assert set(trace.applied) == {6, 7} and trace.velocities == {6: [0.1] * 6}
    trace.on_timing(Sample(Payload(b"x")))  # not a message
    assert trace.rejected == 1


@pytest.mark.parametrize("clock", ["lockstep", "realtime"])
def test_the_figure_stacks_the_stages_and_shows_the_baseline_only_in_lockstep(clock) -> None:
    row = {"latency_ms": 3.0, "render": 50.0, "publish": 1.0, "vision": 2.0}
    result = {
        "config": {"clock": clock, "width_px": 320, "height_px": 240, "transport": "shm"},
        "distributed": {"frames_ms": [{"frame_seq": k, **row} for k in range(3)]},
        "inprocess": {"frames_ms": [{"frame_seq": k, "latency_ms": 1.5} for k in range(3)]},
        "ratio": {"p50": 2.0},
    }
    (ax,) = bench_figure(result).axes
    bars = [p for c in ax.containers for p in c]
    assert len(bars) == 3 * 2  # publish and vision per frame, not the render
    assert max(b.get_y() + b.get_height() for b in bars) == pytest.approx(3.0)
    assert len(ax.get_lines()) == (1 if clock == "lockstep" else 0)
    assert ("2.00" in ax.get_title()) == (clock == "lockstep")
    assert bench_figure({"distributed": {"frames_ms": []}, "inprocess": {}}) is None


def one_run(latency_p50_ms: float, inprocess_p50_ms: float, vision_drops: int, rows) -> BenchReport:
    """A whole run (a stored one as the template) with the figures the medians are tested on."""
    run = load_json(BENCH_JSON[0])
    run = (run.each_run or [run])[0].model_copy(deep=True)
    run.distributed.latency_ms.p50 = latency_p50_ms
    run.distributed.dropped["vision"] = vision_drops
    run.distributed.frames_ms = rows
    run.inprocess.per_frame_ms.p50 = inprocess_p50_ms
    return run


def test_medians_of_runs_leave_the_frame_rows_to_each_run() -> None:
    def row(latency_ms: float, handoff_ms: float) -> dict[str, float]:
        return {"latency_ms": latency_ms, "publish": 0.1, "frame_transport": handoff_ms - 0.1}

    runs = [
        one_run(10.0, 8.0, 0, [row(9.0, 0.5), row(11.0, 0.7)]),
        one_run(14.0, 6.0, 2, [row(12.0, 0.4), row(14.0, 2.0), row(7.0, 0.6)]),
    ]
    m = median_of_runs(runs)
    assert m.distributed.latency_ms.p50 == 12.0 and m.inprocess.per_frame_ms.p50 == 7.0
    written = m.to_json()
    assert "frames_ms" not in written["distributed"] and "frames_ms" not in written["inprocess"]
    assert m.dropped_max["distributed"]["vision"] == 2 and m.runs == 2
    # A count's median stays a count: the lower of the two middle ones.
    assert m.distributed.dropped["vision"] == 0
    assert [r.distributed.frames_ms for r in m.each_run] == [r.distributed.frames_ms for r in runs]
    # The tail over every frame of the runs, not a median of each run's.
    pooled = m.distributed.pooled
    assert pooled.latency_ms.n == 5 and pooled.latency_ms.max == pytest.approx(14.0)
    assert pooled.latency_ms.p50 == pytest.approx(11.0)
    assert pooled.frames_over_goal == 3  # 11, 12 and 14 ms
    # The frame's hand-off (publish + frame_transport) pooled the same way.
    assert pooled.frame_handoff_ms.n == 5
    assert pooled.frame_handoff_ms.p50 == pytest.approx(0.6)
    assert "medians of 2 runs" in format_report(m).splitlines()[0]


@pytest.mark.parametrize("path", BENCH_JSON, ids=lambda p: p.stem)
def test_the_stored_runs_load_and_are_written_back_as_they_are(path: Path) -> None:
    """docs/bench/*.json (what ``umay docs`` reads) are reports: every key known, none lost."""
    report = load_json(path)
    assert json.dumps(report.to_json(), indent=2) + "\n" == path.read_text()
    assert "latency excl. render" in format_report(report)


def test_a_run_is_judged_against_the_goals_only_where_they_are_stated() -> None:
    """The headline's kind of run (lockstep, 640×480 at 30 Hz, OpenGL, frames by reference, no
    view, nothing set but the host's supervisor settings) gets a line per goal that depends on
    the host, met or missed as its figure stands against the limit (a figure on the limit is
    within it, shown with the decimals that say so); another kind of run says why it is not
    judged, rather than being measured against goals not its own."""
    report = load_json(BENCH_DIR / "lockstep_640x480.json")
    data = report.to_json()

    def verdicts(run: dict) -> dict[str, str]:
        lines = against_goals(run)
        assert lines[0].startswith("against issue 26's goals"), lines[0]
        return {f.words: next(x for x in lines[1:] if f.words in x) for f in HOST_FIGURES}

    d = data["distributed"]
    data["distribution_adds_ms"] = {**data["distribution_adds_ms"], "p50": 2.0}
    d["real_time_factor"] = 2.4
    d["pooled"]["latency_ms"] = {**d["pooled"]["latency_ms"], "p50": 6.0, "p99": 9.5}
    said = verdicts(data)
    assert said["what distribution adds"].endswith(" met")
    assert said["real-time factor"].endswith(" missed")
    assert said["latency p50"].endswith(" met") and said["latency p99"].endswith(" missed")
    data["distribution_adds_ms"]["p50"] = 2.0001
    assert verdicts(data)["what distribution adds"].endswith("2.0001 ms   ≤ 2.0 ms  missed")
    host = {**data["config"], "overrides": ["supervisor.cpu_wakeup_latency_us=0"]}
    assert "supervisor.cpu_wakeup_latency_us=0" in against_goals({**data, "config": host})[0]
    others = {
        "the realtime clock": {"clock": "realtime"},
        "320x240 colour": {"width_px": 320, "height_px": 240},
        "the tiny renderer": {"renderer": "tiny"},
        "frames over tcp": {"transport": "tcp"},
        "a live view": {"view": True},
        "--set camera.kinect.enabled=true": {"overrides": ["camera.kinect.enabled=true"]},
    }
    for why, change in others.items():
        (line,) = against_goals({**data, "config": {**data["config"], **change}})
        assert "not judged" in line and why in line, line
    assert "against issue 26's goals" in format_report(report)


def test_the_cpu_model_is_read_from_the_first_processors_block() -> None:
    """Hosts of one class differ in speed: the report names the CPU, not just x86_64."""
    two = (
        "processor\t: 0\nvendor_id\t: AuthenticAMD\ncpu family\t: 26\nmodel\t\t: 2\n"
        "model name\t: AMD EPYC\n\nprocessor\t: 1\nmodel name\t: other\n"
    )
    assert cpu_model(two) == "AMD EPYC (family 26, model 2)"
    assert cpu_model("processor\t: 0\nmodel name\t: Some CPU\n") == "Some CPU"
    assert cpu_model("processor\t: 0\nBogoMIPS\t: 50.00\n") is None  # e.g. many ARM hosts


def test_the_code_measured_is_dirty_only_for_changes_outside_docs(tmp_path: Path) -> None:
    """The docs' bench commands write their JSON into docs/ one after another: that must not
    mark the next run's code as changed; a change to the code must."""
    import subprocess

    def git(*args: str) -> None:
        subprocess.run(["git", "-C", str(tmp_path), *args], check=True, capture_output=True)

    git("init", "-q")
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "run.json").write_text("{}")
    (tmp_path / "code.py").write_text("x = 1\n")
    (tmp_path / "README.md").write_text("")
    git("add", ".")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "start")
    clean = code_version(tmp_path)
    assert clean and not clean.endswith("-dirty")
    (tmp_path / "docs" / "run.json").write_text('{"a": 1}')
    (tmp_path / "README.md").write_text("tables")
    (tmp_path / "new.py").write_text("")  # untracked: not the code measured
    assert code_version(tmp_path) == clean
    (tmp_path / "code.py").write_text("x = 2\n")
    assert code_version(tmp_path) == f"{clean}-dirty"
    assert code_version(tmp_path / "missing") is None


def test_a_report_with_an_unknown_key_does_not_load() -> None:
    data = json.loads(BENCH_JSON[0].read_text())
    data["distributed"]["_velocities"] = {}
    with pytest.raises(ValueError, match="_velocities"):
        BenchReport.model_validate(data)


def test_the_commands_compared_travel_outside_the_json() -> None:
    """The velocities the in-process and distributed commands are compared with stay out of
    the JSON; the comparison takes the frames both answered."""
    run = one_run(10.0, 8.0, 0, [])
    run.distributed.velocities = {5: [0.1, 0.2], 6: None, 7: [0.0, 0.0]}
    run.inprocess.velocities = {5: [0.1, 0.25], 6: [1.0, 1.0]}
    written = run.to_json()
    assert "velocities" not in written["distributed"] and "velocities" not in written["inprocess"]
    diff = same_commands_max_abs_diff(run.distributed.velocities, run.inprocess.velocities)
    assert diff == pytest.approx(0.05)
    assert same_commands_max_abs_diff({6: None}, {6: [1.0]}) is None


def test_an_empty_summary_has_no_percentiles() -> None:
    assert summary_ms([]).model_dump() == {
        "n": 0,
        "p50": None,
        "p99": None,
        "max": None,
        "mean": None,
    }
    s = summary_ms([0.001, 0.003])
    assert (s.n, s.p50, s.max, s.mean) == (
        2,
        pytest.approx(2.0),
        pytest.approx(3.0),
        pytest.approx(2.0),
    )
