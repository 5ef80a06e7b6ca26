"""A small random-start campaign (``umay campaign``) run end to end twice: every run named,
bit-for-bit repeatable."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from deploy.experiments.campaign.causes import CAUSES, cause_family
from deploy.experiments.compare.rows import differences, rows_from_json

CHEAP = ["camera.width_px=320", "camera.height_px=240", "run.timeout_s=15.0"]


def campaign(out: Path, jobs: int, *extra: str) -> subprocess.CompletedProcess:
    sets = [a for item in CHEAP for a in ("--set", item)]
    n = [] if "--only" in extra else ["--n", "3"]  # --only replaces --n
    return subprocess.run(
        [sys.executable, "-m", "deploy", "campaign", *n, "--modes", "dynamic", "mpj",
         "--jobs", str(jobs), "--out", str(out), "--pipeline", "inprocess", *sets, *extra],
        capture_output=True, text=True, timeout=900,
    )  # fmt: skip


def test_a_small_campaign_names_every_run_and_repeats_bit_for_bit(tmp_path: Path) -> None:
    """Twice, with two runs at once and then one at a time: the same seed gives the same runs
    to the bit whatever the order they run in. Through the in-process pipeline, as the
    published campaign. In the first, the first start's runs (the figures) go through the four
    service processes; the second has no figures, so they too run in-process, and still give
    the same numbers (the in-process run is the distributed one to the bit)."""
    first = campaign(tmp_path / "a", 2)
    second = campaign(tmp_path / "b", 1, "--no-figures")
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
    assert (tmp_path / "a" / "figures" / "overlay.png").is_file()
    assert not (tmp_path / "b" / "figures").exists()
    assert a and differences(a, b) == []  # lockstep: the same to the bit, wall time aside
    assert (tmp_path / "a" / "campaign.md").read_text() == (
        tmp_path / "b" / "campaign.md"
    ).read_text()
    # One start of it again (--only, by name and by index): the same runs to the bit.
    again = campaign(tmp_path / "c", 1, "--no-figures", "--only", "start_0002", "0")
    assert again.returncode == 0, again.stderr
    c = rows_from_json((tmp_path / "c" / "results.json").read_text())
    assert sorted({r.scenario for r in c}) == sorted(
        {r.scenario for r in a} & {"start_0000", "start_0002"}
    )
    assert c and differences([r for r in a if r.scenario in {x.scenario for x in c}], c) == []
