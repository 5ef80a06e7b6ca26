"""The in-process pipeline against the distributed lockstep run (the services as processes over
Zenoh): the same result to the last bit; ``umay run --inprocess`` as a command."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from common.session import free_tcp_endpoint
from deploy.launch.evaluate import RunResult
from deploy.launch.run_inprocess import run_scenario_inprocess
from tests.prefixes import unique_prefix
from tests.unit.test_pipeline import short

REPO = Path(__file__).resolve().parents[2]
MOVING = "deploy/scenarios/suite/12_moving_target.toml"
WALL_FIELDS = {"wall_time_s"}
KINECT = (
    "camera.kinect.enabled=true",
    "camera.depth_hz=15",
    "camera.depth_width_px=320",
    "camera.depth_height_px=240",
)


def distributed(tmp_path: Path, name: str, *options: str) -> RunResult:
    out = tmp_path / f"{name}.json"
    argv = [sys.executable, "-m", "deploy", "run", "--clock", "lockstep", "--quiet"]
    # Its own prefix and port: parallel tests, or a `umay up` on this host, never cross it.
    argv += ["--prefix", unique_prefix(), "--listen", free_tcp_endpoint()]
    argv += [*options, "--result", str(out), "--log-dir", str(tmp_path / "logs")]
    proc = subprocess.run(argv, cwd=REPO, capture_output=True, text=True, timeout=600)
    assert proc.returncode in (0, 1), proc.stderr
    return RunResult.model_validate_json(out.read_text())


def same_run(a: RunResult, b: RunResult) -> None:
    left, right = a.model_dump(exclude=WALL_FIELDS), b.model_dump(exclude=WALL_FIELDS)
    assert left == right  # the float fields to the last bit


@pytest.mark.parametrize(
    "scenario_path, overrides, expected",
    [  # the default scenario: test_integration.py (with the deadman and frames by copy)
        (MOVING, (), "converged"),
        # with the Kinect model (its noise from the sim's own seeded generator, drawn the
        # same on both paths), depth at half the colour rate and at another size
        (None, ("run.timeout_s=0.5", *KINECT), "timeout"),
        # the cue's flag must reach vision and the controller on both paths
        (None, ("marker.orientation_cue=true",), "converged"),
    ],
    ids=["moving_target", "timeout_kinect", "orientation_cue"],
)
def test_the_inprocess_run_is_the_distributed_lockstep_run(
    tmp_path: Path, scenario_path: str | None, overrides: tuple[str, ...], expected: str
) -> None:
    options = ["--scenario", scenario_path] if scenario_path else []
    for o in overrides:
        options += ["--set", o]
    reference = distributed(tmp_path, "distributed", *options)
    inprocess = run_scenario_inprocess(short(scenario_path, *overrides))
    same_run(inprocess, reference)
    assert inprocess.reason == expected and inprocess.frames > 0


def test_umay_run_inprocess_writes_the_same_result_and_exit_code(tmp_path: Path) -> None:
    out = tmp_path / "r.json"
    argv = [sys.executable, "-m", "deploy", "run", "--inprocess", "--quiet", "--result", str(out)]
    proc = subprocess.run(
        [*argv, "--set", "run.timeout_s=0.3"], cwd=REPO, capture_output=True, text=True,
        timeout=600,
    )  # fmt: skip
    assert proc.returncode == 1, proc.stderr  # not converged
    written = json.loads(out.read_text())
    assert written["reason"] == "timeout" and "frames" in proc.stdout
    same_run(RunResult(**written), run_scenario_inprocess(short(None, "run.timeout_s=0.3")))
    refused = subprocess.run(
        [*argv, "--clock", "realtime"], cwd=REPO, capture_output=True, text=True, timeout=600
    )
    assert refused.returncode == 2 and "--inprocess" in refused.stderr
