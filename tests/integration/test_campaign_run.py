"""A small random-start campaign (``umay campaign``) run end to end twice: every run named,
bit-for-bit repeatable."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from deploy.experiments.campaign import CAUSES, cause_family
from deploy.experiments.compare.rows import differences, rows_from_json

CHEAP = ["camera.width_px=320", "camera.height_px=240", "run.timeout_s=15.0"]


def campaign(out: Path, pipeline: str) -> subprocess.CompletedProcess:
    sets = [a for item in CHEAP for a in ("--set", item)]
    return subprocess.run(
        [sys.executable, "-m", "deploy", "campaign", "--n", "3", "--modes", "dynamic", "mpj",
         "--jobs", "2", "--out", str(out), "--pipeline", pipeline, *sets],
        capture_output=True, text=True, timeout=900,
    )  # fmt: skip


def test_a_small_campaign_names_every_run_and_repeats_bit_for_bit(tmp_path: Path) -> None:
    """The second time through the in-process pipeline: the same seed gives the same runs to
    the bit wherever they were run (and CI runs the four services once, not twice)."""
    first = campaign(tmp_path / "a", "distributed")
    second = campaign(tmp_path / "b", "inprocess")
    assert first.returncode == 0, first.stderr
    assert second.returncode == 0, second.stderr
    causes = json.loads((tmp_path / "a" / "causes.json").read_text())
    starts = json.loads((tmp_path / "a" / "starts.json").read_text())
    assert len(starts) == 3
    assert len(causes) == 2 * 3  # every start × strategy, refused or run
    for c in causes:
        assert cause_family(c["cause"]) in CAUSES, c
        if c["cause"] != "converged":
            assert c["detail"], c  # every failure says why
    a = rows_from_json((tmp_path / "a" / "results.json").read_text())
    b = rows_from_json((tmp_path / "b" / "results.json").read_text())
    assert a and differences(a, b) == []  # lockstep: the same to the bit, wall time aside
    assert (tmp_path / "a" / "campaign.md").read_text() == (
        tmp_path / "b" / "campaign.md"
    ).read_text()
