"""Domain-study executors: a tiny study through ``--jobs 2`` and through a Dask LocalCluster of
two worker processes gives the same records; a worker killed mid-study loses its run, Dask
runs it again and the study completes; the real lockstep pipeline gives the same records on
either executor."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from deploy.experiments.domains.study import DEFAULT_STUDY, DomainRecord, study_differences
from tests.domains_fakes import KILL_DIR_ENV

REPO = Path(__file__).resolve().parents[2]
BASE_SCENARIO = (DEFAULT_STUDY.parent / "../scenarios/suite/01_baseline.toml").resolve()


def tiny_study(tmp_path: Path, draws: int = 2) -> Path:
    """The published study's file cut to three rotations × one distance × one depth."""
    text = DEFAULT_STUDY.read_text()
    lines = []
    for line in text.splitlines():
        if line.startswith("rotations_deg"):
            line = "rotations_deg = [0, 15, 30]"
        elif line.startswith("distances_m"):
            line = "distances_m = [0.03]"
        elif line.startswith("depths_m"):
            line = "depths_m = [0.0]"
        elif line.startswith("draws"):
            line = f"draws = {draws}"
        elif line.startswith("base_scenario"):
            line = f'base_scenario = "{BASE_SCENARIO}"'
        lines.append(line)
    path = tmp_path / "tiny.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def domains(out: Path, study: Path, *args: str, env: dict | None = None) -> dict:
    proc = subprocess.run(
        [sys.executable, "-m", "deploy", "domains", "--study", str(study), "--out", str(out),
         *args],
        cwd=REPO, capture_output=True, text=True, timeout=900, env={**os.environ, **(env or {})},
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    data = json.loads((out / "domains.json").read_text())
    assert data["complete"]
    return data


def records(data: dict) -> list[DomainRecord]:
    return [DomainRecord.model_validate(r) for r in data["runs"]]


FAKE = "tests.domains_fakes:fake_run"


@pytest.fixture(scope="module")
def with_jobs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    """The tiny study with the stand-in pipeline through ``--jobs 2``: (study file, study)."""
    tmp = tmp_path_factory.mktemp("with_jobs")
    study = tiny_study(tmp)
    modes = ["--modes", "dynamic", "mpj", "points3d"]
    return study, domains(tmp / "jobs", study, "--pipeline", FAKE, "--jobs", "2", *modes)


# Both use the module's --jobs study: one worker makes it once (make test: --dist loadgroup).
@pytest.mark.xdist_group("domains_with_jobs")
def test_jobs_and_a_two_worker_dask_cluster_give_the_same_study(
    tmp_path: Path, with_jobs: tuple[Path, dict]
) -> None:
    study, local = with_jobs
    modes = ["--modes", "dynamic", "mpj", "points3d"]
    dask = domains(tmp_path / "dask", study, "--pipeline", FAKE, "--cluster", "local:2", *modes)
    assert dask["executor"] == "--cluster local:2" and local["executor"] == "--jobs 2"
    assert local["starts"] == dask["starts"]
    runnable = [s for s in local["starts"] if not s["refused"]]
    assert len(runnable) >= 4
    assert len(local["runs"]) == 3 * len(runnable)
    assert study_differences(records(local), records(dask)) == []
    # Every run judged, every failure named.
    assert {r.cause for r in records(local)} <= {"converged", "timeout"}
    assert (tmp_path / "dask" / "figures" / "domain_mpj.png").is_file()
    lines = (tmp_path / "dask" / "runs.jsonl").read_text().splitlines()
    assert sorted(json.loads(x)["key"] for x in lines) == sorted(r["key"] for r in dask["runs"])


@pytest.mark.xdist_group("domains_with_jobs")
def test_a_run_lost_with_its_worker_is_run_again(
    tmp_path: Path, with_jobs: tuple[Path, dict]
) -> None:
    study, reference = with_jobs
    kills = tmp_path / "kills"
    kills.mkdir()
    data = domains(
        tmp_path / "dask", study, "--pipeline", "tests.domains_fakes:kill_once",
        "--cluster", "local:2", "--modes", "dynamic", "mpj", env={KILL_DIR_ENV: str(kills)},
    )  # fmt: skip
    killed_key, pid = (kills / "killed").read_text().split()
    assert int(pid) != os.getpid()
    keys = [r["key"] for r in data["runs"]]
    assert killed_key in keys and len(keys) == len(set(keys))
    runnable = [s for s in data["starts"] if not s["refused"]]
    assert len(keys) == 2 * len(runnable)
    mine = [r for r in records(reference) if r.mode in ("dynamic", "mpj")]
    assert study_differences(mine, records(data)) == []


def test_the_lockstep_pipeline_gives_the_same_records_on_either_executor(tmp_path: Path) -> None:
    study = tiny_study(tmp_path, draws=1)
    args = ["--pipeline", "inprocess", "--cells", "1:3", "--modes", "dynamic"]
    local = domains(tmp_path / "jobs", study, *args, "--jobs", "2")
    dask = domains(tmp_path / "dask", study, *args, "--cluster", "local:2")
    assert len(local["runs"]) == 2
    assert study_differences(records(local), records(dask)) == []
    assert all(r["cause"] for r in local["runs"])


def test_a_published_study_resumes_from_its_domains_json(tmp_path: Path) -> None:
    """A published study keeps domains.json, not runs.jsonl: --resume runs nothing again (a
    pipeline that fails every run would show in the records), e.g. to record its failures."""
    study = tiny_study(tmp_path, draws=1)
    first = domains(tmp_path / "out", study, "--pipeline", FAKE, "--modes", "dynamic")
    (tmp_path / "out" / "runs.jsonl").unlink()
    again = domains(
        tmp_path / "out", study, "--pipeline", "tests.domains_fakes:no_run", "--modes", "dynamic",
        "--resume",
    )  # fmt: skip
    assert study_differences(records(first), records(again)) == []


def test_resume_refuses_the_runs_of_another_study(tmp_path: Path) -> None:
    """Runs are kept by cell, draw and strategy: another seed draws other starts under the same
    keys, so --resume with another seed (or other --set) would have mixed two studies. It is
    refused by name, before anything runs, and the runs kept are left as they were."""
    study = tiny_study(tmp_path, draws=1)
    domains(tmp_path / "out", study, "--pipeline", FAKE, "--modes", "dynamic")
    kept = (tmp_path / "out" / "runs.jsonl").read_text()
    for change, named in ((["--seed", "99"], "seed"), (["--set", "controller.gain=2.0"], "--set")):
        proc = subprocess.run(
            [sys.executable, "-m", "deploy", "domains", "--study", str(study), "--out",
             str(tmp_path / "out"), "--pipeline", FAKE, "--modes", "dynamic", "--resume", *change],
            cwd=REPO, capture_output=True, text=True, timeout=300,
        )  # fmt: skip
        assert proc.returncode == 2, proc.stderr[-2000:]
        assert "belong to another study" in proc.stderr and named in proc.stderr, proc.stderr
        assert (tmp_path / "out" / "runs.jsonl").read_text() == kept
    again = domains(tmp_path / "out", study, "--pipeline", FAKE, "--modes", "dynamic", "--resume")
    assert again["complete"]
