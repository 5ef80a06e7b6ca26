"""``umay bench``: the JSON is complete and sane. No thresholds on time: CI machines vary, and a
benchmark prints its numbers, it does not assert them."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from deploy.bench.processes import code_version
from deploy.bench.stages import (
    INPROCESS_STAGES,
    LATENCY_STAGES,
    PIPELINE,
    STAGES,
    SYNTHETIC_STAGES,
)

FRAMES = 20


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
    # Progress on stderr, a line as each part starts, in the order they run.
    assert [line for line in proc.stderr.splitlines() if line.startswith("umay bench: ")] == [
        f"umay bench: the four-process loop, {FRAMES} frames after 2 to warm up",
        "umay bench: the render and the Kinect model, per renderer",
        "umay bench: the four-process loop again, with tiny",
        "umay bench: the same steps in one process (the in-process baseline)",
        "umay bench: vision, controller and actuation fed at 30 Hz",
    ], proc.stderr
    result = json.loads(out.read_text())
    result["_figure"] = tmp / "stages.png"
    return result


@pytest.mark.xdist_group("bench")  # the module's bench runs once per worker
def test_bench_json_is_complete_and_sane(bench: dict) -> None:
    r = bench
    assert r["config"]["width_px"] == 320 and r["config"]["height_px"] == 240
    assert r["config"]["clock"] == "lockstep" and r["config"]["transport"] == "shm"
    assert r["config"]["renderer"] in ("gl", "tiny") and r["config"]["frames"] == FRAMES
    assert len(r["machine"]["load_start"]) == 3 and r["machine"]["cpus"] >= 1
    # The code it measured: the commit, "-dirty" only for changes outside docs/ and README.md
    # (the rule itself: tests/unit/test_bench.py).
    assert r["machine"]["code"] == code_version() and r["machine"]["code"] is not None

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


@pytest.mark.xdist_group("bench")  # the module's bench runs once per worker
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


def test_a_view_started_late_leaves_the_baseline_on_the_measured_frames(
    monkeypatch: pytest.MonkeyPatch, tmp_path
) -> None:
    """With --view the view and its client start once the services are up, and the lockstep
    sim runs on meanwhile: the window starts later, and the in-process baseline must time
    those same frames (it timed the first ones, cheaper or dearer, and compared commands on
    frames the two runs hardly shared)."""
    import contextlib
    import time

    import deploy.bench.view
    from common.config import load_scenario
    from common.runtime import parse_overrides
    from deploy.bench.run import run_bench

    @contextlib.contextmanager
    def slow_view(*_args, **_kwargs):
        time.sleep(1.5)  # the sim runs on while a view would start
        yield {}

    monkeypatch.setattr(deploy.bench.view, "watched_by_a_view", slow_view)
    overrides = ["camera.width_px=160", "camera.height_px=120"]
    scenario = load_scenario(None, parse_overrides(overrides))
    report = run_bench(
        None, scenario, overrides, 10, 2, tmp_path, synthetic_frames=0,
        reference_renderer=False, view=True,
    )  # fmt: skip
    first = report.distributed.window[0]
    assert first > 2 + 10  # it did run on
    assert [r["frame_seq"] for r in report.inprocess.frames_ms] == list(range(first, first + 10))
    assert report.inprocess.same_commands_max_abs_diff_rad_s == 0.0
