"""``umay accuracy`` as a command: bad input is refused with exit 2, naming it, before the
simulator is loaded."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest


@pytest.mark.parametrize(
    "args, message",
    [
        (["--frames", "0"], "--frames must be at least 1"),
        (["--seed", "-1"], "--seed 0 or more"),
        (["--scenario", "none.toml"], "none.toml: no such scenario file"),
        (["--set", "camera.width_px=1"], "camera.width_px: Input should be greater"),
        (
            ["--json", "file/inside.json"],
            "--json file/inside.json: file exists and is not a folder",
        ),
    ],
)
def test_umay_accuracy_refuses_bad_input_before_loading_the_simulator(
    args: list[str], message: str, tmp_path: Path
) -> None:
    (tmp_path / "file").write_text("x")
    proc = subprocess.run(
        [sys.executable, "-m", "deploy", "accuracy", *args],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
        env={"PYTHONPATH": str(Path(__file__).parents[2]), "PATH": "/usr/bin:/bin"},
    )
    assert proc.returncode == 2, proc.stderr
    assert message in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr and "pybullet build time" not in proc.stderr
