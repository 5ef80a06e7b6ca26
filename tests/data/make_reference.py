"""Regenerate ``tests/data/reference.mcap``, the recording
``tests/integration/test_recording.py`` replays into vision and controller (``umay replay
--check``) as the regression check for perception and control changes.

Regenerate it (from the repository root) when a change to vision or the controller is *meant*
to change their output, or when the scenario schema changes so that the recorded scenario no
longer loads::

    .venv/bin/python tests/data/make_reference.py

which runs, with a free loopback port and a temporary log directory::

    python -m deploy run --quiet --record tests/data/reference.mcap \\
        --set camera.width_px=480 --set camera.height_px=360 --set run.timeout_s=0.4 \\
        --prefix umay/reference --listen tcp/127.0.0.1:<free port> --log-dir <tmp>/logs

14 lockstep frames of the default scenario at 480×360, 1.4 MB. 480×360 is the smallest
common size at which vision sees both markers at the start (at 320×240 and below it reports
the red one as occluded), so the controller really servos in these frames.
The run ends by its timeout, so its exit code is 1 (not converged): expected.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from common.session import free_tcp_endpoint  # noqa: E402
from deploy.recording.read import format_info, read_info  # noqa: E402

OUT = Path(__file__).resolve().parent / "reference.mcap"
SETTINGS = ["camera.width_px=480", "camera.height_px=360", "run.timeout_s=0.4"]


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        argv = [sys.executable, "-m", "deploy", "run", "--quiet", "--record", str(OUT)]
        for item in SETTINGS:
            argv += ["--set", item]
        argv += ["--prefix", "umay/reference", "--listen", free_tcp_endpoint()]
        argv += ["--log-dir", str(Path(tmp) / "logs")]
        proc = subprocess.run(argv, cwd=ROOT, capture_output=True, text=True, timeout=300)
    print(proc.stdout, proc.stderr, sep="")
    if proc.returncode not in (0, 1) or not OUT.exists():
        print(f"the run failed (exit {proc.returncode})", file=sys.stderr)
        return 1
    print(format_info(read_info(OUT)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
