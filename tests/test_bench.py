"""``umay bench``: the JSON is complete and sane. No thresholds on time: CI machines vary, and a
benchmark prints its numbers, it does not assert them."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from common.codec import encode
from common.messages import AppliedCommand, Header, PublishedStamps, SimTiming
from deploy.bench import (
    INPROCESS_STAGES,
    LATENCY_STAGES,
    PIPELINE,
    STAGES,
    SYNTHETIC_STAGES,
    HopStamp,
    Trace,
    analyse_trace,
    median_of_runs,
)
from deploy.recording.plots import bench_figure

FRAMES = 20


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
    assert r["frames"] == 3 and r["frames_complete"] == 2
    assert r["dropped"]["vision"] == 1
    assert r["dropped"]["controller"] == r["dropped"]["actuation"] == r["dropped"]["apply"] == 0
    assert r["stages_ms"]["render"]["p50"] == pytest.approx(100.0)
    assert r["stages_ms"]["vision"]["p50"] == pytest.approx(8.0)
    assert r["latency_ms"]["p50"] == pytest.approx(22.0)
    assert [row["frame_seq"] for row in r["frames_ms"]] == [0, 1]  # the complete ones
    assert all(row["latency_ms"] == pytest.approx(22.0) for row in r["frames_ms"])
    assert r["frames_over_goal"] == 2  # both complete frames took 22 ms, over 10
    assert all(row["vision"] == pytest.approx(8.0) for row in r["frames_ms"])
    # capture → colour frame sent (1 ms) → vision has it (1 ms): the frame's hand-off
    assert r["frame_handoff_ms"]["p50"] == pytest.approx(2.0) and r["frame_handoff_ms"]["n"] == 2
    total = sum(r["stages_ms"][s]["mean"] for s in LATENCY_STAGES)
    assert total == pytest.approx(r["latency_ms"]["mean"], abs=1e-3)


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


def check_summary(s: dict, n: int | None = None) -> None:
    assert set(s) == {"n", "p50", "p99", "max", "mean"}
    if n is not None:
        assert s["n"] == n
    assert s["n"] > 0
    assert 0.0 <= s["p50"] <= s["p99"] <= s["max"]
    assert 0.0 <= s["mean"] <= s["max"]


@pytest.fixture(scope="module")
def bench(tmp_path_factory: pytest.TempPathFactory) -> dict:
    tmp = tmp_path_factory.mktemp("bench")
    out = tmp / "bench.json"
    argv = [sys.executable, "-m", "deploy", "bench", "--frames", str(FRAMES)]
    argv += ["--size", "320x240", "--mode", "lockstep", "--warmup", "2"]
    argv += ["--json", str(out), "--log-dir", str(tmp / "logs")]
    argv += ["--figure", str(tmp / "stages.png")]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"stdout:\n{proc.stdout}\nstderr:\n{proc.stderr}"
    assert "latency excl. render" in proc.stdout and "ratio distributed / in-process" in proc.stdout
    result = json.loads(out.read_text())
    result["_figure"] = tmp / "stages.png"
    return result


def test_bench_json_is_complete_and_sane(bench: dict) -> None:
    r = bench
    assert r["config"]["width_px"] == 320 and r["config"]["height_px"] == 240
    assert r["config"]["clock"] == "lockstep" and r["config"]["transport"] == "shm"
    assert r["config"]["renderer"] in ("gl", "tiny") and r["config"]["frames"] == FRAMES
    assert len(r["machine"]["load_start"]) == 3 and r["machine"]["cpus"] >= 1

    d = r["distributed"]
    assert d["frames"] == FRAMES
    # Lockstep: every frame goes all the way round, none is dropped anywhere.
    assert d["frames_complete"] == FRAMES
    assert all(v == 0 for v in d["dropped"].values()), d["dropped"]
    assert set(d["stages_ms"]) == set(STAGES)
    for stage in STAGES:
        check_summary(d["stages_ms"][stage], FRAMES)
    check_summary(d["latency_ms"], FRAMES)
    assert 0 <= d["frames_over_goal"] <= FRAMES
    # The stages after the render add up to the latency, frame by frame, hence in the mean.
    total = sum(d["stages_ms"][s]["mean"] for s in LATENCY_STAGES)
    assert total == pytest.approx(d["latency_ms"]["mean"], rel=1e-3, abs=0.01)
    assert d["loop_rate_hz"] > 0 and d["real_time_factor"] > 0
    assert d["frames_received_by_vision"] >= FRAMES
    # One host, the ring on: vision read every colour frame in the sim's ring.
    assert d["frames_by_ref"] == d["frames_received_by_vision"]
    check_summary(d["frame_handoff_ms"], FRAMES)
    assert set(d["services"]) == {"sim", "vision", "controller", "actuation"}
    for name, u in d["services"].items():
        assert u["peak_rss_mb"] > 10 and u["rss_mb"] <= u["peak_rss_mb"], name
        assert u["cpu_s"] >= u["window_cpu_s"] >= 0 and u["cpu_ms_per_frame"] >= 0, name
    assert d["status"]["vision"]["rejected"] == 0

    i = r["inprocess"]
    assert i["frames"] == FRAMES
    check_summary(i["per_frame_ms"], FRAMES)
    check_summary(i["per_frame_with_codec_ms"], FRAMES)
    assert i["per_frame_with_codec_ms"]["mean"] >= i["per_frame_ms"]["mean"]
    # Vision's second, warm call on each frame is timed apart, outside the frame's time.
    check_summary(i["stages_ms"]["vision_warm"], FRAMES)
    assert sum(i["stages_ms"][s]["mean"] for s in INPROCESS_STAGES) == pytest.approx(
        i["per_frame_ms"]["mean"], rel=1e-3, abs=0.01
    )
    # Same frames, same functions: the in-process loop computes the distributed commands.
    assert i["same_commands_max_abs_diff_rad_s"] is not None
    assert i["same_commands_max_abs_diff_rad_s"] <= 1e-9

    assert r["ratio"]["p50"] > 0 and r["ratio"]["p99"] > 0 and r["ratio"]["vs_with_codec_p50"] > 0
    assert r["ratio"]["p50"] == pytest.approx(
        d["latency_ms"]["p50"] / i["per_frame_ms"]["p50"], rel=1e-3
    )

    # What distribution adds: the difference of the two p50s, and its parts stage by stage.
    adds = r["distribution_adds_ms"]
    assert adds["p50"] == pytest.approx(d["latency_ms"]["p50"] - i["per_frame_ms"]["p50"], abs=1e-3)
    assert set(adds["parts_p50"]) == set(LATENCY_STAGES)
    assert adds["parts_p50"]["frame_transport"] == d["stages_ms"]["frame_transport"]["p50"]

    # The renderers side by side on the same postures, the sensor model, the reference loop.
    renderers = r["render"]["renderers"]
    assert set(renderers) == {"gl", "tiny"}
    assert renderers["tiny"]["renderer"] == "tiny"
    for v in renderers.values():
        assert v["render_ms"]["n"] >= 2 and 0 < v["render_ms"]["p50"] <= v["render_ms"]["max"]
    model = r["render"]["sensor_model"]
    assert model["colour_px"] == [320, 240] and model["total_ms"]["p50"] > 0
    ref = r["reference_renderer"]
    assert ref["renderer"] == "tiny" and ref["loop_rate_hz"] > 0 and ref["real_time_factor"] > 0
    assert all(v == 0 for v in ref["dropped"].values()), ref["dropped"]

    s = r["synthetic"]
    assert s["rate_hz"] == 30.0 and s["frames"] == FRAMES
    assert set(s["dropped"]) == set(PIPELINE)
    assert all(v >= 0 for v in s["dropped"].values())
    assert sum(s["dropped"].values()) <= FRAMES
    answered = FRAMES - sum(s["dropped"].values())
    if answered:
        check_summary(s["latency_ms"])
        for stage in SYNTHETIC_STAGES:
            check_summary(s["stages_ms"][stage])
    assert set(s["services"]) == set(PIPELINE)


def test_bench_keeps_every_frame_and_draws_them(bench: dict) -> None:
    """Frame by frame: each complete frame's stages add up to its latency, the in-process
    loop timed the same frames, and the figure of them was written."""
    d, i = bench["distributed"], bench["inprocess"]
    rows = d["frames_ms"]
    assert len(rows) == d["frames_complete"] == FRAMES
    for row in rows:
        assert sum(row[s] for s in LATENCY_STAGES) == pytest.approx(row["latency_ms"], abs=1e-3)
        assert all(row[s] >= 0.0 for s in STAGES), row
    assert [r["frame_seq"] for r in i["frames_ms"]] == [r["frame_seq"] for r in rows]
    assert sorted(r["latency_ms"] for r in rows)[FRAMES // 2] == pytest.approx(
        d["latency_ms"]["p50"], rel=0.2
    )
    figure = bench["_figure"]
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and figure.stat().st_size > 20_000


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


def test_medians_of_runs_leave_the_frame_rows_to_each_run() -> None:
    def row(latency_ms: float, handoff_ms: float) -> dict[str, float]:
        return {"latency_ms": latency_ms, "publish": 0.1, "frame_transport": handoff_ms - 0.1}

    run = {
        "distributed": {
            "latency_ms": {"p50": 10.0},
            "dropped": {"vision": 0},
            "frames_ms": [row(9.0, 0.5), row(11.0, 0.7)],
        },
        "inprocess": {"per_frame_ms": {"p50": 8.0}, "frames_ms": [{}]},
    }
    other = {
        "distributed": {
            **run["distributed"],
            "latency_ms": {"p50": 14.0},
            "dropped": {"vision": 2},
            "frames_ms": [row(12.0, 0.4), row(14.0, 2.0), row(7.0, 0.6)],
        },
        "inprocess": {**run["inprocess"], "per_frame_ms": {"p50": 6.0}},
    }
    m = median_of_runs([run, other])
    assert (
        m["distributed"]["latency_ms"]["p50"] == 12.0
        and m["inprocess"]["per_frame_ms"]["p50"] == 7.0
    )
    assert "frames_ms" not in m["distributed"] and "frames_ms" not in m["inprocess"]
    assert m["dropped_max"]["distributed"]["vision"] == 2 and m["runs"] == 2
    # The tail over every frame of the runs, not a median of each run's.
    pooled = m["distributed"]["pooled"]
    assert pooled["latency_ms"]["n"] == 5 and pooled["latency_ms"]["max"] == pytest.approx(14.0)
    assert pooled["latency_ms"]["p50"] == pytest.approx(11.0)
    assert pooled["frames_over_goal"] == 3  # 11, 12 and 14 ms
    # The frame's hand-off (publish + frame_transport) pooled the same way.
    assert pooled["frame_handoff_ms"]["n"] == 5
    assert pooled["frame_handoff_ms"]["p50"] == pytest.approx(0.6)


def test_bench_refuses_bad_options_with_exit_2(tmp_path: Path) -> None:
    for args in (["--size", "640by480"], ["--mode", "fast"], ["--frames", "1"], ["--repeat", "0"]):
        proc = subprocess.run(
            [sys.executable, "-m", "deploy", "bench", *args, "--log-dir", str(tmp_path)],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert proc.returncode == 2, (args, proc.stderr)
        assert "umay bench" in proc.stderr


UMAY_BENCH = [sys.executable, "-m", "deploy", "bench"]


def test_bench_refuses_an_unwritable_output_before_it_starts(tmp_path: Path) -> None:
    """Found before the runs (minutes with --repeat), not after them with a traceback."""
    (tmp_path / "file").write_text("x")
    for option, path in (("--json", tmp_path / "file" / "b.json"), ("--figure", "b.txt")):
        started = time.monotonic()
        proc = subprocess.run(
            [*UMAY_BENCH, option, str(path), "--log-dir", str(tmp_path / "logs")],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert proc.returncode == 2, proc.stderr
        assert f"umay bench: {option} {path}:" in proc.stderr and "Traceback" not in proc.stderr
        assert not (tmp_path / "logs").exists()  # no service was started
        assert time.monotonic() - started < 30
