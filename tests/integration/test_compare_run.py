"""``umay compare`` as a command: bad input, Ctrl-C, and a small real comparison (2 scenarios ×
every strategy at 320×240) whose outputs must be complete and consistent."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

from deploy.experiments.compare.rows import rows_from_json
from deploy.experiments.compare.summary import summarize_modes
from tests.conftest import processes_mentioning
from tests.unit.test_compare import CHEAP, MODES, SMALL_SUITE, _suite_copy, rows_from_csv
from tests.unit.test_plots import PNG_SIGNATURE

UMAY = [sys.executable, "-m", "deploy"]
CHEAP_ARGS = [a for item in CHEAP for a in ("--set", item)]
RUN_TIMEOUT_S = 1200


def test_ctrl_c_stops_every_pipeline(tmp_path: Path) -> None:
    """Nothing left running, and the folder of an earlier comparison as it was: its figures'
    recordings too (the interrupted runs record aside, and their recordings are dropped)."""
    folder = _suite_copy(tmp_path, ("01_baseline.toml",))
    out = tmp_path / "out"
    earlier = out / "figures" / "dynamic" / "run.mcap"
    earlier.parent.mkdir(parents=True)
    earlier.write_bytes(b"an earlier comparison's recording")
    args = ["--scenarios", str(folder), "--modes", "dynamic", "mpj", "--jobs", "2"]
    # Runs that cannot end before the interrupt: a threshold they never reach, no plateau or
    # stall to end them either, a long timeout (a converging run took 8.6 s, less than the
    # pipelines took to show up on a loaded CI; on a fast host a stalled one ends in 2 s).
    never_done = [
        *("--set", "controller.converged_px=0.0001", "--set", "controller.plateau_px=0"),
        *("--set", "controller.stall_after_s=3600", "--set", "run.timeout_s=600"),
    ]
    proc = subprocess.Popen(
        [*UMAY, "compare", *args, "--out", str(out), *CHEAP_ARGS, *never_done],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 120
        while len(processes_mentioning(str(folder))) < 8 and time.monotonic() < deadline:
            time.sleep(0.2)  # two pipelines of four services each
        assert len(processes_mentioning(str(folder))) >= 8, "the pipelines never started"
        time.sleep(2.0)
        proc.send_signal(signal.SIGINT)
        _, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, stderr
    assert "interrupted" in stderr
    assert processes_mentioning(str(folder)) == []
    assert not (out / "results.csv").exists()
    assert earlier.read_bytes() == b"an earlier comparison's recording"
    assert sorted(p.name for p in (out / "figures").rglob("*.mcap")) == ["run.mcap"]


# --- a small real comparison ----------------------------------------------------------------
def test_small_comparison_outputs_are_complete_and_consistent(tmp_path: Path) -> None:
    """Through the in-process pipeline, to keep CI short (it is the distributed lockstep run
    to the bit: test_pipeline_vs_distributed.py, and test_campaign_run.py through the same
    runner); the figures scenario's runs still go through the four service processes, for
    their recordings."""
    folder = _suite_copy(tmp_path, SMALL_SUITE)
    out = tmp_path / "out"
    started = time.monotonic()
    args = ["--scenarios", str(folder), "--jobs", "2", "--out", str(out), *CHEAP_ARGS]
    proc = subprocess.run(
        [*UMAY, "compare", *args, "--pipeline", "inprocess"],
        capture_output=True,
        text=True,
        timeout=RUN_TIMEOUT_S,
    )
    print(f"\nsmall comparison: {time.monotonic() - started:.0f} s\n{proc.stderr[-3000:]}")
    assert proc.returncode == 0, proc.stderr

    rows = rows_from_csv((out / "results.csv").read_text())
    assert rows == rows_from_json((out / "results.json").read_text())
    assert [(r.scenario, r.mode) for r in rows] == [
        (s, m) for s in ("baseline", "moving_target") for m in MODES
    ]
    for r in rows:
        assert r.clock == "lockstep" and r.frames > 0 and r.final_position_error_m is not None
        assert r.moving_target == (r.scenario == "moving_target")
        assert (r.tracking_position_error_m is not None) == r.moving_target
        assert r.reason in ("converged", "timeout"), r
        assert r.on_goal == (r.converged and r.final_position_error_m <= 0.005)
    # The figures scenario's runs went through the four service processes: every strategy
    # reaches its goal through them.
    assert all(r.on_goal for r in rows if r.scenario == "baseline"), rows

    summary = (out / "summary.md").read_text()
    for s in summarize_modes(rows, MODES):
        assert f"| {s.mode} | {s.converged}/{s.runs} | {s.on_goal}/{s.runs} |" in summary
        assert s.runs == 2
    assert summary.count("\n| baseline | ") == len(MODES)

    for mode in MODES:
        for name in ("image_trajectory.png", "ee_velocity.png"):
            path = out / "figures" / mode / name
            assert path.read_bytes()[:8] == PNG_SIGNATURE, path
    assert (out / "figures" / "overlay.png").read_bytes()[:8] == PNG_SIGNATURE
    assert "figures/overlay.png" in summary
    json.loads((out / "results.json").read_text())  # plain JSON, not only pydantic's
