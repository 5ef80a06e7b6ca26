"""``umay domains`` stopped as a terminal stops it: Ctrl-C reaches every process of the
group, the workers too. The study exits 130 with the runs that finished written (runs.jsonl,
domains.json, report.md), on either executor; ``--resume`` then does the rest, and drops a
last line of runs.jsonl cut off by a kill (its run done again)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from deploy.experiments.domains.study import RunTask
from deploy.launch.evaluate import RunResult
from tests.domains_fakes import fake_run

REPO = Path(__file__).resolve().parents[2]
# The default study's first 12 cells, one draw each: 8 starts are runnable.
STUDY = ["--cells", "0:12", "--draws", "1", "--modes", "dynamic"]
SLOW = "tests.integration.test_domains_interrupts:slow_run"
FAKE = "tests.domains_fakes:fake_run"


def slow_run(task: RunTask) -> RunResult:
    """:func:`~tests.domains_fakes.fake_run`, a second long: runs are still going when the
    first one is written."""
    time.sleep(1.0)
    return fake_run(task)


def domains(out: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "deploy", "domains", "--out", str(out), *STUDY, *args],
        cwd=REPO, capture_output=True, text=True, timeout=300,
    )  # fmt: skip


def keys_in(jsonl: Path) -> list[str]:
    return [json.loads(line)["key"] for line in jsonl.read_text().splitlines()]


def interrupted(out: Path, *args: str) -> tuple[int, str]:
    """The study started in a session of its own, Ctrl-C at default as in a terminal, and
    SIGINT sent to its whole group once the first run is written: its exit code and output."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "deploy", "domains", "--out", str(out), *STUDY, *args],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip
    jsonl = out / "runs.jsonl"
    try:
        deadline = time.monotonic() + 120.0
        while not (jsonl.is_file() and jsonl.read_text().strip()):
            assert proc.poll() is None, proc.communicate()[0][-3000:]
            assert time.monotonic() < deadline, "no run written"
            time.sleep(0.05)
        os.killpg(proc.pid, signal.SIGINT)
        output, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    return proc.returncode, output


@pytest.mark.parametrize("executor", [["--jobs", "2"], ["--cluster", "local:2"]], ids=" ".join)
def test_ctrl_c_to_the_group_keeps_the_finished_runs(tmp_path: Path, executor: list[str]) -> None:
    out = tmp_path / "out"
    code, output = interrupted(out, "--pipeline", SLOW, *executor)
    assert code == 130, output[-3000:]
    # The workers ignored it: no run of theirs cut short, no traceback through our code. (A
    # closing Dask cluster may log one of its own, a connection closed under it: not ours.)
    assert "KeyboardInterrupt" not in output, output[-3000:]
    ours = [t for t in output.split("Traceback (most recent call last):")[1:] if "/deploy/" in t]
    assert not ours, output[-3000:]
    data = json.loads((out / "domains.json").read_text())
    assert not data["complete"]
    runnable = [s for s in data["starts"] if not s["refused"]]
    assert len(runnable) == 8
    written = keys_in(out / "runs.jsonl")
    assert sorted(r["key"] for r in data["runs"]) == sorted(written)
    assert 1 <= len(written) < len(runnable)
    assert (out / "report.md").is_file()
    if executor[0] == "--jobs":  # the rest, once (either executor resumes the same way)
        resumed = domains(out, "--pipeline", FAKE, "--resume")
        assert resumed.returncode == 0, resumed.stderr[-3000:]
        again = json.loads((out / "domains.json").read_text())
        assert again["complete"] and len(again["runs"]) == len(runnable)
        assert keys_in(out / "runs.jsonl")[: len(written)] == written


def test_resume_drops_a_last_line_cut_off_and_runs_it_again(tmp_path: Path) -> None:
    out = tmp_path / "out"
    first = domains(out, "--pipeline", FAKE, "--cells", "0:6")
    assert first.returncode == 0, first.stderr[-3000:]
    jsonl = out / "runs.jsonl"
    whole = keys_in(jsonl)
    assert len(whole) == 4
    text = jsonl.read_text()
    jsonl.write_text(text[: len(text) - 80])  # a run killed while writing its line
    resumed = domains(out, "--pipeline", FAKE, "--cells", "0:6", "--resume")
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert f"warning: {jsonl} line 4: cut off" in resumed.stderr
    assert "4 runs (3 kept from runs.jsonl)" in resumed.stderr
    assert sorted(keys_in(jsonl)) == sorted(whole)  # every line whole again, each run once
    assert json.loads((out / "domains.json").read_text())["complete"]
